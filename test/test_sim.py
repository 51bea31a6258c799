"""Physics of the simulated bench: what a motor engineer would check on a real one."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
from scipy.signal import lfilter, lfilter_zi

from bldc_propulsion.contract import EFFECTS, PWM_FRAME_HZ, PWM_FULL, PWM_STOP
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.physics.params import BenchParams, params_with_overrides
from bldc_propulsion.physics.plant import motor_response
from bldc_propulsion.sim import EFFECT_DOCS, PROFILES, SimResult, make_profile, simulate
from bldc_propulsion.sim.profiles import ARMING_S
from bldc_propulsion.sim.random_bench import model_strength

# the paper's battery filter, eq. (1), at 1 kHz
FILTER_B = [4.9975e-4, 4.9975e-4]
FILTER_A = [1.0, -0.9995]


def step(l0: float, l1: float, t_step: float, duration: float, seed: int = 0, **kw) -> SimResult:
    """Command l0 from t = 0, then l1 from t_step."""
    return simulate("step", duration, seed, pwm=(np.array([0.0, t_step]), np.array([l0, l1])), **kw)


def window(res: SimResult, t0: float, t1: float) -> slice:
    return slice(int(round(t0 * 1000)), int(round(t1 * 1000)))


def fall_time(res: SimResult, t_step: float, fraction: float = 0.9) -> float:
    """Time after t_step for the speed to lose ``fraction`` of its value at t_step."""
    k0 = int(round(t_step * 1000)) - 1
    w0 = res.truth_speed[k0]
    after = np.nonzero((res.truth_t > t_step) & (res.truth_speed < (1 - fraction) * w0))[0]
    assert len(after), "speed never fell"
    return float(res.truth_t[after[0]] - t_step)


# --- operating point ----------------------------------------------------------------------
def test_full_throttle_steady_state_on_full_pack() -> None:
    res = step(PWM_FULL, PWM_FULL, 0.0, 4.0)
    w = res.truth_speed[window(res, 3.0, 4.0)].mean()
    i = res.truth_current[window(res, 3.0, 4.0)].mean()
    assert 550.0 <= w <= 650.0
    assert 14.0 <= i <= 16.0
    b = res.params.thrust_coefficient
    np.testing.assert_allclose(res.truth_thrust, b * res.truth_speed**2)
    assert 8.0 < res.truth_thrust[window(res, 3.0, 4.0)].mean() < 12.0  # ~1 kgf, 12x4.5 at 5.8 krpm


def test_speed_rises_with_throttle_over_staircase() -> None:
    res = simulate("staircase", 80.0, 3)
    # steady speed at the end of each hold, grouped by level
    change = np.nonzero(np.diff(res.pwm))[0]  # last frame of each hold
    by_level: dict[float, list[float]] = {}
    for f in change:
        k = int(round(res.pwm_t[f] * 1000)) + 10  # within the last frame, after the ESC delay
        by_level.setdefault(round(float(res.pwm[f]), 4), []).append(float(res.truth_speed[k]))
    levels = sorted(by_level)
    assert len(levels) >= 8
    assert by_level[PWM_STOP] == [0.0] * len(by_level[PWM_STOP])
    for lo, hi in pairwise(levels):
        if hi > 0.055:
            assert min(by_level[hi]) > max(by_level[lo]), (lo, hi, by_level)


def test_no_rotation_below_threshold_and_rotation_just_above() -> None:
    below = step(PWM_STOP, 0.054, 0.0, 3.0)
    assert np.all(below.truth_speed == 0.0)
    assert np.all(below.truth_current == 0.0)
    above = step(PWM_STOP, 0.057, 0.0, 3.0)
    assert above.truth_speed[-1] > 10.0


# --- battery ------------------------------------------------------------------------------
def test_speed_falls_as_battery_discharges() -> None:
    full = simulate("constant", 5.0, 1, soc=1.0)
    low = simulate("constant", 5.0, 1, soc=0.15)
    assert low.truth_voltage[-1] < full.truth_voltage[-1] - 1.0
    assert low.truth_speed[-1] < full.truth_speed[-1] - 20.0
    # over a long constant run, with heating off so only the battery acts
    run = simulate("constant", 150.0, 1, effects={"motor_heating": 0.0})
    early = run.truth_speed[window(run, 10.0, 20.0)].mean()
    late = run.truth_speed[window(run, 140.0, 150.0)].mean()
    assert late < early - 5.0
    assert run.truth_soc[-1] < run.truth_soc[0] - 0.05
    assert np.all(np.diff(run.truth_soc) <= 0.0)


def test_open_circuit_voltage_of_3s_pack() -> None:
    for soc, lo, hi in ((1.0, 12.5, 12.7), (0.5, 10.9, 11.4), (0.01, 9.8, 10.3)):
        res = simulate("constant", 0.01, 0, soc=soc, pwm=(np.array([0.0]), np.array([PWM_STOP])))
        assert lo <= res.truth_voltage[0] <= hi, soc


def test_paper_filter_recovers_terminal_voltage() -> None:
    res = simulate("constant", 20.0, 4)
    assert np.ptp(res.battery_adc[5000:] * res.params.adc_divider_ratio) > 1.0  # modulated
    zi = lfilter_zi(FILTER_B, FILTER_A) * res.battery_adc[0]  # started settled, motor stopped
    f, _ = lfilter(FILTER_B, FILTER_A, res.battery_adc, zi=zi)
    err = f - res.truth_voltage
    assert np.max(np.abs(err[window(res, 8.0, 20.0)])) < 0.1


def test_modulation_grows_with_current() -> None:
    def swing(r: SimResult) -> float:
        return float(np.std(r.battery_adc[1000:] * r.params.adc_divider_ratio - r.truth_voltage[1000:]))

    hi = step(PWM_FULL, PWM_FULL, 0.0, 3.0)
    lo = step(0.065, 0.065, 0.0, 3.0)
    assert swing(hi) > 2.0 * swing(lo)
    assert 0.5 < swing(hi) < 3.0  # volts at the battery: a few volts peak to peak


# --- rotor dynamics -----------------------------------------------------------------------
def test_spin_down_slower_without_active_braking() -> None:
    coast = step(PWM_FULL, PWM_STOP, 3.0, 8.0, effects={"spin_down_asymmetry": 1.0})
    brake = step(PWM_FULL, PWM_STOP, 3.0, 8.0, effects={"spin_down_asymmetry": 0.0})
    assert fall_time(coast, 3.0) > 2.0 * fall_time(brake, 3.0)
    assert coast.truth_current.min() >= 0.0  # no regeneration without braking
    # spin-up is unaffected by the ESC's braking
    up_c = step(PWM_STOP, PWM_FULL, 0.5, 3.0, effects={"spin_down_asymmetry": 1.0})
    up_b = step(PWM_STOP, PWM_FULL, 0.5, 3.0, effects={"spin_down_asymmetry": 0.0})
    np.testing.assert_allclose(up_c.truth_speed, up_b.truth_speed, rtol=1e-9)


def test_rotor_lag_zero_is_instantaneous() -> None:
    lag = step(PWM_STOP, 0.08, 1.0, 2.0, effects={"input_delay": 0.0})
    inst = step(PWM_STOP, 0.08, 1.0, 2.0, effects={"input_delay": 0.0, "rotor_lag": 0.0})
    final = inst.truth_speed[-1]
    k = int(1.0 * 1000)
    assert inst.truth_speed[k] > 0.98 * final
    assert lag.truth_speed[k + 20] < 0.5 * final  # inertia: ~0.1 s time constant
    assert lag.truth_speed[-1] == pytest.approx(final, rel=0.01)
    half = step(PWM_STOP, 0.08, 1.0, 2.0, effects={"input_delay": 0.0, "rotor_lag": 0.5})
    assert half.truth_speed[k + 20] > lag.truth_speed[k + 20]


def test_input_delay_shifts_response_by_40_ms() -> None:
    def onset(res: SimResult) -> float:
        return float(res.truth_t[np.argmax(res.truth_speed > 0)])

    off = step(PWM_STOP, 0.08, 1.0, 1.5, effects={"input_delay": 0.0})
    on = step(PWM_STOP, 0.08, 1.0, 1.5)
    double = step(PWM_STOP, 0.08, 1.0, 1.5, effects={"input_delay": 2.0})
    assert onset(on) - onset(off) == pytest.approx(0.040, abs=0.0015)
    assert onset(double) - onset(off) == pytest.approx(0.080, abs=0.0015)


def test_esc_deadband_zero_is_linear_from_stop() -> None:
    nominal = step(PWM_STOP, 0.053, 0.0, 2.0)
    linear = step(PWM_STOP, 0.053, 0.0, 2.0, effects={"esc_deadband": 0.0})
    assert nominal.truth_speed[-1] == 0.0
    assert linear.truth_speed[-1] > 10.0
    # full throttle is full duty either way
    a = step(PWM_FULL, PWM_FULL, 0.0, 1.0)
    b = step(PWM_FULL, PWM_FULL, 0.0, 1.0, effects={"esc_deadband": 0.0})
    np.testing.assert_allclose(a.truth_speed, b.truth_speed)


def test_battery_voltage_zero_is_a_stiff_supply() -> None:
    stiff = simulate("constant", 20.0, 0, effects={"battery_voltage": 0.0})
    real = simulate("constant", 20.0, 0)
    assert np.ptp(stiff.truth_voltage) < 1e-9
    assert stiff.truth_voltage[0] == pytest.approx(real.truth_voltage[0])  # open-circuit start
    assert real.truth_voltage[-1] < stiff.truth_voltage[-1] - 0.3  # sag + polarisation + drain
    assert stiff.truth_speed[-1] > real.truth_speed[-1]
    half = simulate("constant", 20.0, 0, effects={"battery_voltage": 0.5})
    assert real.truth_voltage[-1] < half.truth_voltage[-1] < stiff.truth_voltage[-1]


@pytest.mark.parametrize("bench_strength", [0.5, 1.75])
def test_the_recorded_voltage_is_what_the_motor_sees_at_any_battery_strength(bench_strength) -> None:
    """Why ``random_bench.model_strength`` maps every battery_voltage strength to 1: driven by the
    recorded (modulation-free) terminal voltage, the physics model reproduces the bench's speed
    at strength 1 and not at the bench's own strength (the record carries the same scaling)."""
    effects = {e: 1.0 for e in EFFECTS} | {"battery_voltage": bench_strength}
    r = simulate("random_steps", 20.0, 3, effects=effects, soc=0.4)
    supply = (r.truth_t, r.truth_voltage)

    def rms_at(model_strength: float) -> float:
        speed = motor_response(BenchParams(), effects | {"battery_voltage": model_strength},
                               (r.pwm_t, r.pwm), supply, r.truth_t, float(r.truth_voltage[0]))
        return float(np.sqrt(np.mean((speed - r.truth_speed) ** 2)))

    assert model_strength("battery_voltage", bench_strength, BenchParams()) == 1.0
    assert rms_at(1.0) < 0.05  # rad/s: the same physics, the same numbers
    assert rms_at(bench_strength) > 1.0
    assert model_strength("battery_voltage", 0.0, BenchParams()) == 0.0


