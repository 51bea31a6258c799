"""The bag module against rosbags' own serializer and against hand-made recordings."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
from dataclasses import dataclass

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.atomic import atomic_output
from bldc_propulsion.bagio import TYPESTORE, BagWriter, open_recording
from bldc_propulsion.errors import BagError, OutputExistsError


@dataclass
class Status:
    name: str
    level: int
    message: str
    values: dict


def _write_sample(path, storage="mcap"):
    rng = np.random.default_rng(3)
    batches = rng.uniform(0, 5, (20, 200)).astype(np.float32)
    with BagWriter(path, storage=storage) as bag:
        for k in range(100):
            bag.write_float64(c.TOPIC_PWM, k * 0.02, 0.05 + k * 1e-4)
        for k in range(20):
            bag.write_float32_array(c.TOPIC_TACH_ADC, k * 0.01 + 0.00995, batches[k])
        bag.write_battery_state(c.TOPIC_BATTERY_VOLTAGE, 0.5, 11.7)
        bag.write_diagnostics(c.TOPIC_DIAGNOSTICS, 1.0, [Status("tach", 1, "signal lost", {"losses": "1"})])
    return batches


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_round_trip_topics_types_and_values(tmp_path, storage):
    batches = _write_sample(tmp_path / "b", storage)
    with open_recording(tmp_path / "b") as rec:
        assert rec.topics() == {
            "pwm": c.FLOAT64, "tachometer/adc": c.FLOAT32_ARRAY,
            "battery/voltage": c.BATTERY_STATE, "diagnostics": c.DIAGNOSTIC_ARRAY,
        }
        t, v = rec.scalars("/pwm")  # leading slash accepted
        np.testing.assert_allclose(t, np.arange(100) * 0.02, atol=1e-9)
        np.testing.assert_allclose(v, 0.05 + np.arange(100) * 1e-4, rtol=0, atol=0)
        got = list(rec.tachometer())
        assert len(got) == 20 and all(len(s) == 200 and s.dtype == np.float32 for _, s in got)
        np.testing.assert_array_equal(np.vstack([s for _, s in got]), batches)
        tv, volts = rec.battery_voltages()
        assert volts.tolist() == [float(np.float32(11.7))] and abs(tv[0] - 0.5) < 1e-9  # float32 field
        (_, _, diag), = rec.messages([c.TOPIC_DIAGNOSTICS])
        assert diag.status[0].level == 1 and diag.status[0].values[0].value == "1"


def test_float64_fast_path_writes_rosbags_bytes(tmp_path):
    F = TYPESTORE.types[c.FLOAT64]
    for value in (0.0, -1.5, 0.0712345, 1e300):
        ref = bytes(TYPESTORE.serialize_cdr(F(data=value), c.FLOAT64))
        with BagWriter(tmp_path / f"f{value}") as bag:
            bag.write_float64("x", 0.0, value)
        with open_recording(tmp_path / f"f{value}") as rec:
            (_, _, _, raw), = rec.raw(["x"])
        assert bytes(raw) == ref


def test_single_mcap_file_reads(tmp_path):
    _write_sample(tmp_path / "b")
    single = tmp_path / "single.mcap"
    shutil.copy(tmp_path / "b" / "b.mcap", single)
    with open_recording(single) as rec:
        assert rec.count("pwm") == 100


def test_messages_come_in_time_order(tmp_path):
    _write_sample(tmp_path / "b")
    with open_recording(tmp_path / "b") as rec:
        times = [t for _, t, _ in rec.messages(["pwm", "tachometer/adc", "battery/voltage"])]
    assert times == sorted(times)


def test_errors_name_the_file_and_problem(tmp_path):
    with pytest.raises(BagError, match="no such recording"):
        open_recording(tmp_path / "nope")
    (tmp_path / "dir").mkdir()
    with pytest.raises(BagError, match="metadata.yaml is missing"):
        open_recording(tmp_path / "dir")
    (tmp_path / "x.csv").write_text("a,b\n")
    with pytest.raises(BagError, match="x.csv: not a recording"):
        open_recording(tmp_path / "x.csv")
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(BagError, match="junk.mcap: cannot open recording"):
        open_recording(tmp_path / "junk.mcap")
    _write_sample(tmp_path / "b")
    with open_recording(tmp_path / "b") as rec:
        with pytest.raises(BagError, match="topic /pwm has type std_msgs/msg/Float64, expected"):
            rec.require("pwm", c.FLOAT32_ARRAY)
        with pytest.raises(BagError, match="topic /battery/adc is missing"):
            rec.require("battery/adc", c.FLOAT64)


def test_existing_output_is_refused_and_untouched(tmp_path):
    _write_sample(tmp_path / "b")
    before = sorted(os.listdir(tmp_path / "b"))
    with pytest.raises(OutputExistsError, match="already exists"):
        with BagWriter(tmp_path / "b"):
            pass
    assert sorted(os.listdir(tmp_path / "b")) == before


def test_failed_write_leaves_nothing_and_keeps_the_old_file(tmp_path):
    target = tmp_path / "model.npz"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with atomic_output(target, force=True) as tmp:
            tmp.write_bytes(b"new, half")
            raise RuntimeError("crash in the middle")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]
    with atomic_output(target, force=True) as tmp:
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.npz"]


def test_sigint_during_a_bag_write_leaves_no_partial_bag(tmp_path):
    """A real subprocess interrupted mid-write: no bag under the final name, no staging left."""
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {os.getcwd()!r})
        from bldc_propulsion.bagio import BagWriter
        with BagWriter({str(tmp_path / 'out')!r}) as bag:
            print('writing', flush=True)
            k = 0
            while True:
                bag.write_float64('pwm', k * 0.02, 0.07)
                k += 1
                if k % 1000 == 0:
                    time.sleep(0.01)
    """)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    # SIGINT back to its default in the child (see test_reliability_sigint.default_sigint)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert proc.stdout.readline().strip() == b"writing"
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    assert proc.returncode != 0
    assert list(tmp_path.iterdir()) == []


