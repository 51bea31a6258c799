"""The online adaptation (core/adaptation.py) wired into ``replay --adapt`` and the thrust_estimator
node (parameter ``adapt``), on a short simulated recording with a known propeller loss injected
mid-flight (sim/faults.py). The model is the simulated bench's own physics, healthy: the injected
loss is the truth the adapted propeller value must reach, and before the onset it must stay near 0.
The node is fed what replay fed its estimator (the recording's pwm, the battery/voltage and
rotor/speed replay published) and must publish what replay wrote.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _models import good_model
from bldc_propulsion import contract as c
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.core.adaptation import ADAPTED, ADAPTED_LABEL
from bldc_propulsion.model import load_model, save_model
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.physics.plant_model import PlantModel
from bldc_propulsion.replay import replay_bag
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.faults import Fault
from bldc_propulsion.sim.record import write_sim_bag

ROOT = Path(__file__).resolve().parents[1]
#: the bench simulated: nominal constants, an actively braking ESC (the model below is exactly it)
EFFECTS = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": 0.0}
LOSS, ONSET_S, DURATION_S = 0.2, 2.0, 10.0
T0_S = 100.0  #: the node's clock at the recording's start (s)


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    """A directory with the physics model (the bench's truth), a network model, the faulted
    recording and its ``replay --adapt`` (the API; the command line is judged below)."""
    d = tmp_path_factory.mktemp("adaptation_node")
    save_model(PlantModel(dataclasses.replace(BenchParams(), sim_step_s=0.005), EFFECTS, 12.0), d / "physics.npz")
    save_model(good_model(), d / "network.npz")
    res = simulate("random_steps", DURATION_S, 5, effects=EFFECTS, soc=0.8,
                   faults=[Fault("propeller_damage", LOSS, ONSET_S)])
    write_sim_bag(res, d / "faulted")
    return d


@pytest.fixture(scope="module")
def replayed(flight) -> dict:
    """``replay --adapt --save-adapted --json`` on the faulted recording: its JSON."""
    d = flight
    proc = cli("replay", str(d / "faulted"), "-o", str(d / "adapted"), "--model", str(d / "physics.npz"),
               "--adapt", "--save-adapted", str(d / "adapted.npz"), "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=300)


def adapted_messages(bag: Path) -> tuple[np.ndarray, np.ndarray, list]:
    """predicted/adapted of a recording: times (s from its start), values (n, 2), the messages."""
    with open_recording(bag) as rec:
        msgs = list(rec.messages([c.TOPIC_PREDICTED_ADAPTED]))
    return (np.array([t for _, t, _ in msgs]), np.array([list(m.data) for _, _, m in msgs]),
            [m for _, _, m in msgs])


# --- replay ---------------------------------------------------------------------------------------

def test_replay_adapt_follows_the_loss_and_writes_predicted_adapted(flight, replayed):
    d, ad = flight, replayed["adaptation"]
    loss = ad["parameters"]["propeller_damage"]
    friction = ad["parameters"]["bearing_friction"]
    assert (loss["unit"], friction["unit"]) == ("fraction", "factor")
    assert loss["value"] == pytest.approx(LOSS, abs=0.04), ad  # the truth
    assert 0.0 < loss["sigma"] < 0.1 and ad["updates"] > 100
    assert ad["in_use"] is True  # the loss followed: the adapted model scores better than the offline
    with open_recording(d / "adapted") as rec:
        assert rec.topics()[c.TOPIC_PREDICTED_ADAPTED] == c.FLOAT64_ARRAY
        speeds = rec.count(c.TOPIC_ROTOR_SPEED)
    t, values, msgs = adapted_messages(d / "adapted")
    # one message per measured speed the estimator took (all of them here), named in order
    assert len(msgs) == ad["updates"] + ad["frozen_samples"] == speeds
    assert ADAPTED_LABEL == "propeller_damage,bearing_friction,pack_resistance"
    assert all([(x.label, x.size, x.stride) for x in m.layout.dim] == [(ADAPTED_LABEL, 3, 3)] for m in msgs)
    # the pack's resistance: 10 s of steps do not tell it (its sigma stays above a fifth of the
    # model's): not known, null in the JSON, NaN on the topic (test_adaptation: a longer flight)
    pack = ad["parameters"]["pack_resistance"]
    assert pack == {"value": None, "sigma": None, "unit": "ohm"}
    assert values[-1, :2].tolist() == [loss["value"], friction["value"]] and np.isnan(values[:, 2]).all()
    assert np.abs(values[t < ONSET_S, 0]).max() < 0.03  # healthy before the onset: nothing to adapt
    assert values[t > ONSET_S + 3.0, 0].min() > 0.75 * LOSS  # followed within 3 s
    # the bulk path and the reference (every message in turn) write the same values
    replay_bag(d / "faulted", d / "reference", model_path=d / "physics.npz", adapt=True, reference=True)
    t_ref, values_ref, _ = adapted_messages(d / "reference")
    assert np.array_equal(t_ref, t) and np.array_equal(values_ref, values, equal_nan=True)


def test_save_adapted_scales_the_propeller_by_the_adapted_loss(flight, replayed):
    ad = replayed["adaptation"]
    assert ad["saved"] == str(flight / "adapted.npz")
    loss = ad["parameters"]["propeller_damage"]["value"]
    offline, adapted = load_model(flight / "physics.npz"), load_model(flight / "adapted.npz")
    assert adapted.kind == c.PHYSICS
    assert adapted.params.propeller_cp == pytest.approx(offline.params.propeller_cp * (1.0 - loss), rel=1e-12)
    ct_loss = max(loss, 0.0)  # CT and b follow a loss only
    assert adapted.params.propeller_ct == pytest.approx(offline.params.propeller_ct * (1.0 - ct_loss), rel=1e-12)
    assert adapted.thrust_coefficient == pytest.approx(offline.thrust_coefficient * (1.0 - ct_loss), rel=1e-12)
    friction = ad["parameters"]["bearing_friction"]["value"]
    assert (adapted.params.motor_no_load_current_a > offline.params.motor_no_load_current_a) == (friction > 1.0)
    assert adapted.metadata["adapted"]["propeller_damage"]["value"] == loss


def test_replay_without_adapt_writes_no_adaptation(flight):
    info = replay_bag(flight / "faulted", flight / "plain", model_path=flight / "physics.npz")
    assert info["adaptation"] is None
    with open_recording(flight / "plain") as rec:
        assert not rec.has(c.TOPIC_PREDICTED_ADAPTED)


@pytest.mark.parametrize("case, words", [
    ("network", ["--model", "network.npz", "physics or hybrid"]),
    ("fallback", ["--adapt needs --model"]),
    ("save without adapt", ["--save-adapted", "needs --adapt"]),
    ("existing save", ["exists.npz", "already exists", "--force"]),
    ("save not npz", ["--save-adapted", ".npz"]),
])
def test_replay_refusals_are_one_line_before_any_work(flight, tmp_path, case, words):
    d = flight
    (tmp_path / "exists.npz").write_bytes((d / "physics.npz").read_bytes())
    args = {"network": ["--model", str(d / "network.npz"), "--adapt"],
            "fallback": ["--adapt"],
            "save without adapt": ["--model", str(d / "physics.npz"), "--save-adapted", str(tmp_path / "a.npz")],
            "existing save": ["--model", str(d / "physics.npz"), "--adapt",
                              "--save-adapted", str(tmp_path / "exists.npz")],
            "save not npz": ["--model", str(d / "physics.npz"), "--adapt",
                             "--save-adapted", str(tmp_path / "a.json")]}[case]
    proc = cli("replay", str(d / "faulted"), "-o", str(tmp_path / "out"), *args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]
    assert not (tmp_path / "out").exists()  # refused before any work


# --- the node -------------------------------------------------------------------------------------

def test_node_adapts_publishes_predicted_adapted_as_replay_and_diagnoses(flight, replayed, start_node):
    from _ros import require_rclpy

    require_rclpy()
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray

    from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode

    d = flight
    h = start_node(ThrustEstimatorNode, model_path=str(d / "physics.npz"), adapt=True)
    received = h.record(Float64MultiArray, c.TOPIC_PREDICTED_ADAPTED)
    h.record(DiagnosticArray, c.TOPIC_DIAGNOSTICS_ABSOLUTE)
    events = []  # (s from the start, kind, value): what replay's estimator took, in its order
    with open_recording(d / "faulted") as rec:
        events += [(t, 0, float(m.data)) for _, t, m in rec.messages([c.TOPIC_PWM])]
    with open_recording(d / "adapted") as rec:  # (replay writes with the input's start time)
        events += [(t, 1, float(m.voltage)) for _, t, m in rec.messages([c.TOPIC_BATTERY_VOLTAGE])]
        events += [(t, 2, float(m.data)) for _, t, m in rec.messages([c.TOPIC_ROTOR_SPEED])]
    events.sort(key=lambda e: e[:2])
    h.feed_estimator(events, T0_S)
    h.spin_until(lambda: bool(h.received[c.TOPIC_DIAGNOSTICS_ABSOLUTE]))
    h.drain()

    t_ref, values_ref, _ = adapted_messages(d / "adapted")
    live = np.array([list(m.data) for m in received])
    assert all([(x.label, x.size) for x in m.layout.dim] == [(ADAPTED_LABEL, len(ADAPTED))] for m in received)
    assert len(live) == len(values_ref)  # one per measured speed, as replay
    # toward the truth: nothing before the onset, the injected loss at the end
    assert np.abs(live[t_ref < ONSET_S, 0]).max() < 0.03
    assert live[-1, 0] == pytest.approx(LOSS, abs=0.04)
    assert np.array_equal(np.isnan(live), np.isnan(values_ref))
    err = np.nanmax(np.abs(live - values_ref))
    print(f"predicted/adapted live - replay: max {err:.2e}")
    # the same code on the same inputs; the times differ by float rounding (100 s + t), which the
    # RLS carries on (~2e-6 here): far below the loss's own sigma (~0.03)
    assert err < 1e-4
    values = [dict(kv) for msg in h.received[c.TOPIC_DIAGNOSTICS_ABSOLUTE] for s in msg.status
              for kv in [[(v.key, v.value) for v in s.values]] if "adaptation" in dict(kv)]
    assert values, "the estimator's status carries the adaptation"
    last = values[-1]
    assert last["adaptation"] == "on" or last["adaptation"].startswith("frozen")
    assert math.isclose(float(last["adapted_propeller_damage"]), live[-1, 0], rel_tol=1e-5)  # (6 digits)
    assert "adapted_bearing_friction_sigma" in last
    assert last["adapted_in_use"] == "True"  # as replay says at the end of the same flight


def test_node_refuses_adapt_for_a_network_in_one_line(flight, context, capsys):
    from _ros import require_rclpy

    require_rclpy()
    from rclpy.parameter import Parameter

    from bldc_propulsion.errors import BadInputError
    from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode, main

    with pytest.raises(BadInputError, match="parameter adapt: model_path .*network.npz.*physics or hybrid"):
        ThrustEstimatorNode(context=context, parameter_overrides=[
            Parameter("model_path", value=str(flight / "network.npz")), Parameter("adapt", value=True)])
    status = main(["thrust_estimator", "--ros-args", "-p", f"model_path:={flight / 'network.npz'}",
                   "-p", "adapt:=true"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "parameter adapt" in err[0], err


def test_replay_adapt_prints_each_parameter_and_says_what_is_not_known(flight, tmp_path):
    """The text summary: the speed's parameters with their sigma and unit; the pack's resistance,
    which 10 s of steps do not tell, said not known instead of a number."""
    proc = cli("replay", str(flight / "faulted"), "-o", str(tmp_path / "out"), "--model", str(flight / "physics.npz"),
               "--adapt")
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if "adaptation (" in x)
    assert re.search(r"propeller_damage 0\.\d+ \+/- 0\.\d+ \(fraction\), bearing_friction \d\.\d+ \+/- ", line), line
    assert "pack_resistance not known (the voltage has not shown it)" in line, line
