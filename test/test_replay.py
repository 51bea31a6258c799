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
        assert abs(rec.count(c.TOPIC_DIAGNOSTICS) - 3 * 12) <= 3  # 1 Hz from each of the three nodes
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


# --- a recording with the measured topics and not the raw ones (an imported thrust-stand log) ---
def _stand_csv(path: Path, res, volts_scale: float = 1.0) -> Path:
    """The simulated run as a thrust stand logs it (100 Hz rows: ESC us, voltage, thrust, RPM)."""
    t = np.arange(0.0, res.truth_t[-1], 0.01)
    esc = 20000.0 * res.pwm[np.searchsorted(res.pwm_t, t + 1e-9, side="right") - 1]
    volts = volts_scale * np.interp(t, res.truth_t, res.truth_voltage)
    thrust = np.interp(t, res.truth_t, res.truth_thrust)
    rpm = np.interp(t, res.truth_t, res.truth_speed) * 60 / (2 * np.pi)
    rows = [f"{a:.3f},{e:.0f},{v:.4f},{f:.5f},{r:.1f}"
            for a, e, v, f, r in zip(t, esc, volts, thrust, rpm, strict=True)]
    header = "Time (s),ESC signal (µs),Voltage (V),Thrust (N),Motor Optical Speed (RPM)"
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    from bldc_propulsion.training.import_csv import import_csv

    d = tmp_path_factory.mktemp("imported")
    res = simulate("random_steps", 8.0, seed=22)
    import_csv(_stand_csv(d / "stand.csv", res), d / "stand")
    import_csv(_stand_csv(d / "low.csv", res, volts_scale=0.75), d / "low")
    return d


def test_imported_recording_uses_its_measured_topics(imported, tmp_path):
    import argparse

    from bldc_propulsion.commands import replay as replay_command

    d = imported
    p = argparse.ArgumentParser()
    replay_command.add_arguments(p)
    result = replay_command.run(p.parse_args([str(d / "stand"), "-o", str(tmp_path / "out")]))
    info = result.data
    assert info["measured_inputs"] == ["/battery/voltage", "/rotor/speed"]
    assert [s["name"] for s in info["status"]] == ["thrust estimator"]  # the stages without input did not run
    assert result.warnings == []
    info_lines = [ln for ln in result.text.splitlines() if "[INFO]" in ln]
    assert len(info_lines) == 1 and "/battery/voltage" in info_lines[0] and "/rotor/speed" in info_lines[0]
    assert "battery/adc sample" not in result.text and "tachometer/adc batch" not in result.text
    with open_recording(d / "stand") as rec, open_recording(tmp_path / "out") as out:
        assert set(out.topics()) == set(c.OUTPUT_TOPICS)
        # measured speed and voltage: as recorded (times and values), rpm beside the speed
        t_in, w_in = rec.scalars(c.TOPIC_ROTOR_SPEED)
        t_out, w_out = out.scalars(c.TOPIC_ROTOR_SPEED)
        np.testing.assert_array_equal(w_out, w_in)
        np.testing.assert_allclose(t_out + (out.t0_ns - rec.t0_ns) * 1e-9, t_in, atol=1e-9)
        np.testing.assert_allclose(out.scalars(c.TOPIC_ROTOR_RPM)[1], w_in * 60 / (2 * np.pi), rtol=1e-12)
        np.testing.assert_array_equal(out.battery_voltages()[1], rec.battery_voltages()[1])
        assert abs(out.count(c.TOPIC_PREDICTED_SPEED) - 800) <= 3  # 100 Hz over 8 s
        for status in [m for _, _, m in out.messages([c.TOPIC_DIAGNOSTICS])][:3]:
            assert [s.name for s in status.status] == ["thrust_estimator: thrust estimator"]


def test_imported_recording_voltage_reaches_the_estimator(imported, tmp_path):
    """The same commands on a pack at 75 % of the voltage: the fallback physics predicts less
    speed (it would predict the same if the recorded voltage were not used)."""
    d = imported
    replay_bag(d / "stand", tmp_path / "full")
    replay_bag(d / "low", tmp_path / "low")
    with open_recording(tmp_path / "full") as a, open_recording(tmp_path / "low") as b:
        full, low = a.scalars(c.TOPIC_PREDICTED_SPEED)[1], b.scalars(c.TOPIC_PREDICTED_SPEED)[1]
    busy = full > 100.0
    assert busy.sum() > 200 and np.all(low[busy] < 0.95 * full[busy])


def test_imported_recording_bulk_path_equals_reference(imported, tmp_path):
    from _replay_corpus import differences

    ref = replay_bag(imported / "stand", tmp_path / "ref", reference=True)
    fast = replay_bag(imported / "stand", tmp_path / "fast")
    assert differences(tmp_path / "ref", tmp_path / "fast", ref, fast) == []


def test_raw_topics_win_over_measured_ones(bench, tmp_path):
    """A recording with tachometer/adc and a rotor/speed too: the tachometer decodes, the
    recorded speed is not copied (nor are the stages' statuses dropped)."""
    from _replay_corpus import _write
    from bldc_propulsion.sim.record import _streams

    _, res = bench
    streams = [s for s in _streams(res) if not s[0].startswith(c.TRUTH_PREFIX)]
    fake = (c.TOPIC_ROTOR_SPEED, np.arange(0.0, 12.0, 0.1), np.full(120, 12345.0))
    _write(tmp_path / "both", [*streams, fake])
    info = replay_bag(tmp_path / "both", tmp_path / "out")
    assert info["measured_inputs"] == []
    assert [s["name"] for s in info["status"]] == ["battery filter", "tachometer", "thrust estimator"]
    with open_recording(tmp_path / "out") as out:
        speeds = out.scalars(c.TOPIC_ROTOR_SPEED)[1]
    assert len(speeds) > 500 and not np.any(speeds == 12345.0)