def test_heating_strength_in_the_model_units_carries_the_thermal_capacity() -> None:
    """Why ``random_bench.model_strength`` scales a heating strength by the bench's thermal
    capacity: a motor with 1/1.5 of it heats 1.5x as fast, which the nominal model reproduces
    exactly with 1.5x the copper coefficient and the thermal resistance that gives the bench's
    time constant (what ``discrepancy --physics`` fits along: ``physics.COMPANIONS``), and not
    with the bench's own strength."""
    import dataclasses

    nominal = BenchParams()
    bench = dataclasses.replace(nominal, motor_thermal_capacity_j_per_k=nominal.motor_thermal_capacity_j_per_k / 1.5)
    model = dataclasses.replace(nominal,
                                motor_thermal_resistance_k_per_w=nominal.motor_thermal_resistance_k_per_w / 1.5)
    cmd = (np.array([0.0, 1.0]), np.array([PWM_STOP, PWM_FULL]))
    t = np.arange(0.0, 120.0, 0.1)
    supply = (np.array([0.0]), np.array([12.0]))
    effects = {e: 0.0 for e in EFFECTS}

    def speed(p: BenchParams, heating: float) -> np.ndarray:
        return motor_response(p, effects | {"motor_heating": heating}, cmd, supply, t, 12.0)

    truth = speed(bench, 0.8)
    assert model_strength("motor_heating", 0.8, bench, nominal) == pytest.approx(1.2)
    np.testing.assert_allclose(speed(model, 1.2), truth, atol=1e-6)  # rad/s: the same physics
    assert np.max(np.abs(speed(model, 0.8) - truth)) > 3.0  # the bench's own strength is not it
    assert np.max(np.abs(speed(nominal, 1.2) - truth)) > 1.0  # nor the CONFIG's time constant
    assert np.max(np.abs(speed(bench, 0.0) - truth)) > 10.0  # and the heating shows at all