def test_battery_state_template_writes_the_typestore_bytes(tmp_path):
    from bldc_propulsion.bagio import battery_state

    with BagWriter(tmp_path / "bs", t0_ns=1_700_000_000_123_456_789) as bag:
        for t, v in ((0.0, 11.1), (1.234567891, 12.6), (100.5, 0.0)):
            bag.write_battery_state(c.TOPIC_BATTERY_VOLTAGE, t, v)
    with open_recording(tmp_path / "bs") as rec:
        for (_, ns, _, raw), v in zip(rec.raw([c.TOPIC_BATTERY_VOLTAGE]), (11.1, 12.6, 0.0), strict=True):
            ref = bytes(TYPESTORE.serialize_cdr(battery_state(ns, v), c.BATTERY_STATE))
            assert bytes(raw) == ref


def test_fast_mcap_writing_makes_the_files_rosbags_makes(tmp_path):
    """BagWriter appends MCAP message records itself: the same file bytes as rosbags' writer,
    across chunk boundaries (over 1 MiB), for every message kind, and single .mcap files."""
    rng = np.random.default_rng(5)
    batches = rng.uniform(0, 5, (700, 400)).astype(np.float32)  # 1.5 MB: two chunks

    def write(path, fast):
        bag = BagWriter(path)
        bag.fast_mcap = fast
        with bag:
            for k in range(700):
                bag.write_float32_array(c.TOPIC_TACH_ADC, k * 0.01 + 0.00995, batches[k])
                bag.write_float64(c.TOPIC_ROTOR_SPEED, k * 0.01 + 0.00995, float(k))
                bag.write_battery_state(c.TOPIC_BATTERY_VOLTAGE, k * 0.01, 11.0 + k * 1e-3)
            bag.write_float64("motor0/pwm", 0.5, 0.07)  # an earlier time, another topic
            bag.write_diagnostics(c.TOPIC_DIAGNOSTICS, 7.0, [Status("tach", 0, "ok", {"a": "1"})])
        assert bag.messages_written == 2102
        assert (bag._mcap is not None) == fast

    (tmp_path / "fast").mkdir()
    (tmp_path / "slow").mkdir()
    for name in ("d", "f.mcap"):  # a bag directory (with metadata.yaml), a single file
        write(tmp_path / "fast" / name, True)
        write(tmp_path / "slow" / name, False)
    fast = sorted(p for p in (tmp_path / "fast").rglob("*") if p.is_file())
    slow = sorted(p for p in (tmp_path / "slow").rglob("*") if p.is_file())
    assert [p.name for p in fast] == [p.name for p in slow] and len(fast) == 3
    for a, b in zip(fast, slow, strict=True):
        assert a.read_bytes() == b.read_bytes(), a.name
    with open_recording(tmp_path / "fast" / "f.mcap") as rec:
        assert len(rec._reader.storage.chunks) == 2
