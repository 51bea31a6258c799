"""Nothing the user owns is destroyed: the output rule of atomic.check_outputs, through the real CLI.

Every case runs the command in a subprocess and checks the exit status, the one line on stderr
and, by hashes, that every file it was pointed at is byte for byte as before. Refusals happen
before any work (no "reading ..." progress line). Small simulated bags (a few seconds) only.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from _models import good_model
from bldc_propulsion.atomic import REPORT_MARKER, describe_path
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.model import save_model
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag

ROOT = Path(__file__).resolve().parents[1]


def run(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def digest(path: Path) -> str:
    """Hash of a file, or of every file (name and bytes) of a directory; '' when absent."""
    if not path.exists():
        return ""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(str(f.relative_to(path) if path.is_dir() else f.name).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def one_line_error(proc: subprocess.CompletedProcess, *needles: str) -> str:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr  # the error alone: no progress, the check came first
    assert "Traceback" not in proc.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def home(tmp_path_factory) -> Path:
    """A user's folder: two small bags, a model, a physics CONFIG, a CSV log, a folder of notes."""
    d = tmp_path_factory.mktemp("home")
    write_sim_bag(simulate("random_steps", 6.0, seed=31), d / "bag")
    write_sim_bag(simulate("random_steps", 6.0, seed=32), d / "bag2")
    save_model(good_model(), d / "model.npz")
    (d / "config.json").write_text('{"effects": {"rotor_lag": 1.0}}\n')
    (d / "notes").mkdir()
    (d / "notes" / "notes.txt").write_text("my notes\n")
    (d / "notes.npz").write_text('{"not": "a model"}\n')
    (d / "notes.json").write_text("plain notes, not a CONFIG\n")
    (d / "logs").mkdir()
    (d / "logs" / "log.csv").write_text("Time (s),ESC signal (µs)\n0,1000\n")
    return d


#: (command line, the paths it must leave alone, words of the one-line error)
REFUSED = {
    "replay over its input": (["replay", "bag", "-o", "bag", "--force"], ["bag"], ["input bag", "never replaces"]),
    "replay into its input": (["replay", "bag", "-o", "bag/out", "--force"], ["bag"], ["input bag"]),
    "train over a folder": (["train", "bag", "--validation", "bag2", "-o", "notes", "--force"],
                            ["notes"], ["-o notes", ".npz"]),
    "train over a non-model .npz": (["train", "bag", "--validation", "bag2", "-o", "notes.npz", "--force"],
                                    ["notes.npz"], ["a JSON file", "not a model", "--force only replaces"]),
    "train over a recording": (["train", "bag", "--validation", "bag2", "-o", "model.npz", "--report", "bag2",
                                "--force"], ["bag2", "model.npz"], ["input bag2"]),
    "simulate over a folder": (["simulate", "--profile", "staircase", "--duration", "2", "-o", "notes", "--force"],
                               ["notes"], ["a directory with 1 entry", "not a recording"]),
    "simulate as .npz": (["simulate", "--profile", "staircase", "--duration", "2", "-o", "x.npz"], [],
                         ["must be a recording", "'.npz'"]),
    "model to a missing folder": (["train", "bag", "--validation", "bag2", "-o", "models/x.npz"], [],
                                  ["directory models does not exist"]),
    # with --physics, -o is a physics model (.npz) or a CONFIG (.json)
    "physics CONFIG as .txt": (["discrepancy", "--physics", "--measured", "bag", "-o", "found.txt"], [],
                               ["must be a physics CONFIG file (.json)", ".json"]),
    "model as .json": (["discrepancy", "--model", "model.npz", "--measured", "bag", "-o", "found.json"], [],
                       ["must be a model file (.npz)"]),
    "CONFIG over a text .json": (["discrepancy", "--physics", "--measured", "bag", "-o", "notes.json", "--force"],
                                 ["notes.json"], ["a text file", "not a physics CONFIG"]),
    "CONFIG over its input": (["discrepancy", "--physics", "config.json", "--measured", "bag", "-o", "config.json",
                               "--force"], ["config.json"], ["input config.json"]),
    "report over a folder": (["evaluate", "--model", "model.npz", "bag", "--report", "notes", "--force"],
                             ["notes"], ["a directory with 1 entry", "not a report directory"]),
    "report without --force": (["evaluate", "--model", "model.npz", "bag", "--report", "notes"],
                               ["notes"], ["already exists", "--force"]),
    "report over the model": (["evaluate", "--model", "model.npz", "bag", "--report", "model.npz", "--force"],
                              ["model.npz"], ["'.npz' names another kind"]),
    "-o and --report the same": (["train", "bag", "--validation", "bag2", "-o", "m.npz", "--report", "m.npz"],
                                 [], ["--report m.npz"]),
    "import over the CSV's folder": (["import-csv", "logs/log.csv", "-o", "logs", "--force"], ["logs"],
                                     ["input logs/log.csv"]),
}


@pytest.fixture(scope="module")
def refused(home):
    """Every REFUSED command run at once (a thread pool: the refusals need no CPU, the
    interpreters' start-up does), with the hashes of the user's files before and after."""
    def snapshot() -> dict[str, str]:
        return {p.name: digest(p) for p in sorted(home.iterdir())}

    before = snapshot()
    with ThreadPoolExecutor(max_workers=6) as pool:
        outcomes = pool.map(lambda argv: run(*argv, cwd=home), (v[0] for v in REFUSED.values()))
        procs = dict(zip(REFUSED, outcomes, strict=True))
    return before, procs, snapshot()


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_refused_in_one_line(refused, case):
    _, procs, _ = refused
    one_line_error(procs[case], *REFUSED[case][2])