def test_motor_heats_under_load_and_loses_speed() -> None:
    hot = simulate("high_load", 90.0, 2)
    cold = simulate("high_load", 90.0, 2, effects={"motor_heating": 0.0})
    amb = hot.params.ambient_temperature_c
    assert hot.truth_temperature[0] == pytest.approx(amb)
    assert hot.truth_temperature[-1] > amb + 20.0
    assert cold.truth_temperature[-1] > amb + 20.0  # still computed with heating off
    assert hot.truth_speed[-1] < cold.truth_speed[-1] - 3.0
    # thermal time constant of minutes: far from its steady state after 10 s
    assert hot.truth_temperature[10_000] < amb + 15.0
    idle = simulate("constant", 30.0, 2, pwm=(np.array([0.0]), np.array([PWM_STOP])))
    assert np.ptp(idle.truth_temperature) < 1e-9


# --- tachometer ---------------------------------------------------------------------------
def test_tach_signal_has_four_edges_per_revolution() -> None:
    res = simulate("constant", 3.0, 5)
    assert res.tach.dtype == np.float32
    assert len(res.tach) == 3 * 20000 and res.tach_rate_hz == 20000.0 and res.tach_t0 == 0.0
    t0, t1 = 1.0, 3.0
    seg = res.tach[int(t0 * res.tach_rate_hz):]
    high = seg > 2.4
    edges = int(np.count_nonzero(high[1:] != high[:-1]))
    revs = res.truth_speed[window(res, t0, t1)].sum() * 1e-3 / (2 * math.pi)
    assert abs(edges - 4 * revs) <= 3
    # beam clear most of the time, two blades of ~10 % each
    assert 0.15 < np.mean(~high) < 0.25
    assert 4.3 < np.median(seg[high]) < 4.7 and np.median(seg[~high]) < 0.6
    # 12-bit ADC over 0..5 V
    lsb = 5.0 / 4096
    np.testing.assert_allclose(seg / lsb, np.round(seg / lsb), atol=1e-3)


