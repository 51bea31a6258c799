"""The health monitor where users look: the thrust_estimator node (parameter ``health``),
``replay --health`` and ``evaluate --health``, against ``bldc-propulsion health`` and the simulator's
truth; and replay feeding a recorded rotor/speed (a log without tachometer/adc) to the estimator.

The flight: the nominal bench (an actively braking ESC) under random steps, a 10 % propeller loss
injected at ONSET_S (sim/faults.py), the model the bench's own physics (healthy). The recording
holds what the estimator node takes during ``ros2 bag play``: pwm, battery/voltage (the battery
filter's output at its 20 Hz) and rotor/speed (the simulator's true speed with a 0.2 % noise, at
50 Hz), as an imported log does; so replay, the health command and the node see the same inputs
and must name the same change at the same onset.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
from pathlib import Path

import numpy as np
import pytest

from _models import good_model
from _replay_corpus import _write
from bldc_propulsion import cli
from bldc_propulsion import contract as c
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.core.battery_filter import BatteryFilter, BatteryFilterConfig
from bldc_propulsion.model import save_model
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.physics.plant_model import PlantModel
from bldc_propulsion.replay import replay_bag
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.faults import Fault

EFFECTS = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": 0.0}
#: the monitor arms after its healthy reference (20 s), a window (5 s) and 10 s of learning
LOSS, ONSET_S, DURATION_S, SEED = 0.1, 40.0, 48.0, 8
T0_S = 100.0  #: the node's clock at the recording's start (s)
SPEED_RATE_HZ, VOLTAGE_EVERY = 50.0, 50  #: rotor/speed rate; battery/voltage = every 50th 1 kHz sample


def measured_streams(res, start_s: float = 0.0) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """pwm, battery/voltage and rotor/speed of a simulated run from ``start_s`` on (times from it)."""
    v = BatteryFilter(BatteryFilterConfig()).process(res.battery_t, res.battery_adc)
    k = np.arange(0, len(v), VOLTAGE_EVERY)
    k = k[np.isfinite(v[k]) & (res.battery_t[k] >= start_s)]
    t_speed = np.arange(start_s + 0.005, res.truth_t[-1], 1.0 / SPEED_RATE_HZ)
    w = np.interp(t_speed, res.truth_t, res.truth_speed)
    w = w * (1.0 + np.random.default_rng(3).normal(0.0, 0.002, len(w)))
    p = res.pwm_t >= start_s
    return [(c.TOPIC_PWM, res.pwm_t[p] - start_s, res.pwm[p]),
            (c.TOPIC_BATTERY_VOLTAGE, res.battery_t[k] - start_s, v[k]),
            (c.TOPIC_ROTOR_SPEED, t_speed - start_s, w)]


@pytest.fixture(scope="module")
def flight(tmp_path_factory) -> Path:
    """The models and the faulted recording (pwm, battery/voltage, rotor/speed; no raw topics)."""
    d = tmp_path_factory.mktemp("health_live")
    save_model(PlantModel(dataclasses.replace(BenchParams(), sim_step_s=0.005), EFFECTS, 12.0), d / "physics.npz")
    save_model(good_model(), d / "network.npz")
    res = simulate("random_steps", DURATION_S, SEED, effects=EFFECTS, soc=0.8,
                   faults=[Fault("propeller_damage", LOSS, ONSET_S)])
    _write(d / "faulted", measured_streams(res))  # ties in time: pwm, voltage, speed (as health merges)
    return d


def level(status) -> int:
    """A DiagnosticStatus' level as a number (rclpy gives a byte, rosbags an int)."""
    return status.level if isinstance(status.level, int) else int.from_bytes(status.level, "little")


