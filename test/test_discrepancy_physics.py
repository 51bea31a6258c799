"""`discrepancy --physics`: the bench physics as the model, on simulator data with one effect hidden.

The physics model is the simulator's own motor/rotor/ESC code driven by the recorded command and
the measured (filtered) battery voltage, so (1) it must reproduce the simulator given the true
terminal voltage, (2) calibration must recover a changed Kv/CP, (3) with every effect on but one
in the CONFIG, on recordings made with all on, that one is named first and the holdout RMSE falls
by >= 30 %; with effects off both in the CONFIG and in the recordings, nothing is named.
Recordings and commands are those of test/test_discrepancy.py (its SCENARIOS).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.discrepancy import physics as ph
from bldc_propulsion.discrepancy.workflow import Options, run_physics_workflow
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.physics import config as pc
from bldc_propulsion.physics import fit as pf
from bldc_propulsion.physics import plant
from bldc_propulsion.physics.params import BenchParams, params_with_overrides
from bldc_propulsion.physics.plant import motor_response
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.sim import random_bench as rb
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag

sys.path.insert(0, str(Path(__file__).parent))
from test_discrepancy import SCENARIOS, _bag, cli, command  # noqa: E402

ALL_ON = {name: 1.0 for name in c.EFFECTS}


@pytest.fixture(scope="module")
def bags_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("physics_bags")


def recordings(d: Path, effect: str, effects: dict[str, float] | None = None) -> dict[str, list[str]]:
    """Measured and holdout bags of a SCENARIOS entry (all effects on unless ``effects``)."""
    _, _, meas_spec, hold_spec = SCENARIOS[effect]
    sub = d / effect
    sub.mkdir(exist_ok=True)
    eff = effects or {}
    return {"measured": [_bag(sub, f"measured{k}_{kd}", kd, 500 + k, eff, soc, dur)
                         for k, (kd, soc, dur) in enumerate(meas_spec)],
            "holdout": [_bag(sub, f"holdout{k}_{kd}", kd, 600 + k, eff, soc, dur)
                        for k, (kd, soc, dur) in enumerate(hold_spec)]}


def physics_run(model: pc.PhysicsConfig, paths: dict[str, list[str]], **kw) -> dict:
    opts = Options(max_effects=kw.pop("max_effects", 1), **kw)
    return run_physics_workflow(model, [load_signals(p) for p in paths["measured"]], [],
                                [load_signals(p) for p in paths["holdout"]], opts, lambda m: None).data


# --- the model is the simulator --------------------------------------------------------------------
@pytest.mark.parametrize("step_s, max_err", [(0.001, 0.5), (pc.PHYSICS_STEP_S, 5.0)])
def test_motor_response_reproduces_the_simulator(step_s, max_err):
    res = simulate("steps", 20.0, 3, pwm=command("steps", 20.0, 3))
    p = dataclasses.replace(BenchParams(), sim_step_s=step_s)
    w = motor_response(p, ALL_ON, (res.pwm_t, res.pwm), (res.truth_t, res.truth_voltage), res.truth_t, 12.0)
    err = w - res.truth_speed
    assert np.max(np.abs(err)) < max_err, np.max(np.abs(err))
    assert np.sqrt(np.mean(err**2)) < max_err / 4


def test_calibration_recovers_changed_kv_cp_throttle_map_and_pack_resistance(tmp_path):
    nominal = BenchParams()
    true = params_with_overrides(nominal, {"motor_kv_rpm_per_v": 1.1 * nominal.motor_kv_rpm_per_v,
                                           "propeller_cp": 0.9 * nominal.propeller_cp,
                                           "esc_throttle_exponent": 1.15,
                                           "battery_series_resistance_ohm":
                                               0.55 * nominal.battery_series_resistance_ohm})
    res = simulate("steps", 30.0, 4, params=true, pwm=command("steps", 30.0, 4))
    write_sim_bag(res, tmp_path / "bag")
    s = load_signals(tmp_path / "bag")
    model = pc.PhysicsConfig(pc.load_config(None).params, dict(ALL_ON)).with_supply([s])
    fit = pf.calibrate_base(model, pf.Data.of([s]))
    got = fit.model.constants()
    assert got["motor_kv_rpm_per_v"] == pytest.approx(true.motor_kv_rpm_per_v, rel=0.03)
    assert got["propeller_cp"] == pytest.approx(true.propeller_cp, rel=0.05)
    assert got["esc_throttle_exponent"] == pytest.approx(1.15, rel=0.03)
    # the pack's series resistance, from the seconds after each step while the battery filter's
    # 2 s low-pass still lags the terminal voltage
    assert got["battery_series_resistance_ohm"] == pytest.approx(true.battery_series_resistance_ohm, rel=0.15)
    # a start a rounding error away from the anchor calibrates the same (scipy's trust radius
    # starts at ||x0||: unshifted, it was 1e-16 here and the constants never moved)
    anchor = np.array(list(model.constants().values())) * (1.0 + 1e-15)
    again = pf.calibrate(model, pf.Data.of([s]), anchor, pf.LOG_RANGE_BASE).model.constants()
    for name, value in got.items():
        assert again[name] == pytest.approx(value, rel=1e-3)
    # held (as after a reference fit): the map stays the model's, straight, and Kv and CP make up
    # for it as best they can (a worse fit), with no column to refit per fold and no fit flag
    held = pf.calibrate_base(model, pf.Data.of([s]), hold=pf.HELD_AFTER_REFERENCE)
    assert held.model.params.esc_throttle_exponent == 1.0 and held.log_range[2] == 0.0
    assert held.model.params.battery_series_resistance_ohm == nominal.battery_series_resistance_ohm
    assert not held.J[:, 2:4].any() and held.J[:, :2].any() and held.sse > 1.5 * fit.sse
    assert [f.quantity for f in pf.fit_flags(held, model, "held")] == []
    # with battery_voltage off the model does not use R_s: it stays the CONFIG's, not fitted, and
    # no flag (a zero column let the solver walk it to its bound, where a later fit found it)
    stiff = model.with_effect("battery_voltage", 0.0)
    off = pf.calibrate_base(stiff, pf.Data.of([s]))
    assert off.model.params.battery_series_resistance_ohm == nominal.battery_series_resistance_ohm
    assert not off.J[:, 3].any() and off.J[:, :3].any()
    assert "battery_series_resistance_ohm" not in [f.quantity for f in pf.fit_flags(off, stiff, "off")]
    assert "battery_series_resistance_ohm" in pf.inert_constants(stiff, pf.Data.of([s]))
    assert pf.inert_constants(stiff, pf.Data.of([s]), ("battery_voltage",)) == set()


def test_reference_fit_recovers_a_curved_throttle_map(tmp_path):
    """An ESC mapping duty = 0.45 x + 0.55 x^2 (a foreign bench's kind of map): the map's curvature,
    fitted on a linear scale with the CALIBRATED constants (``pf.MAP_SHAPE``), is recovered and
    Kv with it; with the power law alone the exponent meets the map at two levels only, Kv
    stands in for the rest and the fit is worse."""
    true = params_with_overrides(BenchParams(), {"esc_throttle_curvature": 0.55})
    res = simulate("steps", 30.0, 4, params=true, pwm=command("steps", 30.0, 4))
    write_sim_bag(res, tmp_path / "bag")
    data = pf.Data.of([load_signals(tmp_path / "bag")])
    model = pc.PhysicsConfig(pc.load_config(None).params, dict(ALL_ON)).with_supply(data.signals)
    curved = pf.calibrate(model, data, *pf.base_window(model), linear=pf.MAP_SHAPE)
    power = pf.calibrate(model, data, *pf.base_window(model))
    assert curved.model.params.esc_throttle_curvature == pytest.approx(0.55, abs=0.05)
    assert curved.model.params.esc_throttle_exponent == pytest.approx(1.0, abs=0.05)
    assert curved.model.params.motor_kv_rpm_per_v == pytest.approx(true.motor_kv_rpm_per_v, rel=0.03)
    assert power.model.params.esc_throttle_curvature == 0.0 and power.sse > 2.0 * curved.sse
    assert [f.quantity for f in pf.fit_flags(curved, model, "curved")] == []
    # held after the reference like the exponent: a later calibration keeps it (no column)
    again = pf.calibrate_base(curved.model, data, pf.HELD_AFTER_REFERENCE)
    assert again.model.params.esc_throttle_curvature == curved.model.params.esc_throttle_curvature
    assert again.linear == ()


@pytest.mark.parametrize("braking_removed", [0.0, 1.0])
def test_the_base_fits_whether_the_esc_brakes_or_coasts(braking_removed, tmp_path):
    """An ESC brakes or lets the rotor coast: the base (``pf.BASE_EFFECTS``) fits which, on a
    reference whose CONFIG states neither, with a physical motor. A braking-only base fitted a
    coasting reference with an instantaneous rotor and a Kv hundreds of times the motor's."""
    effects = {"rotor_lag": 1.0, "spin_down_asymmetry": braking_removed}
    res = simulate("steps", 30.0, 7, effects=effects, pwm=command("steps", 30.0, 7))
    write_sim_bag(res, tmp_path / "bag")
    data = pf.Data.of([load_signals(tmp_path / "bag")])
    config = pc.load_config(None).with_supply(data.signals)
    model, switched = pf.with_base_effects(config)
    assert switched == ("rotor_lag", "spin_down_asymmetry")
    fit = pf.fit_reference(model, data, switched=switched)
    assert fit.model.effects["spin_down_asymmetry"] == pytest.approx(braking_removed, abs=0.1)
    assert fit.model.effects["rotor_lag"] == pytest.approx(1.0, rel=0.25)
    # (Kv trades with the free map exponent on speed alone: within 30 %, not the datasheet's 10 %)
    assert fit.model.params.motor_kv_rpm_per_v == pytest.approx(BenchParams().motor_kv_rpm_per_v, rel=0.3)
    # both ends are physical ESCs, not bounds of the fit; the motor is a loaded one
    assert [f.text() for f in pf.fit_flags(fit, config, "reference fit")] == []


def test_reference_fit_moves_a_dead_time_off_the_configs(tmp_path):
    """The dead time acts on the model's 5 ms grid: its strength must still be fitted (a bench with
    58 ms against the CONFIG's 40 ms stayed at 40 ms, and rotor lag took the blame)."""
    nominal = BenchParams()
    true = params_with_overrides(nominal, {"esc_input_delay_s": 1.5 * nominal.esc_input_delay_s})
    res = simulate("steps", 30.0, 6, params=true, pwm=command("steps", 30.0, 6))
    write_sim_bag(res, tmp_path / "bag")
    s = load_signals(tmp_path / "bag")
    model = pc.PhysicsConfig(pc.load_config(None).params, dict(ALL_ON)).with_supply([s])
    fit = pf.fit_reference(model, pf.Data.of([s]))
    # within a grid step (5 ms of the 40 ms per unit strength) of the truth
    assert fit.model.effects["input_delay"] == pytest.approx(1.5, abs=pc.PHYSICS_STEP_S / nominal.esc_input_delay_s)


def test_rotor_lag_is_reported_as_the_time_constant_the_recordings_show(tmp_path):
    """A motor with 2.5x the CONFIG's winding resistance on a propeller with 1/2.5 its drag: the
    same static map (the recordings fix only their product), another split. The inertia fitted
    in the CONFIG's terms is not the bench's, but the spin-up time constant reported with it is
    (``plant.spin_up_time_constant_s`` on the bench itself, at the same speed)."""
    nominal = BenchParams()
    true = params_with_overrides(nominal, {"winding_resistance_ohm": 2.5 * nominal.winding_resistance_ohm,
                                           "propeller_cp": nominal.propeller_cp / 2.5})
    res = simulate("steps", 30.0, 6, params=true, pwm=command("steps", 30.0, 6))
    write_sim_bag(res, tmp_path / "bag")
    s = load_signals(tmp_path / "bag")
    model = pc.PhysicsConfig(pc.load_config(None).params, dict(ALL_ON)).with_supply([s])
    fit = pf.fit_reference(model, pf.Data.of([s]))
    strength = fit.model.effects["rotor_lag"]
    value = ph.fitted_value("rotor_lag", strength, fit.model.params, fit.model.supply_v)
    truth = 1000.0 * plant.spin_up_time_constant_s(true, {"rotor_lag": 1.0}, value["at_speed_rad_s"])
    assert value["time_constant_ms"] == pytest.approx(truth, rel=0.1)
    assert not 0.7 < strength < 1.3  # the inertia in the CONFIG's terms is off by the split
    assert f"spin-up time constant {value['time_constant_ms']:.0f} ms" in ph.describe("rotor_lag", strength, fit.model)


def test_heating_is_fitted_with_the_motors_thermal_time_constant(tmp_path, monkeypatch):
    """A motor that heats twice as fast as the CONFIG's (thermal capacity 0.5x): with heating's
    strength, its COMPANION (the thermal resistance) is fitted, and the strength is the truth in
    the model's units (2: ``random_bench.model_strength``), the thermal time constant the bench's;
    with the thermal resistance held at the CONFIG's, the strength stands in for the time constant
    (1.14 for 2 here) and the fit is worse (3x the SSE)."""
    nominal = BenchParams()
    true = params_with_overrides(nominal, {"motor_thermal_capacity_j_per_k":
                                           0.5 * nominal.motor_thermal_capacity_j_per_k})
    res = simulate("high_load", 180.0, 2, params=true)
    write_sim_bag(res, tmp_path / "bag")
    s = load_signals(tmp_path / "bag")
    model = pc.PhysicsConfig(pc.load_config(None).params, {**ALL_ON, "motor_heating": 0.5}).with_supply([s])
    data = pf.Data.of([s])
    anchor = np.array(list(model.constants().values()))
    fit = pf.calibrate(model, data, anchor, pf.LOG_RANGE_BASE, ("motor_heating",))
    truth = rb.model_strength("motor_heating", 1.0, true, nominal)
    assert truth == pytest.approx(2.0)
    assert fit.model.effects["motor_heating"] == pytest.approx(truth, rel=0.1)
    tau = ph.fitted_value("motor_heating", 1.0, fit.model.params)["thermal_time_constant_s"]
    assert tau == pytest.approx(true.motor_thermal_capacity_j_per_k * true.motor_thermal_resistance_k_per_w, rel=0.3)
    assert fit.companion_anchor == {"motor_thermal_resistance_k_per_w": nominal.motor_thermal_resistance_k_per_w}
    assert fit.J.shape[1] == len(pc.CALIBRATED) + 2 and fit.J[:, -1].any()  # refitted per fold too
    assert f"thermal time constant {tau:.0f} s" in ph.describe("motor_heating", 1.0, fit.model)
    # what the recordings show on any split: the full-drive speed lost once warm, the bench's
    value = ph.fitted_value("motor_heating", fit.model.effects["motor_heating"], fit.model.params, fit.model.supply_v)
    cold, warm = plant.full_drive_speeds(true, {**{n: 0.0 for n in c.EFFECTS}, "motor_heating": 1.0}, model.supply_v)
    assert value["warm_speed_loss_percent"] == pytest.approx(100.0 * (1.0 - warm / cold), rel=0.15)
    monkeypatch.setattr(pf, "COMPANIONS", {})
    held = pf.calibrate(model, data, anchor, pf.LOG_RANGE_BASE, ("motor_heating",))
    assert held.model.effects["motor_heating"] < 1.5 and held.sse > 2.0 * fit.sse


# --- hidden effects --------------------------------------------------------------------------------
@pytest.mark.parametrize("effect", c.EFFECTS)
def test_hidden_effect_is_named_first_and_the_gap_shrinks(effect, bags_dir):
    model = pc.PhysicsConfig(pc.load_config(None).params, {**ALL_ON, effect: 0.0})
    data = physics_run(model, recordings(bags_dir, effect))
    assert data["named"] == [effect], data["evidence"]
    assert data["holdout_rmse_after"] <= 0.7 * data["holdout_rmse_before"], (
        data["holdout_rmse_before"], data["holdout_rmse_after"])
    ev = data["evidence"][effect]
    assert ev["verdict"] == "new" and ev["p_value"] < 0.01
    assert 0.5 <= ev["fitted_parameters"]["strength"] <= 1.5  # nominal 1 in the recordings


def test_control_names_nothing(bags_dir):
    """Dynamic effects and the deadband off in the CONFIG and in the recordings (commands that
    excite them): switching any of them on must not help on held-out blocks."""
    off = {"input_delay": 0.0, "esc_deadband": 0.0, "spin_down_asymmetry": 0.0, "motor_heating": 0.0}
    sub = bags_dir / "control_off"
    sub.mkdir(exist_ok=True)
    paths = {"measured": [_bag(sub, f"m{k}_{kd}", kd, 700 + k, off) for k, kd in
                          enumerate(["steps", "lowsteps", "updown"])],
             "holdout": [_bag(sub, "h0_steps", "steps", 800, off)]}
    model = pc.PhysicsConfig(pc.load_config(None).params, {**ALL_ON, **off})
    data = physics_run(model, paths, max_effects=3)
    assert data["named"] == [], data["evidence"]
    assert data["holdout_rmse_after"] == data["holdout_rmse_before"]


@pytest.mark.xfail(strict=True, reason="a fit that is not physical is no basis for a verdict (issue 11/12): with "
                   "every other effect off, rotor_lag's fit (holdout 65.7 -> 27.1 rad/s) stands strength 0.59, the "
                   "throttle map (exponent 1.65) and Kv in for the missing effects: a full-drive speed 0.23 of the "
                   "no-load speed, so it is flagged and considered, not added")
def test_nominal_bench_names_the_biggest_missing_effect_first(bags_dir):
    """`--physics` without CONFIG (every effect off) on recordings with all on: the first round
    names rotor_lag (a static motor misses every transient) and the holdout error falls by half.
    (All rounds: rotor_lag, spin_down_asymmetry, esc_deadband, input_delay, battery_voltage,
    66 -> 4.2 rad/s on 30 s recordings; too slow for this file, see the report.)"""
    sub = bags_dir / "all_on"
    sub.mkdir(exist_ok=True)
    # 15 s recordings: the limitation (nothing named) is the same at 30 s, at twice the cost
    paths = {"measured": [_bag(sub, f"m{k}_{kd}", kd, 700 + k, {}, duration=15.0) for k, kd in
                          enumerate(["steps", "lowsteps", "updown"])],
             "holdout": [_bag(sub, "h0_steps", "steps", 800, {}, duration=15.0)]}
    data = physics_run(pc.load_config(None), paths)
    assert data["named"] == ["rotor_lag"], data["evidence"]
    assert data["holdout_rmse_after"] <= 0.5 * data["holdout_rmse_before"]


@pytest.mark.parametrize("reference_has_it, verdict", [(False, "new"), (True, "base")])
def test_reference_tells_new_from_structural(reference_has_it, verdict, bags_dir):
    """rotor_lag off in the CONFIG, on in the measured data; the reference recordings (other
    seeds, same commands) without it: new; with it: part of the base physics (a rotor always has
    inertia: fitted on the reference whatever the CONFIG says), its strength there the truth's,
    and the measured data need no other: nothing named."""
    paths = recordings(bags_dir, "rotor_lag")
    sub = bags_dir / "rotor_lag"
    ref = [load_signals(_bag(sub, f"reference{k}_{reference_has_it}", "steps", 900 + k,
                             {} if reference_has_it else {"rotor_lag": 0.0})) for k in range(2)]
    model = pc.PhysicsConfig(pc.load_config(None).params, {**ALL_ON, "rotor_lag": 0.0})
    data = run_physics_workflow(model, [load_signals(p) for p in paths["measured"]], ref,
                                [load_signals(p) for p in paths["holdout"]], Options(max_effects=1),
                                lambda m: None).data
    assert data["no_verdict"] is None
    if verdict == "new":
        assert data["evidence"]["rotor_lag"]["verdict"] == "new", data["evidence"]["rotor_lag"]
        assert data["named"] == ["rotor_lag"]
    else:
        assert data["reference_fit"]["strengths"]["rotor_lag"] == pytest.approx(1.0, abs=0.1)
        assert data["evidence"]["rotor_lag"]["verdict"] != "new" and data["named"] == []
    assert data["structural"] == []


# --- config files and the command line -------------------------------------------------------------
def test_config_defaults_and_errors(tmp_path):
    base = pc.load_config(None)
    assert all(v == 0.0 for v in base.effects.values()) and base.params.sim_step_s == pc.PHYSICS_STEP_S
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"params": {"propeller_cp": 0.05}, "effects": {"rotor_lag": 0.5}}))
    m = pc.load_config(str(cfg))
    assert m.params.propeller_cp == 0.05 and m.effects["rotor_lag"] == 0.5 and m.effects["input_delay"] == 0.0
    for text, word in [("{", "not valid JSON"), ('{"effects": {"warp_drive": 1}}', "warp_drive"),
                       ('{"params": {"motor_kv": 1}}', "motor_kv"), ('{"effects": {"rotor_lag": -1}}', "rotor_lag"),
                       ('{"colour": 1}', "colour"), ('[1]', "JSON object")]:
        cfg.write_text(text)
        with pytest.raises(BadInputError, match=word) as exc:
            pc.load_config(str(cfg))
        assert str(cfg) in str(exc.value) and "\n" not in str(exc.value)