def test_tach_steady_when_stopped() -> None:
    res = simulate("stopped", 1.0, 0, pwm=(np.array([0.0]), np.array([PWM_STOP])))
    high = res.tach > 2.4
    assert np.all(high) or np.all(~high)


# --- reproducibility ----------------------------------------------------------------------
ARRAYS = ("pwm_t", "pwm", "battery_t", "battery_adc", "tach", "truth_t", "truth_speed",
          "truth_thrust", "truth_current", "truth_voltage", "truth_temperature", "truth_soc")


def test_same_seed_same_arrays_other_seed_other_noise() -> None:
    a = simulate("random_steps", 4.0, 11)
    b = simulate("random_steps", 4.0, 11)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    c = simulate("constant", 2.0, 11)
    d = simulate("constant", 2.0, 12)
    np.testing.assert_array_equal(c.truth_speed, d.truth_speed)  # same command, same physics
    assert not np.array_equal(c.tach, d.tach)
    assert not np.array_equal(c.battery_adc, d.battery_adc)
    assert not np.array_equal(simulate("random_steps", 4.0, 12).pwm, a.pwm)


def test_result_layout() -> None:
    res = simulate("chirp", 2.5, 0)
    assert res.truth_t[0] == 0.0 and res.battery_t[0] == 0.0 and res.pwm_t[0] == 0.0
    assert len(res.truth_t) == 2500 and len(res.battery_t) == 2500
    np.testing.assert_allclose(np.diff(res.pwm_t), 1 / PWM_FRAME_HZ)
    assert len(res.pwm) == 125
    assert set(res.effects) == set(EFFECTS) and all(v == 1.0 for v in res.effects.values())
    assert res.profile == "chirp" and res.seed == 0 and isinstance(res.params, BenchParams)
    for name in ARRAYS:
        assert np.all(np.isfinite(getattr(res, name))), name
    part = simulate("chirp", 1.0, 0, effects={"rotor_lag": 0.3})
    assert part.effects["rotor_lag"] == 0.3 and part.effects["input_delay"] == 1.0


