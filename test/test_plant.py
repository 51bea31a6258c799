"""The plant (ESC, motor, rotor, thermal) on its own: what the simulator and the estimator share."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest

from bldc_propulsion.contract import EFFECTS, PWM_FULL, PWM_STOP
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.physics import params as pp
from bldc_propulsion.physics import plant as pl
from bldc_propulsion.physics.params import BenchParams

ALL_OFF = {name: 0.0 for name in EFFECTS}


def test_plant_imports_nothing_of_the_simulator() -> None:
    code = ("import sys, bldc_propulsion.physics.plant; "
            "print(sorted(m for m in sys.modules if m.startswith('bldc_propulsion.sim')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_bench_params_are_plant_params_plus_battery_and_sensors() -> None:
    b = BenchParams()
    assert isinstance(b, pp.PlantParams)
    for name in pp.PLANT_FIELDS:
        assert getattr(b, name) == getattr(pp.PlantParams(), name)
    assert not any(n.startswith(("tach_", "adc_")) for n in pp.PLANT_FIELDS)
    assert [n for n in pp.PLANT_FIELDS if n.startswith("battery_")] == ["battery_series_resistance_ohm"]


@pytest.mark.parametrize("exponent", [1.0, 0.8, 1.25])
@pytest.mark.parametrize("threshold", [PWM_STOP, 0.055, 0.058])
def test_throttle_map_one_float_equals_the_array(threshold: float, exponent: float) -> None:
    levels = np.linspace(0.03, 0.12, 181)
    arr = pl.throttle(levels, threshold, exponent)
    one = np.array([pl.throttle(float(x), threshold, exponent) for x in levels])
    np.testing.assert_allclose(one, arr, rtol=1e-15, atol=0.0)
    assert np.all(arr[levels <= threshold] == 0.0) and np.all(arr[levels >= PWM_FULL] == 1.0)
    mid = (threshold + PWM_FULL) / 2
    assert pl.throttle(mid, threshold, exponent) == pytest.approx(0.5**exponent)


@pytest.mark.parametrize("curvature", [0.0, 0.35, 1.0])
def test_curved_throttle_map_is_the_linear_and_square_blend(curvature: float) -> None:
    """Exponent 1: duty = (1 - c) x + c x^2 by hand, the foreign ESC's a x + (1 - a) x^2; with an
    exponent it multiplies x**exponent; one float equals the array; an origin below the threshold
    jumps to the curved map's value there."""
    levels = np.linspace(0.03, 0.12, 181)
    threshold = 0.055
    x = np.clip((levels - threshold) / (PWM_FULL - threshold), 0.0, 1.0)
    arr = pl.throttle(levels, threshold, 1.0, None, curvature)
    np.testing.assert_allclose(arr, (1.0 - curvature) * x + curvature * x * x, rtol=1e-14, atol=1e-15)
    bent = pl.throttle(levels, threshold, 1.3, None, curvature)
    np.testing.assert_allclose(bent, x**1.3 * ((1.0 - curvature) + curvature * x), rtol=1e-14, atol=1e-15)
    one = np.array([pl.throttle(float(v), threshold, 1.3, None, curvature) for v in levels])
    np.testing.assert_allclose(one, bent, rtol=1e-15, atol=0.0)
    assert np.all(np.diff(bent) >= 0.0) and bent[-1] == 1.0
    xo = (0.056 - PWM_STOP) / (PWM_FULL - PWM_STOP)
    jump = pl.throttle(0.056, threshold, 1.0, PWM_STOP, curvature)
    assert jump == pytest.approx((1 - curvature) * xo + curvature * xo**2)
    # the plant's map carries it (esc_map), and a curvature past the square law is refused
    p = dataclasses.replace(pp.PlantParams(), esc_throttle_curvature=curvature)
    assert pl.esc_map(p, {"esc_deadband": 1.0})[3] == curvature


def test_dead_time_and_start_level_scale_with_the_effects() -> None:
    p = pp.PlantParams()
    eff = pp.resolve_effects({"input_delay": 0.5, "esc_deadband": 2.0})
    assert pl.dead_time_s(p, eff) == pytest.approx(0.020)
    assert pl.start_level(p, eff) == pytest.approx(0.060)
    # a frame at 1.000 s reaches the ESC at 1.020 s
    d = pl.esc_duty(p, eff, np.array([0.0, 1.0]), np.array([PWM_STOP, PWM_FULL]),
                    np.array([1.019, 1.020, 1.021]))
    assert d.tolist() == [0.0, 1.0, 1.0]


