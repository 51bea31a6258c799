"""b in thrust = b w^2 comes from what was measured or stated, or there is none: no silent number.

Each source against a hand computation (least squares, --thrust-coefficient, hover, CT), the
model file without b, and what has no b downstream: the estimator core, replay, evaluate, the
node (rclpy; skipped without it on a developer machine, required in CI) and the CLI's
one-line errors for options that go together.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from _models import good_model
from _truth_bags import write_bag
from bldc_propulsion import cli
from bldc_propulsion import contract as c
from bldc_propulsion.bagio import BagWriter, open_recording
from bldc_propulsion.core.estimator import NO_THRUST_MESSAGE, ThrustEstimator
from bldc_propulsion.core.status import WARN
from bldc_propulsion.model import load_model, save_model
from bldc_propulsion.physics.fallback import NOMINAL_THRUST_COEFFICIENT, fallback_model
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.physics.plant_model import PlantModel
from bldc_propulsion.priors import add_prior_arguments, priors_from_args
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.replay import replay_bag
from bldc_propulsion.sim import simulate
from bldc_propulsion.training.evaluate import THRUST_NO_COEFFICIENT
from bldc_propulsion.training.train import (
    AIRBORNE_SPEED_FRACTION,
    NO_THRUST_SOURCE,
    ThrustFit,
    fit_thrust_coefficient,
    stated_thrust,
)

G = 9.80665
RHO = 1.225
INCH = 0.0254


def priors(*options: str):
    p = argparse.ArgumentParser()
    add_prior_arguments(p)
    return priors_from_args(p.parse_args(list(options)))


def sig(speed, thrust=None) -> SimpleNamespace:
    """What the thrust fits read of a recording: its speed (rad/s) and measured thrust (N)."""
    return SimpleNamespace(speed=np.asarray(speed, dtype=float),
                           thrust=None if thrust is None else np.asarray(thrust, dtype=float))


# --- each source, by hand -------------------------------------------------------------------

def test_ct_and_diameter_give_b_by_hand():
    fit = stated_thrust(priors("--propeller-ct", "0.11", "--prop-diameter-in", "5"), [])
    assert fit.coefficient == pytest.approx(0.11 * RHO * (5 * INCH) ** 4 / (4 * math.pi**2), rel=1e-12)
    assert fit.source == "CT 0.11, 5 in" and "rho" in fit.assumption
    assert fit.samples == 0 and fit.residual_rms_n is None


def test_stated_b_is_taken_as_given():
    fit = stated_thrust(priors("--thrust-coefficient", "3.5e-6"), [])
    assert (fit.coefficient, fit.source) == (3.5e-6, "stated --thrust-coefficient")
    assert stated_thrust(priors("--motor-kv", "2300", "--prop-diameter-in", "5"), []) is None  # no b stated


def test_hover_gives_b_from_the_airborne_samples_by_hand():
    """On the ground (at rest, idling at 80 rad/s) is not airborne; b = m g / (N mean w^2) over the rest."""
    ground = np.r_[np.zeros(100), np.full(50, 80.0)]
    flight_a = np.r_[ground, np.tile([900.0, 1000.0], 200), ground]
    flight_b = np.r_[np.full(300, 950.0), np.nan, np.zeros(20)]  # a NaN (speed unknown) is no sample
    fit = stated_thrust(priors("--vehicle-mass-kg", "1.2", "--motor-count", "4"), [sig(flight_a), sig(flight_b)])
    mean_w2 = (200 * 900.0**2 + 200 * 1000.0**2 + 300 * 950.0**2) / 700
    assert fit.coefficient == pytest.approx(1.2 * G / (4 * mean_w2), rel=1e-12)
    assert fit.samples == 700
    assert fit.source == "hover: 1.2 kg, 4 motors"
    assert "m g" in fit.assumption and "airborne" in fit.assumption


def test_least_squares_on_measured_thrust_wins_and_a_far_stated_b_is_warned_of():
    w = np.linspace(100.0, 900.0, 200)
    thrust = 2.0e-6 * w**2 + 0.01 * (-1.0) ** np.arange(200)
    expected = float(np.dot(w**2, thrust) / np.dot(w**2, w**2))
    far = fit_thrust_coefficient([sig(w, thrust)], ThrustFit(3.0e-6, None, 0, "stated --thrust-coefficient"))
    assert far.coefficient == pytest.approx(expected, rel=1e-12)
    assert far.source == "least squares on /thrust/measured" and far.samples == 200
    assert far.residual_rms_n == pytest.approx(0.01, rel=0.05)
    assert len(far.warnings) == 1 and "+50 %" in far.warnings[0] and "stated --thrust-coefficient" in far.warnings[0]
    near = fit_thrust_coefficient([sig(w, thrust)], ThrustFit(2.1e-6, None, 0, "CT 0.1, 5 in"))  # 5 % off
    assert near.coefficient == pytest.approx(expected, rel=1e-12) and near.warnings == []


def test_nothing_measured_or_stated_is_no_b():
    none = fit_thrust_coefficient([sig([0.0, 500.0, 700.0])], None)
    assert none.coefficient is None and none.source == NO_THRUST_SOURCE == "none: no thrust measured or stated"
    few = fit_thrust_coefficient([sig([500.0] * 5, [1.0] * 5)], None)  # too few to fit: still none, and said
    assert few.coefficient is None and "too few" in few.warnings[0]
    stated = fit_thrust_coefficient([sig([500.0] * 5, [1.0] * 5)], 2e-6)
    assert stated.coefficient == 2e-6


def test_several_stated_sources_the_first_is_used_and_the_others_named():
    fit = stated_thrust(priors("--thrust-coefficient", "3e-6", "--propeller-ct", "0.11", "--prop-diameter-in", "5"), [])
    assert fit.source == "stated --thrust-coefficient" and fit.coefficient == 3e-6
    assert len(fit.warnings) == 1 and "CT 0.11, 5 in" in fit.warnings[0] and "not used" in fit.warnings[0]


# --- the model file and the estimator core ----------------------------------------------------

def test_a_model_without_b_round_trips(tmp_path):
    net = dataclasses.replace(good_model(), thrust_coefficient=None)
    save_model(net, tmp_path / "net.npz")
    with np.load(tmp_path / "net.npz") as z:
        assert np.isnan(z["thrust_coefficient"])  # stored as NaN
    assert load_model(tmp_path / "net.npz").thrust_coefficient is None
    plant = PlantModel(BenchParams(), dict.fromkeys(c.EFFECTS, 1.0), 12.0, thrust_coefficient=None)
    assert dataclasses.replace(plant, supply_v=11.0).thrust_coefficient is None  # stays without b
    save_model(plant, tmp_path / "plant.npz")
    assert load_model(tmp_path / "plant.npz").thrust_coefficient is None
    # a b, and a physics model's default (its constants' CT), load as before
    save_model(good_model(), tmp_path / "with_b.npz")
    assert load_model(tmp_path / "with_b.npz").thrust_coefficient == NOMINAL_THRUST_COEFFICIENT
    ct = PlantModel(BenchParams(), dict.fromkeys(c.EFFECTS, 1.0), 12.0)
    assert ct.thrust_coefficient == pytest.approx(BenchParams().thrust_coefficient)


def test_the_core_predicts_speed_and_no_thrust_without_b():
    est = ThrustEstimator(dataclasses.replace(good_model(), thrust_coefficient=None))
    est.update_voltage(0.0, 11.5)
    est.update_pwm(0.0, 0.08)
    p = est.predict(0.5)
    assert p.ready and math.isfinite(p.speed_rad_s) and p.thrust_n is None
    thrust = [s for s in est.status() if s.name == "thrust"]
    assert len(thrust) == 1 and thrust[0].level == WARN and thrust[0].message == NO_THRUST_MESSAGE
    stated = ThrustEstimator(dataclasses.replace(good_model(), thrust_coefficient=None), thrust_coefficient=1e-5)
    stated.update_voltage(0.0, 11.5)
    stated.update_pwm(0.0, 0.08)
    q = stated.predict(0.5)
    assert q.thrust_n == pytest.approx(1e-5 * q.speed_rad_s**2, rel=1e-12)
    assert all(s.name != "thrust" for s in stated.status())
    assert ThrustEstimator(fallback_model()).thrust_coefficient == NOMINAL_THRUST_COEFFICIENT  # as before


# --- recordings, replay, evaluate and train through the CLI -------------------------------------

@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("thrust_bags")
    return {"train": write_bag(d / "train", "random_steps", 3, thrust=False),
            "val": write_bag(d / "val", "random_steps", 4, thrust=False),
            "train_thrust": write_bag(d / "train_thrust", "random_steps", 5, thrust=True),
            "val_thrust": write_bag(d / "val_thrust", "random_steps", 6, thrust=True)}


def run_cli(capsys, *args: object) -> tuple[int, str, str]:
    """``bldc-propulsion ARGS`` in this process: exit status, stdout, stderr."""
    try:
        code = cli.main([str(a) for a in args])
    except SystemExit as exc:  # argparse's errors
        code = int(exc.code)
    out = capsys.readouterr()
    return code, out.out, out.err


SMALL = ("--hidden", "3", "--max-epochs", "8", "--restarts", "1")


def train(capsys, bags, out: Path, *options: str, thrust: bool = False) -> tuple[dict, str]:
    tr, va = ("train_thrust", "val_thrust") if thrust else ("train", "val")
    code, stdout, err = run_cli(capsys, "train", bags[tr], "--validation", bags[va], "-o", out, *SMALL,
                                *options, "--json")
    assert code == 0, err
    return json.loads(stdout), err


def test_train_without_thrust_gives_a_model_without_b_and_says_so(capsys, bags, tmp_path):
    code, text, err = run_cli(capsys, "train", bags["train"], "--validation", bags["val"],
                              "-o", tmp_path / "m.npz", *SMALL)
    assert code == 0, err
    assert "  no thrust coefficient (none: no thrust measured or stated): speed only" in text.splitlines()
    assert [w for w in err.splitlines() if w.startswith("warning: no thrust coefficient")]
    model = load_model(tmp_path / "m.npz")
    assert model.thrust_coefficient is None
    assert model.metadata["thrust_fit"]["source"] == "none: no thrust measured or stated"


def test_train_takes_a_stated_b_and_records_where_it_came_from(capsys, bags, tmp_path):
    data, _ = train(capsys, bags, tmp_path / "m.npz", "--thrust-coefficient", "3.5e-6")
    assert data["thrust_coefficient"] == 3.5e-6 and data["thrust_fit"]["source"] == "stated --thrust-coefficient"
    model = load_model(tmp_path / "m.npz")
    assert model.thrust_coefficient == 3.5e-6
    assert model.metadata["thrust_fit"]["source"] == "stated --thrust-coefficient"


def test_train_from_hover_keeps_the_assumption_in_the_model(capsys, bags, tmp_path):
    data, _ = train(capsys, bags, tmp_path / "m.npz", "--vehicle-mass-kg", "1.2", "--motor-count", "4")
    w = load_signals(str(bags["train"])).speed
    w = w[np.isfinite(w)]
    airborne = w[w > AIRBORNE_SPEED_FRACTION * np.percentile(w, 99)]
    assert data["thrust_coefficient"] == pytest.approx(1.2 * G / (4 * np.mean(airborne**2)), rel=1e-9)
    fit = load_model(tmp_path / "m.npz").metadata["thrust_fit"]
    assert fit["source"] == "hover: 1.2 kg, 4 motors" and "m g" in fit["assumption"]


def test_train_fits_measured_thrust_and_warns_when_a_stated_b_disagrees(capsys, bags, tmp_path):
    b_true = BenchParams().thrust_coefficient  # the simulated bench's propeller
    data, err = train(capsys, bags, tmp_path / "m.npz", "--thrust-coefficient", "1e-5", thrust=True)
    assert data["thrust_coefficient"] == pytest.approx(b_true, rel=0.02)
    assert data["thrust_fit"]["source"] == "least squares on /thrust/measured"
    warned = [w for w in err.splitlines() if "the measured thrust gives b" in w]
    assert len(warned) == 1 and "stated --thrust-coefficient" in warned[0]


def test_replay_and_evaluate_have_no_thrust_for_a_model_without_b(capsys, bags, tmp_path):
    save_model(dataclasses.replace(good_model(), thrust_coefficient=None), tmp_path / "no_b.npz")
    info = replay_bag(bags["train_thrust"], tmp_path / "out", model_path=tmp_path / "no_b.npz")
    with open_recording(tmp_path / "out") as rec:
        assert rec.count(c.TOPIC_PREDICTED_SPEED) > 500
        assert not rec.has(c.TOPIC_PREDICTED_THRUST)
    said = [w for w in info["warnings"] if NO_THRUST_MESSAGE in w]
    assert len(said) == 1 and c.TOPIC_PREDICTED_THRUST in said[0]
    # the same model with a b: thrust = b w^2 on every predicted speed
    save_model(good_model(), tmp_path / "b.npz")
    replay_bag(bags["train_thrust"], tmp_path / "out_b", model_path=tmp_path / "b.npz")
    with open_recording(tmp_path / "out_b") as rec:
        _, speed = rec.scalars(c.TOPIC_PREDICTED_SPEED)
        _, thrust = rec.scalars(c.TOPIC_PREDICTED_THRUST)
    np.testing.assert_allclose(thrust, NOMINAL_THRUST_COEFFICIENT * speed**2, rtol=1e-12)

    code, stdout, err = run_cli(capsys, "evaluate", "--model", tmp_path / "no_b.npz", bags["val_thrust"], "--json")
    assert code == 0, err
    data = json.loads(stdout)
    assert data["thrust_coefficient"] is None
    assert data["recordings"][0]["thrust_rmse_n"] is None
    assert data["recordings"][0]["thrust_unavailable"] == THRUST_NO_COEFFICIENT
    code, text, _ = run_cli(capsys, "evaluate", "--model", tmp_path / "no_b.npz", bags["val_thrust"])
    assert "thrust unavailable: the model has no thrust coefficient" in text.splitlines()[0]


@pytest.mark.parametrize("options, words", [
    (["--vehicle-mass-kg", "1.2"], "--vehicle-mass-kg and --motor-count go together"),
    (["--motor-count", "4"], "--vehicle-mass-kg and --motor-count go together"),
    (["--propeller-ct", "0.11"], "--propeller-ct: needs --prop-diameter-in"),
    (["--thrust-coefficient", "-1e-6"], "--thrust-coefficient"),
    (["--thrust-coefficient", "inf"], "--thrust-coefficient"),
    (["--vehicle-mass-kg", "0", "--motor-count", "4"], "--vehicle-mass-kg"),
    (["--motor-count", "2.5", "--vehicle-mass-kg", "1"], "--motor-count"),
    (["--motor-kv", "1900"], "--motor-kv: a prior of the physics fit, so it goes with --kind physics or hybrid"),
    (["--prop-pitch-in", "4.5"], "--prop-pitch-in: a prior of the physics fit"),
])
def test_options_that_go_together_or_out_of_range_are_one_line_errors(capsys, tmp_path, options, words):
    """Checked before any recording is read (the recordings named here do not exist)."""
    code, out, err = run_cli(capsys, "train", tmp_path / "none", "--validation", tmp_path / "nope",
                             "-o", tmp_path / "m.npz", *options)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and words in err, err
    assert not (tmp_path / "m.npz").exists()


def test_hover_on_recordings_where_the_rotor_never_turns_is_a_one_line_error(capsys, tmp_path):
    res = simulate("constant", 2.0, 0)
    with BagWriter(tmp_path / "rest") as bag:  # the rotor at rest: nothing is airborne
        for t, v in zip(res.battery_t[::10], res.battery_adc[::10], strict=True):
            bag.write_float64(c.TOPIC_BATTERY_ADC, float(t), float(v))
        for t in np.arange(0.0, 2.0, 0.02):
            bag.write_float64(c.TOPIC_PWM, float(t), 0.05)
            bag.write_float64(c.TOPIC_ROTOR_SPEED, float(t), 0.0)
    code, _, err = run_cli(capsys, "train", tmp_path / "rest", "--validation", tmp_path / "rest",
                           "-o", tmp_path / "m.npz", "--vehicle-mass-kg", "1.2", "--motor-count", "4")
    assert code == 2 and len(err.strip().splitlines()) == 1, err


# --- the node ------------------------------------------------------------------------------------

def test_node_without_b_publishes_speed_never_thrust_and_says_why(tmp_path):
    from _ros import require_rclpy

    rclpy = require_rclpy()
    from builtin_interfaces.msg import Time as TimeMsg
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import BatteryState
    from std_msgs.msg import Float64

    from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode

    no_b, with_b = tmp_path / "no_b.npz", tmp_path / "b.npz"
    save_model(dataclasses.replace(good_model(), thrust_coefficient=None), no_b)
    save_model(good_model(), with_b)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = ThrustEstimatorNode(context=ctx, parameter_overrides=[
            Parameter("use_sim_time", value=True), Parameter("use_source_timestamps", value=False),
            Parameter("model_path", value=str(no_b))])
        helper = rclpy.create_node("thrust_test_helper", context=ctx)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        executor.add_node(helper)
        got: dict[str, list] = {t: [] for t in (c.TOPIC_PREDICTED_SPEED, c.TOPIC_PREDICTED_THRUST)}
        for topic, box in got.items():
            helper.create_subscription(Float64, topic, box.append, 100)
        diagnostics: list = []
        helper.create_subscription(DiagnosticArray, c.TOPIC_DIAGNOSTICS, diagnostics.append, 100)
        clock = helper.create_publisher(Clock, "/clock", 10)
        pwm = helper.create_publisher(Float64, c.TOPIC_PWM, 10)
        volts = helper.create_publisher(BatteryState, c.TOPIC_BATTERY_VOLTAGE, 10)

        def spin_until(done, timeout_s=10.0):
            deadline = time.monotonic() + timeout_s
            while not done():
                assert time.monotonic() < deadline, "timed out waiting for the node"
                executor.spin_once(timeout_sec=0.01)

        def at(t_s: float) -> TimeMsg:
            return TimeMsg(sec=int(t_s), nanosec=int(round((t_s % 1) * 1e9)))

        def set_time(t_s: float) -> None:
            clock.publish(Clock(clock=at(t_s)))
            spin_until(lambda: node.get_clock().now().nanoseconds >= int(round(t_s * 1e9)))

        spin_until(lambda: pwm.get_subscription_count() > 0 and volts.get_subscription_count() > 0)
        t0 = 100.0
        set_time(t0)
        v = BatteryState(voltage=11.5, present=True)
        v.header.stamp = at(t0)
        volts.publish(v)
        pwm.publish(Float64(data=0.08))
        for k in range(1, 160):
            set_time(t0 + 0.01 * k)
            executor.spin_once(timeout_sec=0.002)
        set_time(t0 + 2.5)
        spin_until(lambda: len(got[c.TOPIC_PREDICTED_SPEED]) > 50 and any(
            NO_THRUST_MESSAGE in s.message for m in diagnostics for s in m.status))
        for _ in range(20):
            executor.spin_once(timeout_sec=0.005)
        assert all(math.isfinite(m.data) and m.data > 0.0 for m in got[c.TOPIC_PREDICTED_SPEED])
        assert got[c.TOPIC_PREDICTED_THRUST] == []
        assert helper.count_publishers(c.TOPIC_PREDICTED_THRUST) == 0  # not even advertised
        why = [s for m in diagnostics for s in m.status if NO_THRUST_MESSAGE in s.message]
        assert all(s.level == DiagnosticStatus.WARN for s in why)
        # a model with b loaded at run time: predicted/thrust appears
        assert node.set_parameters([Parameter("model_path", value=str(with_b))])[0].successful
        spin_until(lambda: helper.count_publishers(c.TOPIC_PREDICTED_THRUST) == 1)
        executor.shutdown()
        node.destroy_node()
        helper.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_discrepancy_writes_a_physics_model_without_the_configs_b(capsys, bags, tmp_path):
    """``discrepancy --physics -o M.npz`` on recordings without thrust never writes the CONFIG's
    (the 12 in bench's) CT as b: no b, and a warning."""
    out = tmp_path / "found.npz"
    code, stdout, err = run_cli(capsys, "discrepancy", "--physics", "--measured", bags["train"], bags["val"],
                                "--max-effects", "1", "-o", out, "--json")
    assert code == 0, err
    data = json.loads(stdout)
    assert data["named"], "every effect is on in the simulator and off in the base: one is named"
    assert load_model(out).thrust_coefficient is None
    assert any("no thrust coefficient" in w for w in data["warnings"])


def test_discrepancys_b_is_measured_else_the_models_else_none(bags):
    """What ``discrepancy`` writes as b: the measured thrust's least squares, else the b of the
    model file it started from, else none."""
    from bldc_propulsion.commands.discrepancy import _thrust_of

    with_thrust = [load_signals(bags["train_thrust"]), load_signals(bags["val_thrust"])]
    w2 = np.concatenate([s.speed**2 for s in with_thrust])
    t = np.concatenate([s.thrust for s in with_thrust])
    ok = np.isfinite(w2) & np.isfinite(t)
    expected = float(np.dot(w2[ok], t[ok]) / np.dot(w2[ok], w2[ok]))
    assert _thrust_of(None, with_thrust).coefficient == pytest.approx(expected, rel=1e-9)
    without = [load_signals(bags["train"])]
    assert _thrust_of(None, without).coefficient is None
    model = SimpleNamespace(thrust_coefficient=3.1e-6)
    kept = _thrust_of(model, without)
    assert kept.coefficient == 3.1e-6 and "model file" in kept.source