# --- profiles -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(PROFILES))
def test_profiles_in_range_and_reproducible(name: str) -> None:
    t, lv = make_profile(name, 100.0, 7)
    assert len(t) == len(lv) == 5000
    assert t[0] == 0.0
    assert np.all(lv >= PWM_STOP) and np.all(lv <= PWM_FULL)
    np.testing.assert_array_equal(lv, make_profile(name, 100.0, np.random.default_rng(7))[1])


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_every_profile_starts_by_arming_the_esc(name: str) -> None:
    """A bench run begins with ~1 s of the stop pulse, rotor at rest (ESC arming)."""
    t, lv = make_profile(name, 30.0, 1)
    assert np.all(lv[t < ARMING_S] == PWM_STOP)
    _, short = make_profile(name, 2.0, 1)  # too short to spend a second arming: profile only
    assert len(short) == 100


@pytest.mark.parametrize("seed", range(5))
def test_the_flight_profile_never_stops_the_motor_and_never_holds(seed: int) -> None:
    """One multirotor motor: after arming and a 2 s take-off never below the flight idle (above
    every start level the randomized benches draw), hovering mid-range, moved every frame (the
    attitude loop's dither), with a punch-out near full throttle somewhere in two minutes."""
    from bldc_propulsion.sim.profiles import FLIGHT_IDLE

    t, lv = make_profile("flight", 120.0, seed)
    flying = lv[t >= ARMING_S + 2.0]
    assert flying.min() >= FLIGHT_IDLE and flying.max() >= 0.095
    assert 0.062 <= float(np.median(flying)) <= 0.09
    steps = np.abs(np.diff(flying))
    assert float(np.mean(steps > 1e-4)) > 0.8  # moved in most frames (held only where clipped)


def test_profile_shapes() -> None:
    _, st = make_profile("staircase", 120.0, 0)
    assert st.min() == pytest.approx(PWM_STOP) and st.max() == pytest.approx(PWM_FULL)
    assert len(np.unique(np.round(st, 4))) == 11
    arm = int(ARMING_S * 50)
    t, tri = make_profile("triangle", 60.0 + ARMING_S, 0)
    tri = tri[arm:]
    assert tri[0] == pytest.approx(PWM_STOP) and tri[len(tri) // 2] == pytest.approx(PWM_FULL)
    _, const = make_profile("constant", 10.0, 0)
    assert np.all(const[arm:] == 0.085)
    _, hl = make_profile("high_load", 300.0, 0)
    assert np.mean(hl >= 0.095) > 0.9 and hl.min() < 0.085
    t, ch = make_profile("chirp", 200.0, 0)
    # slow at the start, fast at the end: count mean crossings in the first and last 20 s
    mid = 0.5 * (PWM_STOP + PWM_FULL)
    slow = np.convolve(ch[:1000] - mid, np.ones(25) / 25, mode="valid")  # 0.5 s average
    fast = np.convolve(ch[-1000:] - mid, np.ones(3) / 3, mode="valid")
    first = np.count_nonzero(np.diff(np.sign(slow)) != 0)
    last = np.count_nonzero(np.diff(np.sign(fast)) != 0)
    assert first <= 6 and last > 60


# --- bad input ----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"effects": {"propwash": 1.0}}, "propwash"),
        ({"effects": {"rotor_lag": -0.1}}, "rotor_lag"),
        ({"effects": {"input_delay": float("nan")}}, "input_delay"),
        ({"effects": {"motor_heating": float("inf")}}, "motor_heating"),
        ({"effects": {"spin_down_asymmetry": 1.5}}, "spin_down_asymmetry"),
        ({"soc": 0.0}, "--soc"),
        ({"soc": 1.01}, "--soc"),
        ({"soc": float("nan")}, "--soc"),
        ({"duration_s": 0.0}, "--duration"),
        ({"duration_s": -3.0}, "--duration"),
        ({"duration_s": float("inf")}, "--duration"),
        ({"duration_s": float("nan")}, "--duration"),
        ({"profile": "sawtooth"}, "sawtooth"),
        ({"seed": -1}, "--seed"),
        ({"pwm": (np.array([0.0, 1.0]), np.array([0.06]))}, "pwm"),
        ({"pwm": (np.array([0.0, np.nan]), np.array([0.06, 0.07]))}, "pwm"),
        ({"pwm": (np.array([1.0, 0.0]), np.array([0.06, 0.07]))}, "pwm"),
    ],
)
def test_bad_inputs_raise_naming_the_item(kwargs: dict, needle: str) -> None:
    args = {"profile": "constant", "duration_s": 1.0, "seed": 0} | kwargs
    with pytest.raises(BadInputError, match=needle.replace("-", r"\-")):
        simulate(**args)