def test_steady_state_is_the_hand_computed_torque_balance() -> None:
    """No inertia, no friction, cold winding: kq w^2 = kt (V - ke w) / R, solved by hand."""
    p = dataclasses.replace(pp.PlantParams(), motor_no_load_current_a=0.0, battery_series_resistance_ohm=0.0)
    step = pl.make_step(p, ALL_OFF, 0.0)
    w, w_next, i, _ = step(0.0, p.ambient_temperature_c, 1.0, 12.0)
    ke, kq, r = p.back_emf_constant_v_s_per_rad, p.torque_coefficient, p.winding_resistance_ohm + p.esc_resistance_ohm
    # kq r w^2 + ke^2 w - ke V = 0
    expected = (-ke * ke + math.sqrt(ke**4 + 4.0 * kq * r * ke * 12.0)) / (2.0 * kq * r)
    assert w == w_next == pytest.approx(expected, rel=1e-12)
    assert i == pytest.approx((12.0 - ke * expected) / r, rel=1e-12)
    assert 550.0 < w < 700.0  # the nominal bench's full-throttle speed on 12 V (sim tests: ~600)


def test_rotor_with_inertia_approaches_the_steady_state_with_its_time_constant() -> None:
    p = pp.PlantParams()
    eff = {**ALL_OFF, "rotor_lag": 1.0}
    w_ss = pl.make_step(p, ALL_OFF, 0.0)(0.0, 25.0, 0.6, 12.0)[0]
    step = pl.make_step(p, eff, 0.0)
    w, temp = 0.0, 25.0
    for _ in range(2000):  # 2 s
        _, w, _, temp = step(w, temp, 0.6, 12.0)
    assert w == pytest.approx(w_ss, rel=1e-3)
    assert temp > 25.0  # copper loss heats the winding


def test_spin_up_time_constant_is_the_small_step_response() -> None:
    """``spin_up_time_constant_s`` (the linearised rotor) against the plant stepped at 1 ms: a small
    duty step from a settled speed reaches 63.2 % of its rise in one time constant. At 1.5x the
    nominal inertia on another winding, so the check is not of the nominal numbers."""
    p = dataclasses.replace(pp.PlantParams(), winding_resistance_ohm=0.35)
    eff = {**ALL_OFF, "rotor_lag": 1.5}
    steady = pl.make_step(p, ALL_OFF, 0.0)
    w0, w1 = (steady(0.0, 25.0, d, 12.0)[0] for d in (0.5, 0.51))
    step = pl.make_step(p, eff, 0.0)
    w, n = w0, 0
    while w < w0 + (1.0 - math.exp(-1.0)) * (w1 - w0):
        _, w, _, _ = step(w, 25.0, 0.51, 12.0)
        n += 1
    tau = pl.spin_up_time_constant_s(p, eff, 0.5 * (w0 + w1))
    assert n * p.sim_step_s == pytest.approx(tau, rel=0.02)
    assert 0.05 < tau < 0.5
    assert pl.spin_up_time_constant_s(p, ALL_OFF, w0) == 0.0  # no inertia: no lag


def test_full_drive_speeds_are_where_the_simulated_winding_levels_off() -> None:
    """``full_drive_speeds`` against the simulator's ground truth at full command on a stiff supply:
    the speed once the winding has settled (a motor with a 13 s thermal time constant run for
    90 s) and the same run without heating (cold)."""
    from bldc_propulsion.sim import simulate

    p = dataclasses.replace(BenchParams(), motor_thermal_capacity_j_per_k=7.0)
    eff = {**{n: 1.0 for n in EFFECTS}, "battery_voltage": 0.0}
    cmd = (np.array([0.0]), np.array([PWM_FULL]))
    hot, cold = (simulate("step", 90.0, 0, effects={**eff, "motor_heating": h}, params=p, pwm=cmd) for h in (1.0, 0.0))
    v = float(hot.truth_voltage[-1])
    assert np.ptp(hot.truth_voltage[-1000:]) < 1e-9  # stiff
    want_cold, want_warm = pl.full_drive_speeds(p, eff, v)
    assert want_cold == pytest.approx(cold.truth_speed[-1], rel=1e-3)
    assert want_warm == pytest.approx(hot.truth_speed[-1], rel=1e-3)
    assert want_warm < want_cold - 10.0


