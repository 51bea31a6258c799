"""The health monitor's noise model (core/health.py) against known truth: the noise a speed block
carries where the healthy reference never went, and healthy simulated flights whose model error
once passed for a change (the false alarms of issue 34)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from _health_data import monitor_events, monitor_over, synthetic_flight
from _models import healthy_physics_model
from bldc_propulsion.core.health import HealthMonitor, HealthSample, _Channel, run_health
from bldc_propulsion.model import load_model
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag


def _flight(seed: int, loss: float = 0.0, onset_s: float = 115.0) -> list[HealthSample]:
    """130 s of holds, 100 speed samples a second: at any speed for 40 s (the model's error is
    learned there), then at LOW speeds only for 60 s (the reference the noise is learned on), then
    at HIGH speeds. measured = predicted + the tachometer's noise, which grows with the speed
    squared (0.5 rad/s per sample at 250 rad/s, 2.9 at 600): at the high speeds it is 30x the
    variance the reference showed. ``loss``: the propeller's loss from ``onset_s`` on, along its
    signature (no model error: the truth is exactly known)."""
    def speeds(t: float) -> tuple[float, float]:
        return (150.0, 600.0) if t < 40.0 else (150.0, 250.0) if t < 100.0 else (500.0, 600.0)

    return synthetic_flight(130.0, seed, (loss, np.array([1.0, 0.0, 0.0, 0.0]), 0.0, onset_s), speeds=speeds,
                            noise_rad_s=lambda level: 0.5 * (level / 250.0) ** 2)


@pytest.mark.parametrize("seed", [1, 2])
def test_no_alarm_where_the_tachometer_is_noisier_than_the_reference_showed(seed):
    """A noise model a + b w^2 learned on the low speeds of the reference said ~0.3 rad/s where
    the high speeds' blocks scatter by ~1: every seed once raised a false alarm at 100-112 s. A
    block's own samples say how noisy it is, whatever speed the reference visited."""
    assert monitor_events(_flight(seed)) == []


@pytest.mark.parametrize("seed", [1, 2])
def test_a_propeller_loss_at_the_noisy_speeds_is_still_named(seed):
    """The same flights with a 10 % loss at 115 s (a 4-6 rad/s rise): the floor keeps the test
    honest, not blind. Found within 1 s, named, its onset within 0.5 s and its size within 0.025."""
    events = monitor_events(_flight(seed, loss=0.1))
    assert len(events) == 1, [e.as_dict() for e in events]
    e = events[0]
    assert e.name == "propeller_damage", e.as_dict()
    assert abs(e.onset_s - 115.0) <= 0.5 and 115.0 <= e.detected_s <= 116.0, e.as_dict()
    assert e.size == pytest.approx(0.1, abs=0.025), e.as_dict()


# --- simulated healthy flights ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    """A physics model fitted on healthy recordings of the nominal bench (as test_health's)."""
    return healthy_physics_model(tmp_path_factory.mktemp("health_noise_model"))


@pytest.mark.parametrize("seed", [31, 32])
def test_healthy_flights_raise_no_alarm(model_path, tmp_path, seed):
    """200 s of random steps on the bench the model was fitted on, nothing changed. The monitor
    once named a propeller loss, a pack's resistance or an unnamed change on both: the model's
    prediction follows the filtered voltage's noise (1-2 rad/s at high current, over seconds),
    undoes the battery filter with a fitted source resistance (an error that decays for 2 s after
    every current step), and a block where a step began passed for steady."""
    bag = tmp_path / "healthy"
    write_sim_bag(simulate("random_steps", 200.0, seed, soc=0.8), bag)
    s = load_signals(bag)
    run = run_health(load_model(model_path), s.pwm_events, s.voltage_events, s.speed_events)
    assert run.events == [], [e.as_dict() for e in run.events]
    assert run.monitored_s > 150.0


# --- the voltage's noise and the currents its reference held -----------------------------------------
def _voltage_channel(quiet_max_a: float, seed: int) -> tuple[HealthMonitor, _Channel, np.ndarray]:
    """A reference of 300 voltage blocks: quiet (steady) ones at 0.1 A up to ``quiet_max_a``, moving
    ones at 0.5-4 A; each block's residual scatters by 2 mV + 8 mV per ampere (the ESC's ripple
    through the battery filter, undone, grows with the current)."""
    rng = np.random.default_rng(seed)
    n = 300
    quiet = np.zeros(n)
    quiet[:150] = 1.0
    amps = np.where(quiet > 0, rng.uniform(0.1, quiet_max_a, n), rng.uniform(0.5, 4.0, n))
    residual = rng.normal(0.0, 1.0, n) * (0.002 + 0.008 * amps)
    mon = HealthMonitor(2.0, speed_scale_rad_s=650.0, pack_resistance_ohm=0.04)
    mon._ref_blocks = n
    ch = _Channel("voltage", residual, np.ones(n), amps, np.zeros(n), np.zeros(n), np.ones((n, 1)),
                  np.zeros((1, n, 1)), min_stretches=1, quiet=quiet, stepped=np.ones(n))
    return mon, ch, residual


@pytest.mark.parametrize("seed", [1, 2])
def test_the_voltage_noise_is_not_learned_from_quiet_blocks_at_idle_only(seed):
    """Quiet blocks at 0.1-0.3 A only (a flight's first steady seconds) say 2-4 mV; the moving
    blocks at 3 A scatter by 26 mV. Learned from them, a healthy flight's first burst once passed
    for a bearing's friction (statistic 148 on a fresh bench): nothing is learned, nothing tested."""
    mon, ch, residual = _voltage_channel(0.3, seed)
    mon._learn_noise(ch, residual, 1)
    assert "voltage" not in mon.noise