def test_unknown_profile_lists_known_ones() -> None:
    with pytest.raises(BadInputError) as err:
        make_profile("sawtooth", 10.0, 0)
    assert "sawtooth" in str(err.value) and all(name in str(err.value) for name in PROFILES)


def test_unknown_effect_lists_known_ones() -> None:
    with pytest.raises(BadInputError) as err:
        simulate("constant", 1.0, 0, effects={"propwash": 1.0})
    assert all(name in str(err.value) for name in EFFECTS)


def test_params_with_overrides() -> None:
    base = BenchParams()
    p = params_with_overrides(base, {"winding_resistance_ohm": 0.25, "battery_cells": 4})
    assert p.winding_resistance_ohm == 0.25 and p.battery_cells == 4 and base.winding_resistance_ohm == 0.2
    known = r"--param nonsense_ohm: unknown bench parameter \(known: .*motor_kv_rpm_per_v"
    with pytest.raises(BadInputError, match=known):
        params_with_overrides(base, {"nonsense_ohm": 1.0})
    for name, value in [("winding_resistance_ohm", 0.0), ("motor_kv_rpm_per_v", -710.0),
                        ("propeller_ct", float("nan")), ("battery_capacity_ah", float("inf")),
                        ("battery_cells", 2.5), ("tach_noise_v", -0.01)]:
        with pytest.raises(BadInputError, match=f"--param {name}"):
            params_with_overrides(base, {name: value})
    # zero where it makes sense: a noise-free tachometer
    assert params_with_overrides(base, {"tach_noise_v": 0.0}).tach_noise_v == 0.0


def test_param_override_changes_physics() -> None:
    stronger = params_with_overrides(BenchParams(), {"motor_kv_rpm_per_v": 800.0})
    base = step(0.08, 0.08, 0.0, 2.0)
    fast = step(0.08, 0.08, 0.0, 2.0, params=stronger)
    assert fast.truth_speed[-1] > base.truth_speed[-1]


def test_effect_docs_cover_every_effect() -> None:
    assert set(EFFECT_DOCS) == set(EFFECTS)
    assert all(doc.strip() for doc in EFFECT_DOCS.values())


def test_inertia_and_thrust_coefficient_plausible() -> None:
    p = BenchParams()
    assert 1.3e-4 < p.propeller_inertia_kg_m2 < 1.8e-4
    assert p.thrust_coefficient == pytest.approx(
        p.propeller_ct * p.air_density_kg_m3 * p.propeller_diameter_m**4 / (4 * math.pi**2))
    assert 2.0e-5 < p.thrust_coefficient < 4.0e-5


# --- randomized benches (sim.random_bench) ---------------------------------------------------
def test_drawn_benches_span_the_stated_ranges_and_repeat_per_seed() -> None:
    from bldc_propulsion.sim import random_bench as rb

    nominal = BenchParams()
    draws = [rb.draw_bench(seed) for seed in range(40)]
    assert rb.draw_bench(3) == draws[3] and draws[3] != draws[4]
    kv = np.array([p.motor_kv_rpm_per_v for p in draws]) / nominal.motor_kv_rpm_per_v
    inertia = np.array([p.rotor_inertia_kg_m2 for p in draws]) / nominal.rotor_inertia_kg_m2
    start = np.array([PWM_STOP + p.esc_deadband_pwm for p in draws])
    delay = np.array([p.esc_input_delay_s for p in draws])
    assert 0.85 <= kv.min() < 0.93 and 1.07 < kv.max() <= 1.15
    assert 0.7 <= inertia.min() < 0.85 and 1.15 < inertia.max() <= 1.3
    assert 0.052 <= start.min() < 0.054 and 0.056 < start.max() <= 0.058
    assert 0.020 <= delay.min() < 0.030 and 0.050 < delay.max() <= 0.060
    # the motor's thermal time constant (capacity and resistance +-50 % each) and friction
    tau = np.array([p.motor_thermal_capacity_j_per_k * p.motor_thermal_resistance_k_per_w for p in draws])
    tau /= nominal.motor_thermal_capacity_j_per_k * nominal.motor_thermal_resistance_k_per_w
    friction = np.array([p.motor_no_load_current_a for p in draws]) / nominal.motor_no_load_current_a
    assert 0.25 <= tau.min() < 0.6 and 1.5 < tau.max() <= 2.25
    assert 0.5 <= friction.min() < 0.7 and 1.3 < friction.max() <= 1.5
    # structure: some benches bend the throttle map, some have a two-RC pack, some neither
    assert 5 < sum(p.esc_throttle_exponent != 1.0 for p in draws) < 35
    assert 5 < sum(p.battery_polarisation2_resistance_ohm > 0 for p in draws) < 35
    for p in draws:  # the OCV curve keeps rising with charge
        assert np.all(np.diff(p.battery_cell_ocv_v) > 0)
    s = [rb.draw_strength("rotor_lag", k) for k in range(40)]
    assert 0.5 <= min(s) < 0.7 and 1.4 < max(s) <= 2.0
    assert all(0.5 <= rb.draw_strength("spin_down_asymmetry", k) <= 1.0 for k in range(40))


