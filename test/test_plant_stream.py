"""The plant as a stream (physics/stream.py) against its batch path and the simulator's truth."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from bldc_propulsion.core.battery_filter import BatteryFilter, BatteryFilterConfig
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.physics.plant import motor_response
from bldc_propulsion.physics.stream import LATE_S, PlantStream
from bldc_propulsion.sim import SimResult, simulate
from bldc_propulsion.sim import random_bench as rb

PWM, VOLTAGE, PREDICT = 0, 1, 2
TAU = BatteryFilterConfig().tau_s


@pytest.fixture(scope="module")
def recording() -> SimResult:
    return simulate("random_steps", 12.0, 5, soc=0.7)


def events(res: SimResult, volt_every: int, grid: np.ndarray, seed: int) -> list[tuple[float, int, float]]:
    """PWM frames, filtered voltage every ``volt_every`` ADC samples and prediction times, in
    time order; inputs stamped alike in a random order, predictions after them."""
    v = BatteryFilter().process(res.battery_t, res.battery_adc)
    rng = np.random.default_rng(seed)
    ev = ([(t, PWM, x) for t, x in zip(res.pwm_t.tolist(), res.pwm.tolist(), strict=True)]
          + [(t, VOLTAGE, x)
             for t, x in zip(res.battery_t[::volt_every].tolist(), v[::volt_every].tolist(), strict=True)])
    ev = [e for _, e in sorted(zip(rng.random(len(ev)), ev, strict=True))]
    ev.sort(key=lambda e: e[0])  # stable: ties keep the random order
    return sorted(ev + [(t, PREDICT, 0.0) for t in grid.tolist()], key=lambda e: (e[0], e[1] == PREDICT))


def run(stream: Any, ev: list[tuple[float, int, float]],
        speed_at: Callable[[float], float] | None = None) -> np.ndarray:
    """Feed ``ev`` to ``stream`` (update_pwm, update_voltage); the speed at each PREDICT event,
    from ``speed_at`` (default: the stream's own)."""
    at = stream.speed_at if speed_at is None else speed_at
    out = []
    for t, kind, x in ev:
        if kind == PWM:
            stream.update_pwm(t, x)
        elif kind == VOLTAGE:
            stream.update_voltage(t, x)
        else:
            out.append(at(t))
    return np.array(out)


CASES = {
    # the physics model's 5 ms step, every effect at nominal, voltage at the node's 20 Hz
    "nominal, 20 Hz voltage": (dataclasses.replace(BenchParams(), sim_step_s=0.005), {}, 50, TAU),
    # another bench (bent throttle map), no dead time (commands act at the step they land on),
    # a measured terminal voltage at 1 kHz
    "random bench, no dead time": (rb.draw_bench(1), {"input_delay": 0.0, "battery_voltage": 0.7}, 1, 0.0),
    "random bench, coasting": (dataclasses.replace(rb.draw_bench(2), sim_step_s=0.002),
                               {"spin_down_asymmetry": 0.4, "motor_heating": 4.0}, 7, TAU),
    # an ESC whose map starts below its start threshold (esc_map_origin_share), threshold at 3x
    "random bench, map from below the threshold": (dataclasses.replace(rb.draw_bench(3), esc_map_origin_share=1.4),
                                                   {"esc_deadband": 3.0}, 10, TAU),
    # a curved map (linear and square blend)
    "random bench, curved map": (dataclasses.replace(rb.draw_bench(4), esc_throttle_curvature=0.6), {}, 10, TAU),
    # a pack with a fast polarisation branch the filter passes only in part (plant.Supply)
    "polarisation branch": (dataclasses.replace(BenchParams(), sim_step_s=0.005,
                                                supply_polarisation_resistance_ohm=0.04,
                                                supply_polarisation_time_constant_s=2.5),
                            {"battery_voltage": 0.9}, 10, TAU),
}


@pytest.mark.parametrize("case", CASES)
def test_stream_equals_the_batch_path(case: str, recording: SimResult) -> None:
    params, eff, every, tau = CASES[case]
    grid = np.arange(0.013, 11.9, 0.01)  # 100 Hz predictions, not on the steps
    ev = events(recording, every, grid, seed=len(case))
    got = run(PlantStream(params, eff, 11.5, tau), ev)
    v = BatteryFilter().process(recording.battery_t, recording.battery_adc)
    want = motor_response(params, eff, (recording.pwm_t, recording.pwm),
                          (recording.battery_t[::every], v[::every]), grid, 11.5, tau, hold_supply=True)
    assert np.max(np.abs(got - want)) < 1e-9
    assert np.ptp(want) > 200.0  # the rotor did move


@pytest.mark.parametrize("case", CASES)
def test_stream_equals_the_batch_path_from_a_running_start(case: str, recording: SimResult) -> None:
    """The recording cut at 3 s, the rotor turning there: both start from the same speed (the
    running state: command held, supply current already filtered) and stay equal."""
    params, eff, every, tau = CASES[case]
    cut = 3.0
    w0 = float(np.interp(cut, recording.truth_t, recording.truth_speed))
    grid = np.arange(cut + 0.013, 11.9, 0.01)
    ev = [e for e in events(recording, every, grid, seed=len(case)) if e[0] >= cut]
    got = run(PlantStream(params, eff, 11.5, tau, initial_speed=w0), ev)
    v = BatteryFilter().process(recording.battery_t, recording.battery_adc)
    p, b = recording.pwm_t >= cut, recording.battery_t[::every] >= cut
    want = motor_response(params, eff, (recording.pwm_t[p], recording.pwm[p]),
                          (recording.battery_t[::every][b], v[::every][b]), grid, 11.5, tau, hold_supply=True,
                          initial_speed=w0)
    assert np.max(np.abs(got - want)) < 1e-9
    assert w0 > 200.0 and abs(want[0] - w0) < 0.05 * w0  # started turning, no braking transient
    rest = motor_response(params, eff, (recording.pwm_t[p], recording.pwm[p]),
                          (recording.battery_t[::every][b], v[::every][b]), grid, 11.5, tau, hold_supply=True)
    assert rest[0] < 0.5 * w0  # as before: from rest


def test_predicting_more_or_less_often_changes_nothing(recording: SimResult) -> None:
    params, eff, every, tau = CASES["nominal, 20 Hz voltage"]
    fine = np.arange(0.013, 11.9, 0.001)
    a = run(PlantStream(params, eff, 11.5, tau), events(recording, every, fine, 1))
    b = run(PlantStream(params, eff, 11.5, tau), events(recording, every, fine[::97], 2))
    np.testing.assert_array_equal(a[::97], b)


def test_stream_on_the_terminal_voltage_reproduces_the_simulator() -> None:
    """Known truth: the simulator's speed, from its command and its terminal voltage."""
    res = simulate("random_steps", 10.0, 3)
    s = PlantStream(BenchParams(), {}, 12.0, 0.0)
    ev = sorted([(t, PWM, x) for t, x in zip(res.pwm_t.tolist(), res.pwm.tolist(), strict=True)]
                + [(t, VOLTAGE, x) for t, x in zip(res.truth_t.tolist(), res.truth_voltage.tolist(), strict=True)]
                + [(t, PREDICT, 0.0) for t in res.truth_t[1:-1].tolist()], key=lambda e: (e[0], e[1]))
    err = run(s, ev) - res.truth_speed[1:-1]
    assert np.max(np.abs(err)) < 0.5
    assert np.max(res.truth_speed) > 300.0


def test_not_ready_at_rest_late_inputs_and_reset() -> None:
    s = PlantStream(BenchParams(), {}, 12.0, TAU)
    assert math.isnan(s.speed_at(1.0)) and not s.ready
    s.update_pwm(1.0, 0.09)
    assert math.isnan(s.speed_at(1.1))  # no voltage yet
    s.update_voltage(1.0, 12.0)
    assert s.ready and s.speed_at(0.5) == 0.0  # before the first command: at rest
    w = s.speed_at(2.0)
    assert w > 300.0
    s.update_voltage(1.2, 12.0)  # stamped before the steps that prediction committed
    assert s.late_inputs == 1
    assert s.speed_at(2.0 + LATE_S) > w  # still speeding up
    s.reset()
    assert not s.ready and math.isnan(s.speed_at(3.0))


@pytest.mark.parametrize("case", CASES)
def test_the_health_monitors_nominal_lane_is_the_stream(case: str, recording: SimResult) -> None:
    """core.health.PhysicsTwins steps its own copy of the plant (one lane per fault); its nominal
    lane is the physics model's prediction, throttle map included (its origin, start threshold and
    exponent), at every step of the model's grid."""
    from bldc_propulsion.core.health import PhysicsTwins

    params, eff, every, tau = CASES[case]
    t0, dt = float(recording.pwm_t[0]), params.sim_step_s
    grid = t0 + dt * np.arange(1, int(11.0 / dt))
    ev = events(recording, every, grid, seed=len(case))
    stream = run(PlantStream(params, eff, 11.5, tau), ev)
    twin = PhysicsTwins(params, eff, 11.5, tau)

    def twin_speed(t: float) -> float:
        s = twin.sample(t)
        return math.nan if s is None else s.speed_rad_s
    got = run(twin, ev, twin_speed)
    ok = np.isfinite(got)
    assert ok.mean() > 0.95 and np.ptp(stream) > 200.0
    assert np.max(np.abs(got[ok] - stream[ok])) < 1e-6