@pytest.mark.parametrize("seed", [1, 2])
def test_the_voltage_noise_is_learned_once_quiet_blocks_reach_the_currents_tested(seed):
    """Quiet blocks up to 3 A: the noise is learned, and at 3 A it is the truth within 30 %."""
    mon, ch, residual = _voltage_channel(3.0, seed)
    mon._learn_noise(ch, residual, 1)
    a, b, _, kappa = mon.noise["voltage"]
    assert math.sqrt(kappa * (a + b * 9.0)) == pytest.approx(0.002 + 0.008 * 3.0, rel=0.3)


# --- the learned error below the slowest speed it was learned on -------------------------------------
def _bending_low(seed: int) -> list[HealthSample]:
    """100 s of holds at 330-600 rad/s (the model's error learned there: none), then 8 s of holds
    at 300-330 rad/s, just under the slowest learned speed (within _ERROR_MARGIN of the scale, 650),
    where the model's error bends down to -6 rad/s at 300 (a friction the model lacks, which weighs
    more as the speed falls), then 7 s at 330-600 again: the rotor is healthy throughout."""
    samples = synthetic_flight(115.0, seed, speeds=lambda t: (300.0, 330.0) if 100.0 <= t < 108.0 else (330.0, 600.0))

    def error(w: float) -> float:
        return -6.0 * min(max((330.0 - w) / 30.0, 0.0), 1.0) ** 2

    return [dataclasses.replace(s, measured_speed_rad_s=s.measured_speed_rad_s + error(s.predicted_speed_rad_s))
            for s in samples]


@pytest.mark.parametrize("seed", [1, 2])
def test_nothing_is_seen_where_the_speed_first_falls_under_the_slowest_learned(seed):
    """The learned error extrapolated below its slowest speed said 0 where the model is
    1-6 rad/s off: on both seeds a change (bearing_friction) was seen with its onset in the low
    holds. Below the slowest learned speed a block is not tested for a change until it is learned
    (it only helps name one found elsewhere): no change, alarm or minor, begins there."""
    mon = monitor_over(_bending_low(seed))
    seen = [e for e in [*mon.events, *mon.minor] if 100.0 <= e.onset_s <= 108.0]
    assert seen == [], [e.as_dict() for e in seen]
    assert mon.events == [], [e.as_dict() for e in mon.events]


@pytest.mark.parametrize("seed", [1, 2])
def test_a_propeller_loss_just_above_the_fastest_learned_is_still_named(seed):
    """Above the fastest learned speed the learned error is trusted up to _ERROR_MARGIN: learned at
    150-540 rad/s for 100 s, then held at 540-570, a 10 % loss at 110 s is found within 2 s and named."""
    samples = synthetic_flight(130.0, seed, (0.1, np.array([1.0, 0.0, 0.0, 0.0]), 0.0, 110.0),
                               speeds=lambda t: (150.0, 540.0) if t < 100.0 else (540.0, 570.0))
    events = monitor_events(samples)
    assert len(events) == 1, [e.as_dict() for e in events]
    assert events[0].name == "propeller_damage" and 110.0 <= events[0].detected_s <= 112.0, events[0].as_dict()


# --- the learned error where the model's error bends --------------------------------------------------
def _bending_visits(seed: int) -> tuple[list[HealthSample], Callable[[float], float]]:
    """130 s of holds at 330-600 rad/s, but for the first 3 s of every 20 at 150-170 rad/s, where the
    model's error bends fast: -10 (150 / w)^4 rad/s (-10 at 150, -0.4 at 330: a friction or a
    drive offset the model lacks weighs most near a stop). The rotor is healthy throughout."""
    samples = synthetic_flight(130.0, seed, speeds=lambda t: (150.0, 170.0) if t % 20.0 < 3.0 else (330.0, 600.0))

    def error(w: float) -> float:
        return -10.0 * (150.0 / w) ** 4

    return [dataclasses.replace(s, measured_speed_rad_s=s.measured_speed_rad_s + error(s.predicted_speed_rad_s))
            for s in samples], error


@pytest.mark.parametrize("seed", [1, 2])
def test_the_learned_error_holds_at_every_speed_the_flight_visits(seed):
    """The model's error learned over a flight that spends 85 % of its time fast and dips to low
    holds where the error bends by 4 rad/s: where the flight mostly is, within 0.25 rad/s of the
    truth, and at the low holds within 1.2 rad/s (the bend is 4 rad/s across their 20 rad/s). A
    cubic over all speeds let the bend pull its shape at 330-400 rad/s off by 1.3-1.7 rad/s, and
    missed the low holds by 1.5-2.2."""
    samples, error = _bending_visits(seed)
    mon = monitor_over(samples)
    lo, hi = mon._learned_span()
    assert lo < 155.0 and hi > 585.0, (lo, hi)

    def miss(w: float) -> float:
        return abs(float(mon._terms(w) @ mon._error_coef) - error(w))

    assert max(miss(w) for w in np.linspace(330.0, 590.0, 27)) <= 0.25
    assert max(miss(w) for w in np.linspace(152.0, 168.0, 9)) <= 1.2