@pytest.mark.parametrize("text, word", [("{not json", "not valid JSON"),
                                        ('{"effects": {"warp_drive": 1}}', "warp_drive")])
def test_cli_bad_config_is_a_one_line_error(text, word, bags_dir, tmp_path):
    cfg = tmp_path / "bad.json"
    cfg.write_text(text)
    proc = cli("discrepancy", "--physics", str(cfg), "--measured", recordings(bags_dir, "rotor_lag")["measured"][0])
    assert proc.returncode == 2, proc.stderr
    assert word in proc.stderr and str(cfg) in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("flag", [["--hidden", "5"], ["--max-epochs", "10"], ["--seed", "1"]])
def test_cli_network_flags_are_refused_with_physics(flag, bags_dir):
    """Options of the network's retraining mean nothing to the physics model: refused, not ignored."""
    proc = cli("discrepancy", "--physics", "--measured", recordings(bags_dir, "rotor_lag")["measured"][0], *flag)
    assert proc.returncode == 2, proc.stderr
    assert flag[0] in proc.stderr and "--model" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


def test_cli_json_output_and_round_trip(bags_dir, tmp_path):
    paths = recordings(bags_dir, "rotor_lag")
    cfg = tmp_path / "base.json"
    cfg.write_text(json.dumps({"effects": {**ALL_ON, "rotor_lag": 0.0}}))
    out = tmp_path / "found.json"
    proc = cli("discrepancy", "--physics", str(cfg), "--measured", *paths["measured"], "--holdout", *paths["holdout"],
               "--max-effects", "1", "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    for key in ("named", "structural", "holdout_rmse_before", "holdout_rmse_after", "windows", "evidence", "model"):
        assert key in data
    assert data["named"] == ["rotor_lag"] and data["model"] == str(out)
    assert data["evidence"]["rotor_lag"]["p_value"] < 0.01
    # the written config reads back as CONFIG: the fitted model itself
    back = pc.load_config(str(out))
    assert back.config() == data["physics"]
    assert back.effects["rotor_lag"] == pytest.approx(data["evidence"]["rotor_lag"]["fitted_parameters"]["strength"])
    # an existing output is refused without --force, and left as it was
    before = out.read_text()
    again = cli("discrepancy", "--physics", str(cfg), "--measured", *paths["measured"], "-o", str(out))
    assert again.returncode == 2 and "already exists" in again.stderr
    assert out.read_text() == before
    # every effect on (the fitted config): no candidate is left, nothing is named
    full = cli("discrepancy", "--physics", str(out), "--measured", *paths["measured"], "--json")
    assert full.returncode == 0, full.stderr
    assert json.loads(full.stdout)["named"] == []


# --- real thrust-stand logs (../shared/real, read in place) --------------------------------------
REAL = Path(__file__).resolve().parents[2] / "shared" / "real"


@pytest.mark.parametrize("log, expected", [
    # "a 16.8 V supply that sags to 13.7 V at ~10 A": the voltage is what the model lacks
    pytest.param("rcbenchmark_steps_90percent", "battery_voltage", marks=pytest.mark.xfail(
        strict=True, reason="against the nominal bench (Kv 6036, CP 0.00057, throttle exponent 1.46 calibrated vs "
        "710, 0.042, 1: another motor and propeller) battery_voltage scores 32 % on held-out blocks (p = 0.12): not "
        "significant; the start level is named instead (65 %, p = 0.001). Before the throttle map "
        "was calibrated its fit took CP to a bound. A CONFIG of that bench is what the physics path needs")),
    # "optical RPM shows a slow coast-down (ESC without active braking)"
    pytest.param("rcbenchmark_step_coastdown_16v_10in", "spin_down_asymmetry", marks=pytest.mark.xfail(
        strict=True, reason="one 18 s log at 4 Hz, no holdout: spin_down_asymmetry is not significant (p = 0.25); "
        "rotor_lag is proposed (76 %, p = 0.0055) but its fit takes Kv to a bound of its range, so nothing is "
        "named")),
])
def test_real_logs_name_what_their_benches_are_known_for(log, expected, tmp_path):
    """What the logs' own documentation says of their benches is what the workflow finds,
    against the nominal bench physics (another motor and propeller: Kv and CP calibrated)."""
    csv = REAL / f"{log}.csv"
    if not csv.is_file():
        pytest.skip(f"{csv} not found (../shared/real beside the repository)")
    bag = tmp_path / "bag"
    proc = cli("import-csv", str(csv), "-o", str(bag))
    assert proc.returncode == 0, proc.stderr
    proc = cli("discrepancy", "--physics", "--measured", str(bag), "--max-effects", "3", "--json")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert expected in data["named"], data["evidence"]
    assert data["evidence"][expected]["p_value"] < 0.01
    assert data["holdout_rmse_after"] < 0.9 * data["holdout_rmse_before"]
    assert data["holdout_in_sample"]  # one short log each: no separate holdout, and it says so
