"""An ESC start threshold apart from the throttle map's origin (``PlantParams.esc_map_origin_share``):
the map by hand, the default as the old map bit for bit, the model file, and fits that recover a
known origin from data simulated with the plant itself (plant truth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.contract import EFFECTS, PWM_FULL, PWM_STOP
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.physics import fit as pf
from bldc_propulsion.physics.config import CALIBRATED, PhysicsConfig
from bldc_propulsion.physics.params import BenchParams, PlantParams, check_plant, params_with_overrides
from bldc_propulsion.physics.plant import (
    esc_duty,
    esc_map,
    map_origin,
    motor_response,
    motor_response_with_current,
    throttle,
)
from bldc_propulsion.physics.plant_model import PlantModel, check_physics_arrays
from bldc_propulsion.physics.sizing import physics_start
from bldc_propulsion.priors import INCH_M, MotorPriors
from bldc_propulsion.recordings import Signals
from bldc_propulsion.sim import random_bench as rb
from bldc_propulsion.training.fit_physics import start_threshold, train_physics

ON = {n: 1.0 for n in EFFECTS}


def old_throttle(level: np.ndarray, threshold: float, exponent: float) -> np.ndarray:
    """The throttle map before the origin existed, verbatim: the reference the default must equal."""
    lv = np.clip(level, PWM_STOP, PWM_FULL)
    x = np.clip((lv - threshold) / (PWM_FULL - threshold), 0.0, 1.0)
    return x if exponent == 1.0 else x**exponent


def old_throttle_float(level: float, threshold: float, exponent: float) -> float:
    """The same for one float (min/max and Python's power, as the stream's step computed it)."""
    lv = min(max(level, PWM_STOP), PWM_FULL)
    x = min(max((lv - threshold) / (PWM_FULL - threshold), 0.0), 1.0)
    return x if exponent == 1.0 else x**exponent


def test_duty_curve_by_hand() -> None:
    """Threshold 0.056 (esc_deadband 0.006 at strength 1), share 1.2: the map starts at
    0.056 - 1.2 x 0.006 = 0.0488 and runs to PWM_FULL over 0.0512; nothing at or below 0.056."""
    p = dataclasses.replace(PlantParams(), esc_deadband_pwm=0.006, esc_map_origin_share=1.2)
    assert map_origin(p, ON) == pytest.approx(0.0488, abs=1e-15)
    levels = np.array([0.045, PWM_STOP, 0.0559, 0.056, 0.0561, 0.075, 0.1, 0.11])
    want = np.array([0.0, 0.0, 0.0, 0.0, 0.0073 / 0.0512, 0.0262 / 0.0512, 1.0, 1.0])
    np.testing.assert_allclose(throttle(levels, *esc_map(p, ON)), want, rtol=1e-12, atol=1e-15)
    bent = dataclasses.replace(p, esc_throttle_exponent=1.5)
    np.testing.assert_allclose(throttle(levels, *esc_map(bent, ON)), want**1.5, rtol=1e-12, atol=1e-15)
    for lv, d in zip(levels.tolist(), throttle(levels, *esc_map(bent, ON)).tolist(), strict=True):
        assert throttle(lv, *esc_map(bent, ON)) == pytest.approx(d, rel=1e-12, abs=1e-15)  # one float: the same
    # through the dead time: PWM_STOP (no drive) until the first frame has waited 40 ms
    t = np.array([0.0, 0.039, 0.041, 0.2])
    duty = esc_duty(p, ON, np.array([0.0]), np.array([0.075]), t)
    np.testing.assert_allclose(duty, [0.0, 0.0, 0.0262 / 0.0512, 0.0262 / 0.0512], rtol=1e-12)


def test_share_one_is_a_map_from_stop_cut_off_below_the_threshold() -> None:
    """Share 1: above the threshold, the duty of an ESC without one (the map starts at PWM_STOP
    whatever the threshold's strength), as the foreign bench's ESC has it."""
    p = dataclasses.replace(PlantParams(), esc_map_origin_share=1.0)
    levels = np.linspace(0.04, 0.105, 131)
    for strength in (0.5, 1.0, 2.5):
        eff = {**ON, "esc_deadband": strength}
        no_threshold = throttle(levels, *esc_map(p, {**ON, "esc_deadband": 0.0}))
        want = np.where(levels <= PWM_STOP + strength * p.esc_deadband_pwm, 0.0, no_threshold)
        np.testing.assert_allclose(throttle(levels, *esc_map(p, eff)), want, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("seed", range(6))
def test_the_default_is_the_old_map_bit_for_bit(seed: int) -> None:
    """Every bench the simulator draws, every strength of esc_deadband (the threshold itself among
    the levels): the duty is the old map's, to the bit."""
    p = rb.draw_bench(seed)
    assert p.esc_map_origin_share == 0.0
    rng = np.random.default_rng(seed)
    for strength in (0.0, 1.0, float(rng.uniform(0.0, 6.0))):
        eff = {**ON, "esc_deadband": strength}
        threshold = PWM_STOP + strength * p.esc_deadband_pwm
        levels = np.r_[rng.uniform(0.045, 0.105, 500), threshold, PWM_STOP, PWM_FULL]
        want = old_throttle(levels, threshold, p.esc_throttle_exponent)
        assert np.array_equal(throttle(levels, *esc_map(p, eff)), want)
        assert [throttle(x, *esc_map(p, eff)) for x in levels.tolist()] == [
            old_throttle_float(x, threshold, p.esc_throttle_exponent) for x in levels.tolist()]
        cmd_t = np.arange(0.0, 1.0, 0.02)
        t = np.arange(0.0, 1.2, 0.005)
        assert np.array_equal(esc_duty(p, eff, cmd_t, levels[:len(cmd_t)], t),
                              old_throttle(levels[:len(cmd_t)][np.clip(np.searchsorted(
                                  cmd_t, t - eff["input_delay"] * p.esc_input_delay_s + 1e-9, side="right") - 1,
                                  0, None)], threshold, p.esc_throttle_exponent)
                              * (t - eff["input_delay"] * p.esc_input_delay_s + 1e-9 >= 0.0))


def test_a_separate_origin_changes_the_speed_and_is_checked() -> None:
    p = dataclasses.replace(BenchParams(), sim_step_s=0.005)
    cmd = (np.array([0.0, 1.0, 2.0]), np.array([0.054, 0.056, 0.07]))
    t = np.arange(0.0, 3.0, 0.01)
    sup = (t, np.full_like(t, 12.0))
    base = motor_response(p, ON, cmd, sup, t, 12.0)
    moved = motor_response(dataclasses.replace(p, esc_map_origin_share=1.0), ON, cmd, sup, t, 12.0)
    assert np.array_equal(base[t < 1.0], moved[t < 1.0])  # below the threshold (0.055): no drive either way
    assert np.all(moved[(t > 1.8) & (t < 2.0)] > base[(t > 1.8) & (t < 2.0)] + 50.0)  # 0.056: the map from stop
    with pytest.raises(BadInputError, match="esc_map_origin_share"):
        check_plant(dataclasses.replace(p, esc_map_origin_share=-0.1))
    assert params_with_overrides(BenchParams(), {"esc_map_origin_share": 1.1}).esc_map_origin_share == 1.1


def test_model_file_keeps_the_origin_and_reads_files_without_it() -> None:
    """A model file written before the origin existed (no such name) reads as the default; a model
    with a separate origin keeps it through its arrays and gives it to its stream."""
    eff = {n: 1.0 for n in EFFECTS}
    arrays = dict(PlantModel(dataclasses.replace(PlantParams(), esc_map_origin_share=0.7), eff, 12.0).physics_arrays())
    names = arrays["physics_names"].tolist()
    keep = np.array([n != "esc_map_origin_share" for n in names])
    old = {**arrays, "physics_names": arrays["physics_names"][keep], "physics_values": arrays["physics_values"][keep]}
    check_physics_arrays(old, pytest.fail)
    assert PlantModel.of_arrays(old, None, {}).params == PlantParams()
    new = PlantModel(dataclasses.replace(PlantParams(), esc_map_origin_share=0.7), eff, 12.0)
    back = PlantModel.of_arrays(new.physics_arrays(), None, {})
    assert back.params.esc_map_origin_share == 0.7
    assert back.feature_params()[c.INPUT_PHYSICS_SPEED]["esc_map_origin_share"] == 0.7


# --- fits on the plant's own data -----------------------------------------------------------------
SUPPLY_V = 12.0
#: The truth: the nominal bench, threshold at strength 2 (PWM 0.060 = 1200 us), map from 0.054 (share 0.6).
TRUE_SHARE, TRUE_DEADBAND = 0.6, 2.0
TRUTH_EFFECTS = {**{n: 0.0 for n in EFFECTS}, "rotor_lag": 1.0, "esc_deadband": TRUE_DEADBAND}


def staircase(name: str, levels_us: list[float], seed: int, hold_s: float = 1.5) -> Signals:
    p = dataclasses.replace(BenchParams(), sim_step_s=0.005, esc_map_origin_share=TRUE_SHARE)
    t_ev = np.arange(0.0, len(levels_us) * hold_s, 0.02)
    level = np.repeat(np.asarray(levels_us) / c.PWM_PERIOD_US, round(hold_s / 0.02))[:len(t_ev)]
    t = np.arange(0.0, t_ev[-1], 0.01)
    v = np.full_like(t, SUPPLY_V)
    w = motor_response(p, TRUTH_EFFECTS, (t_ev, level), (t, v), t, SUPPLY_V)
    speed = w + np.random.default_rng(seed).normal(0.0, 1.0, len(t))
    return Signals(path=name, sha256=name, t=t, pwm=np.interp(t, t_ev, level), voltage=v, speed=speed, thrust=None,
                   current=None, speed_source="rotor/speed", voltage_source=c.bare(c.TOPIC_BATTERY_VOLTAGE),
                   pwm_events=(t_ev, level), voltage_events=(t, v), speed_events=(t, speed))


def test_the_holds_place_the_threshold() -> None:
    """At rest at 1150 and 1190 us, running from 1210 us: the threshold just above 1190 us."""
    s = staircase("a", [1000, 1150, 1190, 1210, 1400, 1700, 1300], 0)
    threshold = start_threshold([s])
    assert threshold is not None and 1190 / c.PWM_PERIOD_US < threshold < 1190 / c.PWM_PERIOD_US + 1e-5
    assert start_threshold([staircase("b", [1300, 1500, 1700], 1)]) is None  # no level at rest above stop


def test_a_fit_recovers_the_origin() -> None:
    """Plant truth: from the map starting at the threshold (share 0), Kv, CP and the origin fitted
    on the speed (threshold and inertia held at the truth's) recover the truth; held at 0, the
    fit is far worse."""
    data = pf.Data.of([staircase("a", [1000, 1150, 1210, 1250, 1300, 1400, 1550, 1700, 1900, 1450, 1220], 0),
                       staircase("b", [1230, 1600, 1350, 1260, 1800, 1205], 1)])
    model = PhysicsConfig(dataclasses.replace(BenchParams(), sim_step_s=0.005), dict(TRUTH_EFFECTS), SUPPLY_V)
    hold = tuple(n for n in CALIBRATED if n not in ("motor_kv_rpm_per_v", "propeller_cp"))
    held = ("rotor_lag", "esc_deadband")
    free = pf.fit_reference(model, data, hold=hold, held_effects=held, linear=("esc_map_origin_share",))
    assert free.model.params.esc_map_origin_share == pytest.approx(TRUE_SHARE, abs=0.03)
    assert free.model.params.motor_kv_rpm_per_v == pytest.approx(710.0, rel=0.02)
    assert free.model.params.propeller_cp == pytest.approx(0.042, rel=0.05)
    assert free.linear == ("esc_map_origin_share",) and free.J.shape[1] == len(CALIBRATED) + 1
    assert not [f for f in pf.fit_flags(free, model, "fit") if f.quantity == "esc_map_origin_share"]
    rmse = np.sqrt(free.sse / len(free.r))
    assert rmse < 1.5  # the speed's own noise is 1 rad/s
    straight = pf.fit_reference(model, data, hold=hold, held_effects=held)
    assert np.sqrt(straight.sse / len(straight.r)) > 3.0 * rmse


# --- train --kind physics: the origin candidate ----------------------------------------------------
PRIORS = MotorPriors(motor_kv_rpm_per_v=1900.0, propeller_diameter_m=7 * INCH_M, propeller_pitch_m=5.6 * INCH_M)
STAND_V = 16.0
#: The stand's truth: the stated motor behind an ESC that maps from PWM_STOP (share 1) but starts the
#: rotor only above 1120 us (esc_deadband 1.2 x 0.005); braking actively.
STAND_EFFECTS = {**{n: 1.0 for n in EFFECTS}, "spin_down_asymmetry": 0.0, "esc_deadband": 1.2}


def stand(name: str, levels_us: list[float], seed: int, with_current: bool = True, hold_s: float = 2.0) -> Signals:
    """A staircase on the stand's plant: speed and supply current with noise, the supply recorded."""
    start = physics_start(PRIORS, STAND_V)
    assert start is not None
    p = dataclasses.replace(start.params, esc_map_origin_share=1.0, sim_step_s=0.005)
    t_ev = np.arange(0.0, len(levels_us) * hold_s, 0.02)
    level = np.repeat(np.asarray(levels_us) / c.PWM_PERIOD_US, round(hold_s / 0.02))[:len(t_ev)]
    t = np.arange(0.0, t_ev[-1], 0.01)
    v = np.full_like(t, STAND_V)
    w, i = motor_response_with_current(p, STAND_EFFECTS, (t_ev, level), (t, v), t, STAND_V)
    rng = np.random.default_rng(seed)
    speed = w + rng.normal(0.0, 5.0, len(t))
    current = i + rng.normal(0.0, 0.05, len(t)) if with_current else None
    return Signals(path=name, sha256=name, t=t, pwm=np.interp(t, t_ev, level), voltage=v, speed=speed, thrust=None,
                   current=current, speed_source="rotor/speed", voltage_source=c.bare(c.TOPIC_BATTERY_VOLTAGE),
                   pwm_events=(t_ev, level), voltage_events=(t, v), speed_events=(t, speed))


def test_training_frees_the_origin_where_the_current_and_the_holds_identify_it() -> None:
    """With the supply current and a level the rotor rests at above PWM_STOP, a fifth fit frees the
    origin below the threshold the holds place (just above 1100 us); it fits the stand and the
    validation keeps it, with the true origin (PWM_STOP: share 1 of a threshold at 1100 us)."""
    train = [stand("a", [1000, 1100, 1150, 1250, 1400, 1600, 1800, 1500, 1200, 1100], 0),
             stand("b", [1100, 1300, 1700, 1170, 1450, 1900, 1350], 1)]
    val = [stand("v", [1050, 1180, 1550, 1100, 1300, 1750], 2)]
    out = train_physics(train, val, thrust_coefficient=4.4e-6, priors=PRIORS)
    assert len(out.candidates) == 5
    kept = out.candidates[0]
    assert "map from below the start threshold (PWM 0.0550" in kept["fit"], [d["fit"] for d in out.candidates]
    assert kept["constants"]["esc_map_origin_share"] == pytest.approx(1.0, abs=0.05)
    assert kept["constants"]["motor_kv_rpm_per_v"] == pytest.approx(1900.0, rel=0.03)
    assert kept["validation_rmse_rad_s"] < 10.0  # the speed's noise is 5 rad/s
    assert kept["validation_rmse_rad_s"] < 0.5 * min(d["validation_rmse_rad_s"] for d in out.candidates[1:])
    assert out.model.params.esc_map_origin_share == kept["constants"]["esc_map_origin_share"]
    # without the current the origin trades with Kv, the exponent and CP: not freed
    bare = train_physics([dataclasses.replace(s, current=None) for s in train], val, thrust_coefficient=4.4e-6,
                         priors=PRIORS)
    assert len(bare.candidates) == 4 and bare.model.params.esc_map_origin_share == 0.0