def test_far_benches_are_another_motor_class_sized_by_its_power() -> None:
    """``draw_far_bench``: draw_bench's bench moved to a 3S or 4S pack, a no-load speed of
    0.7-1.4x and a shaft power of 0.5-2x, the propeller's diameter from P ~ w^3 D^5 and the
    winding sized as V^2 / P (so the copper-loss share stays the class's): checked per draw
    against the drawn speed and power recovered from Kv, cells and diameter."""
    from bldc_propulsion.sim import random_bench as rb

    nominal = BenchParams()
    assert rb.draw_far_bench(3) == rb.draw_far_bench(3) and rb.DRAWS["far"] is rb.draw_far_bench
    cells = set()
    for seed in range(30):
        near, far = rb.draw_bench(seed), rb.draw_far_bench(seed)
        volts = far.battery_cells / nominal.battery_cells
        speed = far.motor_kv_rpm_per_v * volts / near.motor_kv_rpm_per_v
        power = speed**3 * (far.propeller_diameter_m / near.propeller_diameter_m) ** 5
        assert 0.7 <= speed <= 1.4 and 0.5 - 1e-9 <= power <= 2.0 + 1e-9
        assert far.winding_resistance_ohm == pytest.approx(near.winding_resistance_ohm * volts**2 / power)
        assert far.motor_thermal_capacity_j_per_k == pytest.approx(near.motor_thermal_capacity_j_per_k * power)
        assert far.esc_input_delay_s == near.esc_input_delay_s  # the ESC and sensors are draw_bench's
        cells.add(far.battery_cells)
    assert cells == {3, 4}


def test_bent_throttle_map_and_second_rc_change_the_physics() -> None:
    """exponent > 1 lowers the mid-throttle speed, not the full-throttle one; a second RC branch
    sags the terminal voltage further under sustained load."""
    bent = params_with_overrides(BenchParams(), {"esc_throttle_exponent": 1.2})
    lin_mid, bent_mid = (step(PWM_STOP, 0.075, 0.0, 3.0, params=p).truth_speed[-1] for p in (BenchParams(), bent))
    lin_full, bent_full = (step(PWM_STOP, PWM_FULL, 0.0, 3.0, params=p).truth_speed[-1] for p in (BenchParams(), bent))
    assert bent_mid < lin_mid - 10.0 and bent_full == pytest.approx(lin_full, abs=0.5)
    two_rc = params_with_overrides(BenchParams(), {"battery_polarisation2_resistance_ohm": 0.03,
                                                   "battery_polarisation2_time_constant_s": 60.0})
    one, two = (simulate("constant", 60.0, 1, params=p) for p in (BenchParams(), two_rc))
    assert two.truth_voltage[-1] < one.truth_voltage[-1] - 0.05
    # a drawn bench simulates, and is another bench (not the nominal speeds)
    from bldc_propulsion.sim import random_bench as rb

    other = step(PWM_STOP, 0.08, 0.0, 3.0, params=rb.draw_bench(1)).truth_speed[-1]
    assert abs(other - step(PWM_STOP, 0.08, 0.0, 3.0).truth_speed[-1]) > 5.0