def test_without_braking_the_current_never_goes_negative() -> None:
    p = pp.PlantParams()
    for braking_removed, brakes in ((0.0, True), (1.0, False)):
        step = pl.make_step(p, {**ALL_OFF, "rotor_lag": 1.0, "spin_down_asymmetry": braking_removed}, 0.0)
        _, _, i, _ = step(500.0, 25.0, 0.1, 12.0)  # fast rotor, little drive: back-EMF wins
        assert (i < 0.0) if brakes else (i == 0.0)


@pytest.mark.parametrize("field, value, needle", [
    ("motor_kv_rpm_per_v", 0.0, "must be > 0"),
    ("motor_kv_rpm_per_v", -710.0, "must be > 0"),
    ("motor_rotor_inertia_kg_m2", -1e-6, "must be >= 0"),
    ("propeller_mass_kg", 0.0, "must be > 0"),
    ("propeller_cp", math.nan, "finite"),
    ("esc_deadband_pwm", 0.05, "no throttle range"),
    ("sim_step_s", 0.01, "too coarse"),
    ("esc_throttle_curvature", 1.2, "past the square law"),
    ("esc_throttle_curvature", -0.1, ">= 0"),
])
def test_unphysical_constants_are_named(field: str, value: float, needle: str) -> None:
    p = dataclasses.replace(pp.PlantParams(), **{field: value})
    name, why = pp.plant_problem(p)
    assert name == field and needle in why
    with pytest.raises(BadInputError, match=rf"^--param {field}: .*{needle}"):
        pp.check_plant(p)
    assert pp.plant_problem(pp.PlantParams()) is None


def test_strengths_are_checked_by_one_rule() -> None:
    assert pp.strength_problem("rotor_lag", 2.0) is None
    assert "unknown effect" in pp.strength_problem("wobble", 1.0)
    assert ">= 0" in pp.strength_problem("rotor_lag", -1.0)
    assert "[0, 1]" in pp.strength_problem("spin_down_asymmetry", 1.5)
    with pytest.raises(BadInputError, match=r"^--effect rotor_lag='x': not a number"):
        pp.resolve_effects({"rotor_lag": "x"})


def test_supply_puts_back_the_polarisation_the_battery_filter_has_not_passed() -> None:
    """A pack of E behind R_s and one RC branch (R_p, tau_p), its terminal voltage measured
    through a first-order low-pass (scipy's lfilter as the reference filter): what the model feeds
    the motor, the filtered voltage plus ``Supply``'s correction less the series drop, is the
    terminal voltage at every step of a current staircase; without the branch in the model it
    is off by a fifth of the branch's largest drop."""
    from scipy.signal import lfilter

    from bldc_propulsion.physics.plant import Supply

    dt, tau_s, r_s, r_p, tau_p, e = 0.001, 2.0, 0.03, 0.02, 2.5, 12.0
    ib = np.repeat([0.0, 20.0, 5.0, 30.0, 0.0], 4000)
    a_p, a_f = 1.0 - math.exp(-dt / tau_p), 1.0 - math.exp(-dt / tau_s)
    vp_true = lfilter([a_p], [1.0, a_p - 1.0], r_p * ib)  # v_p[k] after step k's current
    terminal = e - r_s * ib - np.concatenate(([0.0], vp_true[:-1]))  # the branch as it stood during step k
    filtered = np.concatenate(([e], lfilter([a_f], [1.0, a_f - 1.0], terminal, zi=[(1.0 - a_f) * e])[0][:-1]))

    def seen(p: pp.PlantParams) -> np.ndarray:
        sp = Supply.of(p, {"battery_voltage": 1.0}, e, tau_s)
        state, out = sp.start(0.0), []
        for k in range(len(ib)):
            out.append(filtered[k] + sp.correction(state) - r_s * ib[k])
            state = sp.advance(state, float(ib[k]))
        return np.array(out)

    p = dataclasses.replace(pp.PlantParams(), sim_step_s=dt, battery_series_resistance_ohm=r_s,
                            supply_polarisation_resistance_ohm=r_p, supply_polarisation_time_constant_s=tau_p)
    assert np.max(np.abs(seen(p) - terminal)) < 1e-9
    off = np.max(np.abs(seen(dataclasses.replace(p, supply_polarisation_resistance_ohm=0.0)) - terminal))
    assert off > 0.2 * r_p * 30.0