def test_refusals_change_nothing(refused, home):
    """Every file and folder the commands were pointed at, byte for byte; nothing new (no
    output, no staging directory)."""
    before, _, after = refused
    assert after == before
    kept = {p for v in REFUSED.values() for p in v[1]}
    assert kept <= set(before) and all(before[p] for p in kept)


def test_force_replaces_the_same_kind(home, tmp_path):
    """A recording by a recording, a model by a model, a report this tool made by a report."""
    bag = tmp_path / "sim"
    assert run("simulate", "--profile", "staircase", "--duration", "2", "-o", bag, cwd=tmp_path).returncode == 0
    first = digest(bag)
    proc = run("simulate", "--profile", "staircase", "--duration", "2", "--seed", "5", "-o", bag, "--force",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert digest(bag) != first
    model = tmp_path / "m.npz"
    save_model(good_model(), model)
    proc = run("discrepancy", "--model", model, "--measured", home / "bag", "--reference", home / "bag2",
               "-o", model, "--force", cwd=tmp_path)
    one_line_error(proc, "input")  # the model is discrepancy's input: never its own output


def test_report_is_rewritten_whole(home, tmp_path):
    report = tmp_path / "report"
    proc = run("evaluate", "--model", home / "model.npz", home / "bag", "--report", report, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (report / REPORT_MARKER).is_file() and (report / "index.html").is_file()
    (report / "stale.png").write_bytes(b"from an older run")
    before = digest(report)
    one_line_error(run("evaluate", "--model", home / "model.npz", home / "bag", "--report", report,
                       cwd=tmp_path), "already exists")
    assert digest(report) == before
    proc = run("evaluate", "--model", home / "model.npz", home / "bag2", "--report", report, "--force",
               "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["report"] == str(report)
    assert not (report / "stale.png").exists()
    assert "bag2" in (report / "index.html").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]  # no staging left


def test_mcap_output_is_one_file(tmp_path):
    proc = run("simulate", "--profile", "staircase", "--duration", "2", "-o", "x.mcap", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "x.mcap").is_file() and sorted(os.listdir(tmp_path)) == ["x.mcap"]
    with open_recording(tmp_path / "x.mcap") as rec:
        assert rec.count("pwm") == 100
    proc = run("replay", "x.mcap", "-o", "out.mcap", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "out.mcap").is_file()
    assert describe_path(tmp_path / "out.mcap") == "an MCAP recording"
    one_line_error(run("simulate", "--profile", "staircase", "--duration", "2", "--storage", "sqlite3",
                       "-o", "y.mcap", cwd=tmp_path), "MCAP storage only")


def _foreign_bag(path: Path, storage: str = "mcap") -> Path:
    """A recording another tool wrote (rosbags directly, as `ros2 bag record` would: no mark);
    ``path`` ending in .mcap: its single MCAP file."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from bldc_propulsion.bagio import TYPESTORE

    bag_dir = path.with_name(path.stem + "_dir") if path.suffix == ".mcap" else path
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(bag_dir, version=9, storage_plugin=plugin) as writer:
        conn = writer.add_connection("/pwm", "std_msgs/msg/Float64", typestore=TYPESTORE)
        writer.write(conn, 10**9, b"\x00\x01\x00\x00" + struct.pack("<d", 0.05))  # CDR Float64
    if path.suffix == ".mcap":
        (bag_dir / f"{bag_dir.name}.mcap").rename(path)
        for f in bag_dir.iterdir():
            f.unlink()
        bag_dir.rmdir()
    return path


@pytest.mark.parametrize("name,storage,where", [("bench", "mcap", "its metadata.yaml"),
                                                ("bench_sqlite", "sqlite3", "its metadata.yaml"),
                                                ("bench.mcap", "mcap", "its rosbag2 metadata record")])
def test_force_never_replaces_a_recording_another_tool_wrote(tmp_path, name, storage, where):
    """A typo in -o must not wipe a bench log: only a recording carrying this tool's mark in
    rosbag2's custom_data is replaced by --force; one this tool wrote there is."""
    from bldc_propulsion.atomic import RECORDING, RECORDING_MARK, check_output, recording_marked
    from bldc_propulsion.errors import BadInputError

    foreign = _foreign_bag(tmp_path / name, storage)
    before = digest(foreign)
    assert not recording_marked(foreign)
    with pytest.raises(BadInputError, match="not written by bldc-propulsion") as err:
        check_output(foreign, RECORDING, force=True)
    assert "\n" not in str(err.value)
    line = one_line_error(run("simulate", "--profile", "staircase", "--duration", "1", "-o", foreign, "--force",
                              cwd=tmp_path), str(foreign), f"no mark in {where}", "remove it yourself")
    assert "not written by bldc-propulsion" in line
    assert digest(foreign) == before and sorted(p.name for p in tmp_path.iterdir()) == [name]
    ours = tmp_path / f"ours{'.mcap' if name.endswith('.mcap') else ''}"
    args = ["--storage", storage] if storage != "mcap" else []
    assert run("simulate", "--profile", "staircase", "--duration", "1", "-o", ours, *args,
               cwd=tmp_path).returncode == 0
    assert recording_marked(ours)
    if ours.is_dir():
        assert f"{RECORDING_MARK[0]}: {RECORDING_MARK[1]}" in (ours / "metadata.yaml").read_text()
    first = digest(ours)
    proc = run("simulate", "--profile", "staircase", "--duration", "1", "--seed", "7", "-o", ours, "--force",
               *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert digest(ours) != first and recording_marked(ours)
