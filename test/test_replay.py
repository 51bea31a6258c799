"""`replay` writes what the nodes would publish, and its rotor speed matches simulator truth."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.errors import BadInputError, BagError, ModelError
from bldc_propulsion.replay import replay_bag
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """12 s of random steps, with its ground truth."""
    d = tmp_path_factory.mktemp("replay")
    res = simulate("random_steps", 12.0, seed=21)
    write_sim_bag(res, d / "in")
    return d, res


@pytest.fixture(scope="module")
def replayed(bench):
    d, res = bench
    info = replay_bag(d / "in", d / "out")
    return d, res, info


def test_every_output_topic_is_written_with_its_type(replayed):
    d, _, info = replayed
    with open_recording(d / "out") as rec:
        assert rec.topics() == c.OUTPUT_TOPICS
        n_batches = rec.count(c.TOPIC_ROTOR_SPEED)
        assert n_batches == rec.count(c.TOPIC_ROTOR_RPM)
        # one per 10 ms batch with a speed to stand behind: none while the rotor is starting
        # from rest (the first revolution) or at rest before the stop is known
        assert 0.7 * 1200 < n_batches <= 1200
        assert abs(rec.count(c.TOPIC_BATTERY_VOLTAGE) - 12 * 20) <= 2  # publish_rate_hz 20
        assert abs(rec.count(c.TOPIC_PREDICTED_SPEED) - 1200) <= 3  # 100 Hz estimator timer
        assert abs(rec.count(c.TOPIC_DIAGNOSTICS) - 12) <= 1  # 1 Hz
    assert info["messages_out"] > 0 and info["messages_in"] > 0


def test_rotor_speed_matches_truth(replayed):
    """Below 2 % RMS through steps, against the truth averaged over the revolution measured."""
    d, res, _ = replayed
    with open_recording(d / "out") as rec:
        t, speed = rec.scalars(c.TOPIC_ROTOR_SPEED)
        _, rpm = rec.scalars(c.TOPIC_ROTOR_RPM)
    np.testing.assert_allclose(rpm, speed * 60 / (2 * np.pi), rtol=1e-12)
    # truth: mean speed over the last revolution before each batch time
    angle = np.concatenate([[0.0], np.cumsum(res.truth_speed[1:] * np.diff(res.truth_t))])
    true_mean = np.empty(len(t))
    for k, tk in enumerate(t):
        a_end = np.interp(tk, res.truth_t, angle)
        t_start = np.interp(a_end - 2 * np.pi, angle, res.truth_t)
        true_mean[k] = 2 * np.pi / (tk - t_start) if tk > t_start else 0.0
    # from rest the decoder needs a first full revolution (5 edges) before it can say anything
    rest_t = res.truth_t[res.truth_speed < 1.0]
    last_rest = rest_t[np.clip(np.searchsorted(rest_t, t) - 1, 0, None)]
    fast = (true_mean > 100.0) & (t - last_rest > 0.3)
    assert fast.sum() > 400
    rel = (speed[fast] - true_mean[fast]) / true_mean[fast]
    # speed_now is the latest edge's estimate: up to one edge interval older than the batch
    assert np.sqrt(np.mean(rel**2)) < 0.02


def test_battery_voltage_recovers_the_terminal_voltage(replayed):
    d, res, _ = replayed
    with open_recording(d / "out") as rec:
        t, v = rec.battery_voltages()
    late = t > 3.0  # after the filter's settling
    truth = np.interp(t[late], res.truth_t, res.truth_voltage)
    assert np.sqrt(np.mean((v[late] - truth) ** 2)) < 0.15


def test_summary_json_from_the_command_line(bench, tmp_path):
    d, _ = bench
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.run(
        [sys.executable, "-m", "bldc_propulsion.cli", "replay", str(d / "in"), "-o", str(tmp_path / "o"), "--json"],
        capture_output=True, text=True, env=env, cwd=ROOT, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["path"] == str(tmp_path / "o") and info["messages_in"] > 0 and info["messages_out"] > 0
    proc = subprocess.run(
        [sys.executable, "-m", "bldc_propulsion.cli", "replay", str(d / "in"), "-o", str(tmp_path / "o")],
        capture_output=True, text=True, env=env, cwd=ROOT, timeout=300,
    )
    assert proc.returncode == 2 and "already exists" in proc.stderr


def test_bad_inputs_are_clear_errors(bench, tmp_path):
    d, _ = bench
    with pytest.raises(BagError, match="no such recording"):
        replay_bag(tmp_path / "missing", tmp_path / "o1")
    with pytest.raises(BadInputError, match="never replaces an input"):  # not even with force
        replay_bag(d / "in", d / "in", force=True)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"this is not a zip")
    with pytest.raises(ModelError, match="bad.npz"):
        replay_bag(d / "in", tmp_path / "o2", model_path=bad)
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()


def test_truncated_recording_keeps_the_readable_part(bench, tmp_path):
    d, _ = bench
    import shutil

    shutil.copytree(d / "in", tmp_path / "cut")
    mcap = tmp_path / "cut" / "in.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    try:
        info = replay_bag(tmp_path / "cut", tmp_path / "o")
    except BagError as exc:  # a reader that cannot even index the file: a clear error
        assert "cut" in str(exc)
        return
    assert info["read_error"] and info["messages_in"] > 0