def run_json(capsys, *args: str) -> dict:
    assert cli.main([*[str(a) for a in args], "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def run_text(capsys, *args: str) -> str:
    assert cli.main([str(a) for a in args]) == 0
    return capsys.readouterr().out


@pytest.fixture(scope="module")
def offline(flight) -> dict:
    """``health --json`` on the recording (the reference the others must equal; module scope, so
    stdout is captured here rather than by capsys)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli.main(["health", "--model", str(flight / "physics.npz"), str(flight / "faulted"), "--json"]) == 0
    (rec,) = json.loads(buf.getvalue())["recordings"]
    return rec


def test_the_health_command_names_the_injected_loss(offline):
    (e,) = offline["events"]
    assert e["name"] == "propeller_damage" and e["unit"] == "fraction"
    assert abs(e["onset_s"] - ONSET_S) <= 0.5 and ONSET_S <= e["detected_s"] <= ONSET_S + 5.0, e
    assert e["size"] == pytest.approx(LOSS, abs=0.03), e


def test_replay_health_gives_the_health_commands_events_and_diagnostics(flight, offline, tmp_path, capsys):
    d = flight
    info = run_json(capsys, "replay", d / "faulted", "-o", tmp_path / "out", "--model", d / "physics.npz", "--health")
    assert info["health"]["events"] == offline["events"]  # the same code on the same inputs: equal
    assert info["health"]["monitored_s"] == offline["monitored_s"]
    # the seconds each channel tested: the same in both, none beyond what was monitored
    assert info["health"]["tested_s"] == offline["tested_s"]
    assert set(offline["tested_s"]) == {"speed", "voltage"}
    assert 0.0 < offline["tested_s"]["speed"] <= offline["monitored_s"] + 1.0
    assert info["health"]["threshold"] == offline["threshold"]
    (final,) = [s for s in info["status"] if s["name"] == "health"]
    e = offline["events"][0]
    assert final["level"] == 2 and final["values"]["effect"] == "propeller_damage"
    assert float(final["values"]["onset_s"]) == pytest.approx(e["onset_s"], abs=1e-5)  # (6 digits)
    assert final["values"]["unit"] == "fraction"
    # the written recording: the estimator node's diagnostics with the health status, once a second,
    # OK until the change is found, then WARN while it is named, then ERROR naming it
    with open_recording(tmp_path / "out") as rec:
        diag = [(t, s) for _, t, m in rec.messages([c.TOPIC_DIAGNOSTICS]) for s in m.status
                if s.name == "thrust_estimator: health"]
    assert len(diag) == pytest.approx(DURATION_S, abs=2)
    levels = [level(s) for _, s in diag]
    times = np.array([t for t, _ in diag])
    assert set(np.array(levels)[times < e["detected_s"]]) == {0}
    assert levels[-1] == 2 and set(levels) <= {0, 1, 2} and levels == sorted(levels)
    last = {kv.key: kv.value for kv in diag[-1][1].values}
    assert last["effect"] == "propeller_damage" and float(last["onset_s"]) == pytest.approx(e["onset_s"], abs=1e-5)
    assert {"size", "unit", "detected_s"} <= set(last)
    # the text: a line per change, as the health command prints it
    text = run_text(capsys, "replay", d / "faulted", "-o", tmp_path / "out2", "--model", d / "physics.npz",
                    "--health")
    health_text = run_text(capsys, "health", "--model", d / "physics.npz", d / "faulted")
    event_lines = [ln.strip() for ln in health_text.splitlines() if "propeller_damage" in ln]
    assert len(event_lines) == 1 and event_lines[0] in [ln.strip() for ln in text.splitlines()], text


def test_replay_health_reference_path_gives_the_same_events(flight, offline, tmp_path):
    """Every message in turn (the reference path) and the bulk path feed the monitor alike."""
    info = replay_bag(flight / "faulted", tmp_path / "ref", model_path=flight / "physics.npz", health=True,
                      reference=True)
    assert info["health"] is not None and info["health"]["events"] == offline["events"]


def test_evaluate_health_gives_the_health_commands_events(flight, offline, capsys):
    d = flight
    data = run_json(capsys, "evaluate", "--model", d / "physics.npz", d / "faulted", "--health")
    (rec,) = data["health"]
    assert rec["events"] == offline["events"]
    text = run_text(capsys, "evaluate", "--model", d / "physics.npz", "--model", d / "network.npz",
                    d / "faulted", "--health")
    assert sum("propeller_damage" in ln for ln in text.splitlines()) == 1
    assert "not run: a network model has no physics" in text


def test_replay_starts_the_physics_from_a_recorded_rotor_speed(tmp_path):
    """A log cut at speed (rotor/speed, no tachometer/adc): the physics' first prediction is the
    measured speed, not rest (it was rest before the recorded speed reached the estimator)."""
    res = simulate("random_steps", 8.0, 3, effects=EFFECTS, soc=0.8)
    start = float(res.truth_t[np.argmax(res.truth_speed > 300.0)]) + 0.5  # turning fast by then
    streams = measured_streams(res, start)
    _write(tmp_path / "cut", streams)
    save_model(PlantModel(dataclasses.replace(BenchParams(), sim_step_s=0.005), EFFECTS, 12.0), tmp_path / "m.npz")
    info = replay_bag(tmp_path / "cut", tmp_path / "out", model_path=tmp_path / "m.npz")
    (est,) = [s for s in info["status"] if s["name"] == "thrust estimator"]
    assert est["values"]["physics_starts_measured"] == "1"
    with open_recording(tmp_path / "out") as rec:
        t, w = rec.scalars(c.TOPIC_PREDICTED_SPEED)
    measured = float(np.interp(t[0], streams[2][1], streams[2][2]))
    truth = float(np.interp(t[0] + start, res.truth_t, res.truth_speed))
    print(f"first prediction {w[0]:.1f} rad/s, measured {measured:.1f}, truth {truth:.1f}")
    assert truth > 300.0 and w[0] == pytest.approx(truth, rel=0.03)


# --- refusals: one line, before any work ----------------------------------------------------------

@pytest.mark.parametrize("case, words", [
    ("replay network", ["--model", "network.npz", "physics or hybrid"]),
    ("replay fallback", ["--health needs --model"]),
    ("evaluate network", ["--health", "network.npz", "physics or hybrid"]),
])
def test_refusals_are_one_line(flight, tmp_path, capsys, case, words):
    d = flight
    args = {"replay network": ["replay", d / "faulted", "-o", tmp_path / "o", "--model", d / "network.npz", "--health"],
            "replay fallback": ["replay", d / "faulted", "-o", tmp_path / "o", "--health"],
            "evaluate network": ["evaluate", "--model", d / "network.npz", d / "faulted", "--health"]}[case]
    assert cli.main([str(a) for a in args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]
    assert not (tmp_path / "o").exists()


# --- the node -------------------------------------------------------------------------------------

def test_node_names_the_fault_on_diagnostics_as_replay(flight, offline, start_node):
    from _ros import require_rclpy

    require_rclpy()
    from diagnostic_msgs.msg import DiagnosticArray

    from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode

    d = flight
    h = start_node(ThrustEstimatorNode, model_path=str(d / "physics.npz"), health=True)
    diagnostics = h.record(DiagnosticArray, c.TOPIC_DIAGNOSTICS_ABSOLUTE)
    topics = (c.TOPIC_PWM, c.TOPIC_BATTERY_VOLTAGE, c.TOPIC_ROTOR_SPEED)
    with open_recording(d / "faulted") as rec:
        events = [(t, k, float(m.voltage if k == 1 else m.data))
                  for topic, t, m in rec.messages(list(topics)) for k in [topics.index(c.bare(topic))]]
    h.feed_estimator(events, T0_S)
    h.drain()

    health = [(h_t, {kv.key: kv.value for kv in s.values}, s) for msg in diagnostics
              for h_t in [msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9]
              for s in msg.status if s.name.endswith("thrust_estimator: health")]
    assert len(health) >= DURATION_S - 2
    e = offline["events"][0]
    assert all(level(s) == 0 for t, _, s in health if t < T0_S + e["detected_s"])  # nothing before
    t_last, values, s = health[-1]
    assert level(s) == 2, (s.message, values)
    assert values["effect"] == "propeller_damage" and values["unit"] == "fraction"
    onset, detected = float(values["onset_s"]), float(values["detected_s"])
    print(f"node: {s.message}; onset {onset - T0_S:.2f} s, found {detected - T0_S:.2f} s (truth {ONSET_S})")
    assert abs(onset - (T0_S + ONSET_S)) <= 0.5 and detected - onset <= 5.0
    # the offline result's onset and time of finding, on the node's clock: the same code on the
    # same inputs, but 100 s + t rounds otherwise than t, and the monitor's 0.1 s blocks start at
    # its first sample, so a sample on a block's edge (here every fifth) may fall in the next one:
    # within a block, and an evaluation (2 blocks) for the finding
    assert onset == pytest.approx(T0_S + e["onset_s"], abs=0.1 + 1e-6)
    assert detected == pytest.approx(T0_S + e["detected_s"], abs=0.2 + 1e-6)
    assert 0.0 < float(values["size"]) < 0.3


def test_node_refuses_health_without_physics_in_one_line(flight, context, capsys):
    from _ros import require_rclpy

    require_rclpy()
    from rclpy.parameter import Parameter

    from bldc_propulsion.errors import BadInputError
    from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode, main

    with pytest.raises(BadInputError, match="parameter health: model_path .*network.npz.*physics or hybrid"):
        ThrustEstimatorNode(context=context, parameter_overrides=[
            Parameter("model_path", value=str(flight / "network.npz")), Parameter("health", value=True)])
    for model in (str(flight / "network.npz"), "''"):  # a network; '' = the fallback
        status = main(["thrust_estimator", "--ros-args", "-p", f"model_path:={model}", "-p", "health:=true"])
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1 and "parameter health" in err[0], err
