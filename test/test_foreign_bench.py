"""The foreign bench (benchmarks/foreign_bench): its recordings read like the project's own, its
physics meets its own analytic steady state, and each hidden-effect switch does what it names."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.foreign_bench import model as m  # noqa: E402
from benchmarks.foreign_bench.draw import draw_bench, full_throttle  # noqa: E402
from benchmarks.foreign_bench.record import write_bag  # noqa: E402
from benchmarks.foreign_bench.scenarios import RESTSTARTS_S, hidden_effect_size, project_scenarios  # noqa: E402
from bldc_propulsion import contract as c  # noqa: E402
from bldc_propulsion.bagio import open_recording  # noqa: E402
from bldc_propulsion.recordings import load_signals  # noqa: E402

#: every effect off except the one a test switches: each test isolates one mechanism
NONE_ON = {e: False for e in m.SWITCHABLE}


def steps(times_levels: list[tuple[float, float]], duration: float) -> tuple[np.ndarray, np.ndarray]:
    """A 50 Hz command: each (start time, level) held until the next; stopped before the first."""
    t = np.arange(0.0, duration, 1.0 / c.PWM_FRAME_HZ)
    u = np.full(len(t), c.PWM_STOP)
    for t0, level in times_levels:
        u[t >= t0 - 1e-9] = level
    return t, u


def run(b: m.ForeignBench, cmd: tuple[np.ndarray, np.ndarray], duration: float, **effects: bool) -> dict:
    return m.integrate(b, cmd[0], cmd[1], duration, 1.0, {**NONE_ON, **effects})


def at(res: dict, t: float) -> float:
    return float(np.interp(t, res["t"], res["speed"]))


def test_bags_load_like_the_projects_and_decode_to_the_truth(tmp_path):
    b = draw_bench(0)
    cmd = steps([(1.0, 0.07), (3.0, 0.09), (5.0, 0.06)], 8.0)
    res = m.simulate(b, *cmd, 8.0, seed=3)
    write_bag(res, tmp_path / "bag")
    with open_recording(tmp_path / "bag") as rec:
        topics = rec.topics()
    assert topics == {**c.INPUT_TOPICS, **c.TRUTH_TOPICS}  # what the project's simulator records
    s = load_signals(tmp_path / "bag")
    truth = np.interp(s.t, res.t, res.speed)
    steady = (s.t > 2.0) & (np.abs(np.gradient(truth, s.t)) < 5.0)
    assert np.sqrt(np.mean((s.speed - truth)[steady] ** 2)) < 0.01 * truth.max()
    # the filtered voltage (the package's 2 s low-pass) settles on the bus voltage
    late = s.t > 7.0
    assert np.median(s.voltage[late]) == pytest.approx(np.median(np.interp(s.t[late], res.t, res.bus_v)), rel=0.03)


@pytest.mark.parametrize("seed", [0, 7, 13])
@pytest.mark.parametrize("level", [0.065, 0.085, 0.10])
def test_steady_speed_matches_the_analytic_torque_balance(seed, level):
    b = draw_bench(seed)
    res = run(b, steps([(0.5, level)], 4.0), 4.0)  # stiff supply, alpha 0: the balance is exact
    duty = float(m.duty_of_level(b, np.array(level), deadband=False))
    want = m.steady_speed(b, duty, m.pack_ocv(b, 1.0))
    assert want > 0.0
    assert at(res, 4.0) == pytest.approx(want, rel=0.01)


def test_coasting_spins_down_slower_than_braking():
    b = draw_bench(1)
    cmd = steps([(0.5, 0.10), (2.5, 0.06)], 4.0)
    brake, coast = run(b, cmd, 4.0), run(b, cmd, 4.0, spin_down_asymmetry=True)
    assert at(brake, 2.5) == pytest.approx(at(coast, 2.5), rel=1e-6)  # identical spin-up
    assert at(coast, 2.8) > at(brake, 2.8) + 0.05 * at(brake, 2.5)
    assert np.min(coast["current"]) >= 0.0 and np.min(brake["current"]) < 0.0


def test_deadband_keeps_the_rotor_at_rest_below_the_start_level():
    b = draw_bench(2)
    below = 0.5 * (c.PWM_STOP + b.start_level)
    cmd = steps([(0.5, below)], 3.0)
    assert np.max(run(b, cmd, 3.0, esc_deadband=True)["speed"]) == 0.0
    assert at(run(b, cmd, 3.0), 3.0) > 0.0
    above = steps([(0.5, b.start_level + 0.002)], 3.0)
    assert at(run(b, above, 3.0, esc_deadband=True), 3.0) > 0.0


@pytest.mark.parametrize("seed", [100, 102, 103])  # rotors at rest within 10 s of PWM 0.075 (85 % of benches)
def test_reststarts_start_every_low_level_from_rest_and_cover_every_band(seed):
    """The foreign esc_deadband experiment (scenarios.OWN_EXPERIMENT) shows a start level only if
    each level starts from rest and the lowest levels are there; the project's lowstarts finds
    these coasting rotors still turning."""
    T = project_scenarios()
    b = draw_bench(seed)
    cmd = T.command("reststarts", RESTSTARTS_S, seed)
    res = run(b, cmd, RESTSTARTS_S, spin_down_asymmetry=True)  # a coasting ESC: the slowest stop
    onsets = np.flatnonzero(np.diff(cmd[1]) > 0) + 1
    levels = cmd[1][onsets]
    assert len(onsets) >= T.RESTSTART_STRATA
    # one level in each band of 0.05-0.075 (the command rounds levels to 1e-4)
    edges = c.PWM_STOP + 0.025 * np.arange(T.RESTSTART_STRATA + 1) / T.RESTSTART_STRATA
    first = np.sort(levels[:T.RESTSTART_STRATA])
    assert np.all((first >= edges[:-1] - 5e-5) & (first <= edges[1:] + 5e-5))
    assert max(at(res, cmd[0][k]) for k in onsets) < 1.0
    short = T.command("lowstarts", 30.0, seed)
    coasting = run(b, short, 30.0, spin_down_asymmetry=True)
    assert max(at(coasting, short[0][k]) for k in np.flatnonzero(np.diff(short[1]) > 0) + 1) > 50.0


def test_hidden_effect_size_is_what_the_effect_does_to_the_measured_speed():
    """The judge's size of a hidden effect: nothing for a start level no command lies below (the
    commands' levels are 1e-4 apart, the stop level 0.05 is no drive either way), tens of rad/s for
    one in the middle of the low levels, and nothing for the control."""
    b = draw_bench(103)
    assert hidden_effect_size("esc_deadband", 103, dataclasses.replace(b, start_level=c.PWM_STOP + 1e-4)) == 0.0
    assert hidden_effect_size("esc_deadband", 103, dataclasses.replace(b, start_level=0.07)) > 30.0
    assert hidden_effect_size("control", 103, b) == 0.0


def test_input_delay_starts_the_response_after_the_dead_time():
    b = draw_bench(3)
    cmd = steps([(1.0, 0.08)], 1.5)
    for on, delay in ((True, b.dead_time_s), (False, b.esc_frame_s)):
        res = run(b, cmd, 1.5, input_delay=on)
        moving = res["t"][res["speed"] > 0.0]
        assert moving[0] == pytest.approx(1.0 + delay, abs=2 * m.STEP_S)


def test_heating_raises_the_winding_temperature_and_slows_the_rotor():
    b = draw_bench(4)
    cmd = steps([(0.5, 0.10)], 60.0)
    cold, warm = run(b, cmd, 60.0), run(b, cmd, 60.0, motor_heating=True)
    rise = warm["temperature_c"][-1] - b.ambient_c
    assert rise > 10.0
    # at the end the resistance is (1 + alpha rise) R: the torque balance at that R
    r_hot = b.r_winding_ohm * (1.0 + m.COPPER_ALPHA_PER_K * rise)
    assert at(warm, 60.0) == pytest.approx(m.steady_speed(b, 1.0, m.pack_ocv(b, 1.0), r_hot), rel=0.01)
    assert at(warm, 60.0) < at(cold, 60.0)


@pytest.mark.parametrize("seed", [4, 46])
def test_full_drive_warm_speed_is_where_the_simulated_winding_levels_off(seed):
    # the thermal time constant shortened to 2 s (the balance does not depend on it): 40 s at full
    # drive on the stiff supply levels the winding off; its speed there is full_drive_speeds' warm
    b = dataclasses.replace(draw_bench(seed), thermal_tau_s=2.0)
    v = m.pack_ocv(b, 1.0)
    cold, warm = m.full_drive_speeds(b, v)
    res = run(b, steps([(0.5, c.PWM_FULL)], 40.0), 40.0, motor_heating=True)
    assert at(res, 40.0) == pytest.approx(warm, rel=2e-3)
    assert cold == pytest.approx(m.steady_speed(b, 1.0, v), rel=1e-9)
    assert 0.01 < 1.0 - warm / cold < 0.2  # a winding that heats by tens of kelvin, not a runaway


def test_battery_sags_under_load_and_the_stiff_supply_does_not():
    b = draw_bench(5)
    cmd = steps([(0.5, 0.10), (3.0, 0.05)], 6.0)
    stiff, pack = run(b, cmd, 6.0), run(b, cmd, 6.0, battery_voltage=True)
    assert np.ptp(stiff["bus_v"]) == 0.0 and stiff["bus_v"][0] == pytest.approx(m.pack_ocv(b, 1.0))
    loaded = np.interp(2.9, pack["t"], pack["bus_v"])
    assert loaded < m.pack_ocv(b, 1.0) - 0.02 * m.pack_ocv(b, 1.0)  # R0 alone draws 3-8 %
    # after the load the RC branches recover slowly: still below the open-circuit voltage
    assert loaded < np.interp(3.5, pack["t"], pack["bus_v"]) < m.pack_ocv(b, pack["soc"][-1])


def test_drawn_benches_are_physically_plausible():
    for seed in range(20):
        b = draw_bench(seed)
        f = full_throttle(b)
        assert 300.0 <= b.kv_rpm_per_v <= 2500.0, seed
        assert 5.0 * 0.0254 <= b.diameter_m <= 15.0 * 0.0254, seed
        assert 300.0 <= f["speed_rad_s"] < 2000.0, (seed, f)  # the tachometer decoder's limit
        assert 3.0 < f["current_a"] < 80.0, (seed, f)
        assert f["tip_speed_m_s"] < 250.0, (seed, f)
        assert 0.6 < b.ke_v_s * f["speed_rad_s"] / m.pack_ocv(b, 1.0) < 0.9, (seed, f)  # loaded / no-load
        assert 60.0 <= b.thermal_tau_s <= 300.0 and 0.005 <= b.dead_time_s <= 0.030
        assert 0.052 <= b.start_level <= 0.058
        assert b.inertia_kg_m2 > 0.0 and b.inductance_h > 0.0
        assert m.pack_ocv(b, 1.0) * b.divider < 10.0  # under the default battery filter's ADC limit
        assert 4.0 < f["current_a"] / b.capacity_ah < 14.0, (seed, f)  # C-rate at full throttle
