"""The bulk replay path writes exactly what the reference (per-message) path writes.

Every output message (topic, bag time, CDR bytes) and the summary are compared on a corpus
that reaches every branch of replay: profiles, MCAP and SQLite3, a single .mcap file, a
vehicle recording with --namespace, battery/voltage inputs (with and without battery/adc),
dropped and NaN tachometer batches, battery gaps and rejected samples, a truncated file and
a damaged chunk (which only the reference path reads), a trained model, and the bulk path
in short windows.
"""

from __future__ import annotations

import numpy as np
import pytest

from _models import good_model
from _replay_corpus import CASES, build_corpus, differences
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.errors import BagError
from bldc_propulsion.model import save_model
from bldc_propulsion.replay import replay_bag


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay_fast")
    bags = build_corpus(root / "in", duration_s=6.0)
    save_model(good_model(), root / "model.npz")
    return root, bags


CASES_WITH_MODEL = [*CASES, ("faults", {"model": True}), ("vehicle", {"namespace": "motor0", "model": True})]


@pytest.mark.parametrize("name,kw", CASES_WITH_MODEL, ids=[f"{n}{'+model' if k.get('model') else ''}"
                                                           for n, k in CASES_WITH_MODEL])
def test_bulk_path_equals_reference(corpus, name, kw):
    root, bags = corpus
    kw = dict(kw)
    if kw.pop("model", False):
        kw["model_path"] = root / "model.npz"
    tag = name + ("_m" if "model_path" in kw else "") + kw.get("namespace", "")
    try:
        ref = replay_bag(bags[name], root / f"ref_{tag}", reference=True, **kw)
    except BagError as exc:  # the same error either way
        with pytest.raises(BagError) as fast_exc:
            replay_bag(bags[name], root / f"fast_{tag}", **kw)
        assert str(fast_exc.value) == str(exc)
        return
    fast = replay_bag(bags[name], root / f"fast_{tag}", **kw)
    assert differences(root / f"ref_{tag}", root / f"fast_{tag}", ref, fast) == []


def test_bulk_read_is_used_where_it_can_be(corpus, monkeypatch):
    import bldc_propulsion.replay as replay

    root, bags = corpus

    def no_reference(*args):
        raise AssertionError("the reference path ran")

    monkeypatch.setattr(replay._Nodes, "run_reference", no_reference)
    for name in ("chirp", "sqlite3", "faults", "single_file.mcap"):
        replay_bag(bags[name], root / f"used_{name}")
    with pytest.raises(AssertionError, match="reference path ran"):  # damaged: streamed
        replay_bag(bags["corrupt_chunk"], root / "used_corrupt")
    for name in ("chirp", "sqlite3", "single_file.mcap", "vehicle"):
        with open_recording(bags[name], "motor0" if name == "vehicle" else None) as rec:
            assert rec.bulk(["pwm", "battery/adc", "tachometer/adc"]) is not None, name


@pytest.mark.parametrize("name", ["chirp", "faults", "vehicle", "corrupt_chunk"])
def test_bulk_path_in_short_windows_equals_reference(corpus, name, monkeypatch):
    """Windows of 0.7 s (instead of a minute): state carries across them exactly."""
    import bldc_propulsion.replay as replay

    root, bags = corpus
    kw = {"namespace": "motor1"} if name == "vehicle" else {}
    ref = replay_bag(bags[name], root / f"wref_{name}", reference=True, **kw)
    monkeypatch.setattr(replay, "BULK_WINDOW_S", 0.7)
    fast = replay_bag(bags[name], root / f"wfast_{name}", **kw)
    assert differences(root / f"wref_{name}", root / f"wfast_{name}", ref, fast) == []


def test_replay_command_names_the_rotor_and_its_spin(corpus, tmp_path):
    """`replay --joint-name --frame-id --spin-direction`: the nodes' parameters of the same names,
    in the stamped outputs; the torque's sign follows the spin; a blank name is one line, exit 2."""
    import subprocess
    import sys

    from bldc_propulsion import contract as c
    from bldc_propulsion.bagio import open_recording

    root, bags = corpus
    got = {}
    for spin in (1, -1):
        out = tmp_path / f"out{spin}"
        proc = subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", "replay", str(bags["chirp"]), "-o",
                               str(out), "--joint-name", "motor2_rotor", "--frame-id", "motor2_prop",
                               "--spin-direction", str(spin)], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        with open_recording(out) as rec:
            states = [m for _, _, m in rec.messages([c.TOPIC_PREDICTED_STATE, c.TOPIC_ROTOR_STATE])]
            wrenches = [m for _, _, m in rec.messages([c.TOPIC_PREDICTED_WRENCH])]
        assert states and {m.name[0] for m in states} == {"motor2_rotor"}
        assert wrenches and {m.header.frame_id for m in wrenches} == {"motor2_prop"}
        got[spin] = np.array([m.wrench.torque.z for m in wrenches])
    turning = np.abs(got[1]) > 1e-9
    assert turning.any() and np.allclose(got[-1][turning], -got[1][turning])
    assert np.all(got[1][turning] < 0)  # counter-clockwise rotor: the body is pushed clockwise
    proc = subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", "replay", str(bags["chirp"]), "-o",
                           str(tmp_path / "blank"), "--joint-name", " "], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "--joint-name" in proc.stderr
