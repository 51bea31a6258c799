"""Physics and hybrid predictions start where the data starts: a recording that begins with the
rotor turning (a log cut mid-run) starts the physics from its measured speed, not at rest;
one that begins at rest is predicted exactly as before. Truth: the simulator's speed."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.core import features as F
from bldc_propulsion.core.estimator import MEASURED_SPEED_MAX_AGE_S, START_WINDOW_S, ThrustEstimator
from bldc_propulsion.core.features import start_params
from bldc_propulsion.discrepancy.network import slice_signals
from bldc_propulsion.model import HybridModel, NetworkModel
from bldc_propulsion.physics import config as pc
from bldc_propulsion.physics import params as pp
from bldc_propulsion.physics import plant as pl
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.physics.plant import measured_start_speed
from bldc_propulsion.physics.plant_model import PlantModel
from bldc_propulsion.recordings import Signals, load_signals
from bldc_propulsion.sim import SimResult, simulate
from bldc_propulsion.sim.record import write_sim_bag
from bldc_propulsion.training.evaluate import predict_speed
from bldc_propulsion.training.train import features_of

#: the nominal bench with an actively braking ESC (the bundled bags' bench)
EFFECTS = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": 0.0}
CUT_S = 3.0  #: where the cut recordings begin: the rotor at ~420 rad/s, 2 s after its spin-up
HEAD_S = 0.5  #: the start the error is measured over (a few rotor time constants)


def command() -> tuple[np.ndarray, np.ndarray]:
    """50 Hz frames: 1 s stop, then 0.085 to 4 s, 0.065 to 5.5 s, 0.09 to 7 s (the cut part has
    a step down and a step up after its start)."""
    t = np.arange(0.0, 7.0, 0.02)
    level = np.select([t < 1.0, t < 4.0, t < 5.5], [c.PWM_STOP, 0.085, 0.065], 0.09)
    return t, level


@pytest.fixture(scope="module")
def run() -> SimResult:
    return simulate("steps", 7.0, 3, effects=EFFECTS, soc=0.8, pwm=command())


@pytest.fixture(scope="module")
def full(run: SimResult, tmp_path_factory) -> Signals:
    path = tmp_path_factory.mktemp("start") / "full"
    write_sim_bag(run, path)
    return load_signals(path)


def cut_signals(s: Signals, t0: float) -> Signals:
    """The recording from ``t0`` on, as a bench log started late records it: the battery
    filter's output recorded (it ran before), the tachometer's speed, events from ``t0``."""
    g = s.t >= t0
    (pt, pv), (vt, vv) = s.pwm_events, s.voltage_events
    kp, kv = pt >= t0, vt >= t0
    return dataclasses.replace(s, path=f"{s.path}#from{t0:g}", t=s.t[g], pwm=s.pwm[g], voltage=s.voltage[g],
                               speed=s.speed[g], thrust=None, current=None,
                               pwm_events=(pt[kp], pv[kp]), voltage_events=(vt[kv], vv[kv]))


def truth(run: SimResult, t: np.ndarray, offset: float = 0.0) -> np.ndarray:
    return np.interp(t + offset, run.truth_t, run.truth_speed)


def physics(step_s: float = 0.005) -> PlantModel:
    """The bench's own constants and effects: the simulator's truth as a physics model."""
    return PlantModel(dataclasses.replace(BenchParams(), sim_step_s=step_s), EFFECTS, 12.0)


def hybrid() -> HybridModel:
    rng = np.random.default_rng(7)
    net = NetworkModel((c.INPUT_PHYSICS_SPEED, c.INPUT_PWM_FILTERED), [0.0, 0.0], [650.0, 1.0], -30.0, 30.0,
                       rng.normal(size=(3, 2)), rng.normal(size=3), rng.normal(size=3) / 3, 0.0)
    return HybridModel(physics(), net)


def at_rest(model, sig: Signals) -> np.ndarray:
    """The prediction as it was before: the physics started at rest whatever the recording."""
    return predict_speed(model, sig, features_of(sig, model.input_names, start_params(model.feature_params(), 0.0)))


def head_errors(pred: np.ndarray, want: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """(error at the first grid time, RMSE over the first HEAD_S), rad/s."""
    err = pred - want
    head = t < t[0] + HEAD_S
    return float(err[0]), float(np.sqrt(np.mean(err[head] ** 2)))


# --- the trust rule --------------------------------------------------------------------------
@pytest.mark.parametrize("speeds, gap, want", [
    ([0.0] * 8, 0.01, 0.0),  # at rest
    ([3.0, 2.5, 4.0, 3.0, 3.5], 0.01, 0.0),  # below REST_SPEED_RAD_S: rest
    ([600.0, 602.0, 598.0, 601.0, 599.0, 600.0], 0.01, 600.0),  # turning: the first sample
    ([1800.0, 600.0, 602.0, 598.0, 601.0], 0.01, 600.0),  # a lone spike first: the next sample
    ([500.0, 550.0, 600.0, 650.0, 700.0], 0.01, 500.0),  # spinning up 10 % per sample: still agrees
    ([600.0, 50.0, 1500.0, 900.0, 10.0], 0.01, 0.0),  # no three agree: not trusted, rest
    ([600.0, math.nan, 600.0, 600.0, 600.0], 0.01, 0.0),  # a gap in the measurement
    ([600.0] * 5, 0.5, 0.0),  # measured from 0.5 s after the first command: not the physics' start
    ([600.0] * 3, 0.01, 0.0),  # too few samples to tell
])
def test_measured_start_speed_trusts_only_agreeing_samples_at_the_start(speeds, gap, want):
    t = 10.0 + gap + 0.01 * np.arange(len(speeds))
    assert measured_start_speed(t, np.array(speeds), 10.0) == want


# --- (a) a recording cut mid-run, offline ------------------------------------------------------
@pytest.mark.parametrize("make", [physics, hybrid], ids=["physics", "hybrid"])
def test_cut_recording_starts_from_the_measured_speed(make, run, full):
    """Known truth: the simulator's speed. Started at rest the prediction is wrong by the whole
    speed at t = 0 (423 rad/s) and by 215 rad/s RMS over the first 0.5 s; started from the
    measured speed, by 0.1-0.3 rad/s and 0.8-1.2 rad/s RMS (the model's own error)."""
    model, sig = make(), cut_signals(full, CUT_S)
    want = truth(run, sig.t)
    w0 = want[0]
    before = head_errors(at_rest(model, sig), want, sig.t)
    after = head_errors(predict_speed(model, sig), want, sig.t)
    assert w0 > 400.0
    assert abs(before[0]) > 0.8 * w0 and before[1] > 150.0
    assert abs(after[0]) < 2.0 and after[1] < 2.0  # 2.4 with the supply current started at 0
    # 3 s on the two agree again, but for the heat and the filtered supply current of the spin-up
    # the rest start invents (~1 rad/s): the physics forgets where it started
    late = sig.t > sig.t[0] + 3.0
    np.testing.assert_allclose(predict_speed(model, sig)[late], at_rest(model, sig)[late], atol=2.0)


def cut_run(run: SimResult, t0: float) -> SimResult:
    """The simulated run from ``t0`` on, as a bench that started recording late writes it."""
    k = int(math.ceil((t0 - run.tach_t0) * run.tach_rate_hz - 1e-9))
    p, b, tr = run.pwm_t >= t0, run.battery_t >= t0, run.truth_t >= t0
    return dataclasses.replace(
        run, pwm_t=run.pwm_t[p], pwm=run.pwm[p], battery_t=run.battery_t[b], battery_adc=run.battery_adc[b],
        tach_t0=run.tach_t0 + k / run.tach_rate_hz, tach=run.tach[k:],
        **{f: getattr(run, f)[tr] for f in ("truth_t", "truth_speed", "truth_thrust", "truth_current",
                                            "truth_voltage", "truth_temperature", "truth_soc")})


def test_cut_bag_end_to_end(run, tmp_path):
    """A bag written from t = 3 s (load_signals decodes its tachometer and filters its battery
    ADC from the cut on): the physics starts from the decoded speed. The battery filter starts
    on the cut's first ADC sample, ESC modulation and all, so the voltage it gives starts up to
    ~1 V off for its 2 s time constant: the first 0.5 s keep 11 rad/s RMS of that (204 from
    rest), the first grid time 2 rad/s (423 from rest)."""
    part = cut_run(run, CUT_S)
    write_sim_bag(part, tmp_path / "cut")
    sig = load_signals(tmp_path / "cut")
    offset = float(part.pwm_t[0] - sig.pwm_events[0][0])  # the bag's clock starts at its first message
    want = truth(run, sig.t, offset)
    model = physics()
    before = head_errors(at_rest(model, sig), want, sig.t)
    after = head_errors(predict_speed(model, sig), want, sig.t)
    assert abs(before[0]) > 0.8 * want[0] and abs(after[0]) < 0.03 * want[0]
    assert after[1] < 0.2 * before[1]


def test_discrepancy_physics_starts_from_the_measured_speed(run, full):
    """The discrepancy workflow's physics (its own batch path on the gridded voltage) too: a fit
    on a cut recording is not bent by a spin-up that never happened."""
    sig = cut_signals(full, CUT_S)
    model = pc.PhysicsConfig(dataclasses.replace(BenchParams(), sim_step_s=0.005), EFFECTS, 12.0)
    want = truth(run, sig.t)
    err0, rmse = head_errors(model.predict(sig), want, sig.t)
    assert abs(err0) < 0.02 * want[0] and rmse < 6.0  # (Data.residual, the fits' residual, is this)


# --- (b) a recording that starts at rest: nothing changes ------------------------------------------
def motor_response_at_rest(params, effects, pwm_events, supply, t_out, v_ref, supply_tau_s=0.0, hold_supply=False,
                           initial_speed=0.0):
    """``plant.motor_response`` as it was before it took a start speed (the reference): the rotor
    at rest at the first command, PWM_STOP before it, no supply current filtered yet."""
    assert initial_speed == 0.0  # a recording from rest asks for no start speed
    eff = pp.resolve_effects(effects)
    cmd_t, cmd = (np.asarray(a, dtype=float) for a in pwm_events)
    t0 = min(float(cmd_t[0]), float(t_out[0]))
    dt = params.sim_step_s
    n = int(math.ceil((float(t_out[-1]) - t0) / dt - 1e-9)) + 1
    step_t = t0 + np.arange(n) * dt
    sup_t, sup_v = (np.asarray(a, dtype=float) for a in supply)
    sp = pl.Supply.of(params, eff, v_ref, float(supply_tau_s))
    volts = pl.held(sup_t, sup_v, step_t) if hold_supply else np.interp(step_t, sup_t, sup_v)
    source = (sp.v_ref + sp.strength * (volts - sp.v_ref)).tolist()
    duty = pl.esc_duty(params, eff, cmd_t, cmd, step_t).tolist()
    step = pl.make_step(params, eff, sp.source_resistance_ohm)
    w, temp, ib_lp, speed = 0.0, params.ambient_temperature_c, 0.0, [0.0] * n
    for k in range(n):
        speed[k], w, i, temp = step(w, temp, duty[k], source[k] + sp.source_resistance_ohm * ib_lp)
        ib_lp += sp.lowpass_gain * (duty[k] * i - ib_lp)
    return np.interp(t_out, step_t, speed)


@pytest.mark.parametrize("make", [physics, hybrid], ids=["physics", "hybrid"])
def test_recording_from_rest_is_predicted_bit_for_bit_as_before(make, run, full, monkeypatch):
    """evaluate's path and the discrepancy physics give the very numbers of the batch path as
    it was (the reference above), and the estimator fed the measured speed (0: at rest) those of
    one fed none."""
    model = make()
    assert measured_start_speed(full.t, full.speed, full.pwm_events[0][0]) == 0.0
    now = predict_speed(model, full)
    plant = pc.PhysicsConfig(dataclasses.replace(BenchParams(), sim_step_s=0.005), EFFECTS, 12.0)
    now_ph = plant.predict(full)
    monkeypatch.setattr(F, "motor_response", motor_response_at_rest)
    monkeypatch.setattr(pc, "motor_response", motor_response_at_rest)
    assert np.array_equal(now, predict_speed(model, full), equal_nan=True)
    assert np.isfinite(now).mean() > 0.95 and np.nanmax(now) > 400.0
    assert np.array_equal(now_ph, plant.predict(full))
    monkeypatch.undo()
    rest = full.t <= full.t[0] + 1.0  # the stop pulse: the tachometer says 0
    fed, est = streamed(model, full, list(zip(full.t[rest].tolist(), full.speed[rest].tolist(), strict=True)))
    assert np.array_equal(fed, streamed(model, full)[0], equal_nan=True) and est.speed_accepted == rest.sum()


def test_a_part_of_a_recording_runs_its_physics_from_the_recording_start(full):
    """The discrepancy workflow's slices keep the events from the recording's start (the physics
    runs through the history, rotor at rest at the first command): no start speed for them."""
    part = slice_signals(full, CUT_S, 6.0, "part")
    assert measured_start_speed(part.t, part.speed, part.pwm_events[0][0]) == 0.0
    model = physics()
    np.testing.assert_array_equal(predict_speed(model, part), at_rest(model, part))


def test_network_inputs_are_untouched(full):
    net = hybrid().network
    sig = cut_signals(full, CUT_S)
    names = [c.INPUT_PWM_FILTERED]
    params = net.feature_params()
    assert F.with_measured_start(names, params, sig.t, sig.speed, sig.pwm_events[0]) is params


# --- (c), (d) the live core ------------------------------------------------------------------------
def streamed(model, sig: Signals, speeds: Sequence[tuple[float, float]] = ()) -> tuple[np.ndarray, ThrustEstimator]:
    """The estimator fed the recording's events and ``speeds`` (t, rad/s) in time order (a speed
    before an input at the same time), asked at every grid time."""
    est = ThrustEstimator(model)
    ev = sorted([(t, 1, x) for t, x in zip(*map(np.ndarray.tolist, sig.pwm_events), strict=True)]
                + [(t, 2, x) for t, x in zip(*map(np.ndarray.tolist, sig.voltage_events), strict=True)]
                + [(t, 0, x) for t, x in speeds]
                + [(t, 3, 0.0) for t in sig.t.tolist()])
    out = []
    for t, kind, x in ev:
        if kind == 0:
            est.update_speed(t, x)
        elif kind == 1:
            est.update_pwm(t, x)
        elif kind == 2:
            est.update_voltage(t, x)
        else:
            out.append(est.predict(t).speed_rad_s)
    return np.array(out), est


@pytest.mark.parametrize("make", [physics, hybrid], ids=["physics", "hybrid"])
def test_live_core_given_the_measured_speed_equals_evaluate(make, full):
    """(c) batch == stream from the same start speed; (d) the live core starts from it."""
    model, sig = make(), cut_signals(full, CUT_S)
    t_cmd = float(sig.pwm_events[0][0])
    w0 = measured_start_speed(sig.t, sig.speed, t_cmd)
    stream, est = streamed(model, sig, [(t_cmd - 0.005, w0)])
    batch = predict_speed(model, sig)
    ok = np.isfinite(batch)
    assert ok.mean() > 0.95 and np.array_equal(ok, np.isfinite(stream))
    assert np.max(np.abs(batch[ok] - stream[ok])) < 1e-9
    assert est.physics_starts_measured == 1 and est.status()[0].values["physics_starts_measured"] == "1"


def test_live_core_starts_from_the_measured_speed_and_only_then():
    model = physics()
    est = ThrustEstimator(model)
    est.update_voltage(9.9, 11.5)
    est.update_speed(9.95, 612.0)
    est.update_pwm(10.0, 0.085)
    assert est.predict(10.0).speed_rad_s == 612.0  # the state at the first command
    later = est.predict(10.3).speed_rad_s
    est.update_speed(10.31, 100.0)  # a measurement after the start is never used
    assert est.predict(10.3).speed_rad_s == later and est.physics_starts_measured == 1
    # no measured speed, or one too old or at rest: at rest at the first command, as before
    for speeds in ([], [(10.0 - MEASURED_SPEED_MAX_AGE_S - 0.01, 612.0)], [(9.99, 2.0)]):
        e = ThrustEstimator(model)
        for t, w in speeds:
            e.update_speed(t, w)
        e.update_voltage(9.9, 11.5)
        e.update_pwm(10.0, 0.085)
        assert e.predict(10.0).speed_rad_s == 0.0 and e.physics_starts_measured == 0
    # bad samples are refused and counted
    assert not est.update_speed(10.4, math.nan) and not est.update_speed(10.4, -5.0)
    assert not est.update_speed(10.2, 600.0) and est.speed_rejected == 3  # older than the latest


def test_live_core_takes_a_measured_speed_that_comes_just_after_the_first_command(full):
    """The tachometer's first speed needs a batch and a revolution: arriving within
    START_WINDOW_S of the first command it still starts the physics, which is rebuilt from the
    inputs since; from then on the core predicts as if it had come first."""
    model, sig = physics(), cut_signals(full, CUT_S)
    t_cmd = float(sig.pwm_events[0][0])
    w0 = measured_start_speed(sig.t, sig.speed, t_cmd)
    first, _ = streamed(model, sig, [(t_cmd - 0.005, w0)])
    late, est = streamed(model, sig, [(t_cmd + 0.6 * START_WINDOW_S, w0)])
    after = sig.t >= t_cmd + 0.6 * START_WINDOW_S
    assert est.physics_starts_measured == 1
    assert np.max(np.abs(first[after] - late[after])) < 1e-9
    too_late, est = streamed(model, sig, [(t_cmd + 2.0 * START_WINDOW_S, w0)])
    assert est.physics_starts_measured == 0 and too_late[-1] == pytest.approx(first[-1], abs=1.0)


def test_live_core_restarts_the_physics_from_the_measured_speed():
    """After a stall of the commands (the node's pwm_timeout_s) the physics starts again at the
    next command from the measured speed; a network model has nothing to restart."""
    est = ThrustEstimator(physics())
    est.update_voltage(0.0, 11.5)
    est.update_pwm(0.0, 0.09)
    assert est.predict(2.0).speed_rad_s > 400.0
    est.update_speed(5.0, 0.0)  # meanwhile the ESC stopped the rotor (failsafe)
    est.restart_physics()
    est.update_pwm(5.01, 0.09)
    assert est.predict(5.01).speed_rad_s == 0.0  # from the measured rest, not from 475 rad/s
    assert est.predict(7.0).speed_rad_s > 400.0
    net = ThrustEstimator(NetworkModel((c.INPUT_PWM_FILTERED,), [0.0], [1.0], 0.0, 600.0, np.ones((2, 1)),
                                       np.zeros(2), np.ones(2), 0.0))
    net.update_pwm(0.0, 0.08)
    w = net.predict(1.0).speed_rad_s
    net.update_speed(1.0, 300.0)
    net.restart_physics()
    assert net.predict(1.0).speed_rad_s == w


# --- the node ------------------------------------------------------------------------------------
def test_node_takes_rotor_speed(tmp_path):
    """The estimator node subscribes to rotor/speed and its physics starts from it."""
    from _ros import require_rclpy

    rclpy = require_rclpy()
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import BatteryState
    from std_msgs.msg import Float64

    from bldc_propulsion.model import save_model
    from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode

    path = tmp_path / "physics.npz"
    save_model(physics(), path)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = ThrustEstimatorNode(context=ctx, parameter_overrides=[Parameter("model_path", value=str(path))])
        try:
            assert node.measured_speed_sub.topic_name == "/rotor/speed"
            node.on_speed(Float64(data=640.0), None)
            volts = BatteryState(voltage=11.5)
            volts.header.stamp = node.get_clock().now().to_msg()
            node.on_voltage(volts)
            node.on_pwm(Float64(data=0.085), None)
            t = node.core.features.pwm_t
            assert node.core.predict(t).speed_rad_s == 640.0 and node.core.physics_starts_measured == 1
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_real_log_cut_mid_run_starts_from_its_measured_speed(tmp_path):
    """A real thrust-stand log (esc_test: F80 Pro 1900 kv, 7 in propeller, 16 V supply), its last
    third imported as a recording (it starts at ~1640 rad/s): the physics starts from the
    measured speed, whatever its constants (here rough ones for that motor)."""
    import csv
    import io

    from bldc_propulsion.training.import_csv import import_csv

    log = Path(__file__).resolve().parents[2] / "shared" / "real" / "esc_test" / "Log_2019-11-09_181347.csv"
    rows = list(csv.reader(io.StringIO(log.read_text(encoding="utf-8-sig"), newline="")))
    col = [h.strip() for h in rows[0]].index("Time (s)")
    part = tmp_path / "part.csv"
    with open(part, "w", encoding="utf-8", newline="") as fh:
        csv.writer(fh).writerows([rows[0], *(r for r in rows[1:] if r[col].strip() and float(r[col]) >= 75.8)])
    import_csv(part, tmp_path / "part")
    sig = load_signals(tmp_path / "part")
    rough = dataclasses.replace(BenchParams(), sim_step_s=0.002, motor_kv_rpm_per_v=1900.0, propeller_diameter_m=0.178)
    model = PlantModel(rough, EFFECTS, 16.0, supply_tau_s=0.0)  # the log's supply measured directly
    w0 = sig.speed[0]
    assert w0 > 1500.0 and measured_start_speed(sig.t, sig.speed, sig.pwm_events[0][0]) == w0
    assert abs(predict_speed(model, sig)[0] - w0) < 0.01 * w0
    assert abs(at_rest(model, sig)[0] - w0) > 0.99 * w0
