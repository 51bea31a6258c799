"""`bldc-propulsion simulate` as a user runs it: bags, JSON, and one-line errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import cli
from bldc_propulsion import contract as c
from bldc_propulsion.bagio import open_recording

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)


def test_simulate_writes_the_contract_topics_at_their_rates(tmp_path):
    out = tmp_path / "bench"
    proc = run("simulate", "--profile", "staircase", "--duration", "3", "--seed", "4", "-o", str(out), "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["path"] == str(out)
    with open_recording(out) as rec:
        assert rec.topics() == {**{k: v for k, v in c.INPUT_TOPICS.items()}, **c.TRUTH_TOPICS}
        t, pwm = rec.scalars(c.TOPIC_PWM)
        assert np.allclose(np.diff(t), 1 / c.PWM_FRAME_HZ, atol=1e-6)  # 50 Hz frames
        assert np.all((pwm >= c.PWM_STOP) & (pwm <= c.PWM_FULL))
        tb, adc = rec.scalars(c.TOPIC_BATTERY_ADC)
        assert np.allclose(np.diff(tb), 1e-3, atol=1e-6)  # 1 kHz
        assert 4.0 < np.median(adc) < 7.0  # ~12 V through a ~1:2 divider
        batches = list(rec.tachometer())
        assert all(len(s) == 200 for _, s in batches)  # default batch
        times = np.array([tt for tt, _ in batches])
        assert np.allclose(np.diff(times), 0.01, atol=1e-6)  # 100 Hz batches of 20 kHz samples
        assert abs(rec.duration_s - 3.0) < 0.05


def test_same_seed_same_bag_different_seed_different(tmp_path):
    for name, seed in (("a", "1"), ("b", "1"), ("c", "2")):
        (tmp_path / name).mkdir()  # same bag name in each: the name is written inside the bag
        assert run("simulate", "--profile", "random_steps", "--duration", "2", "--seed", seed,
                   "-o", str(tmp_path / name / "bag")).returncode == 0
    read = lambda n: (tmp_path / n / "bag" / "bag.mcap").read_bytes()  # noqa: E731
    assert read("a") == read("b")
    assert read("a") != read("c")


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--profile", "zigzag"], "zigzag"),
        (["--effect", "gremlins=1"], "gremlins"),
        (["--effect", "rotor_lag"], "rotor_lag"),
        (["--param", "warp_factor=9"], "warp_factor"),
        (["--duration", "-5"], "duration"),
        (["--soc", "1.5"], "soc"),
        (["--namespace", "motor 1"], "--namespace motor 1: not a ROS namespace"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_no_bag(tmp_path, args, needle):
    base = {"--profile": "staircase", "--duration": "1", "-o": str(tmp_path / "bag")}
    for k in range(0, len(args), 2):
        base[args[k]] = args[k + 1] if k + 1 < len(args) else None
    argv = ["simulate"]
    for k, v in base.items():
        argv += [k] if v is None else [k, v]
    proc = run(*argv)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "bag").exists()
    assert list(tmp_path.iterdir()) == []


def test_existing_or_unwritable_output_is_refused(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "keep.txt").write_text("mine")
    proc = run("simulate", "--profile", "staircase", "--duration", "1", "-o", str(tmp_path / "bag"))
    assert proc.returncode == 2 and "already exists" in proc.stderr
    assert (tmp_path / "bag" / "keep.txt").read_text() == "mine"
    proc = run("simulate", "--profile", "staircase", "--duration", "1", "-o", str(tmp_path / "no" / "bag"))
    assert proc.returncode == 2 and "does not exist" in proc.stderr


def test_main_returns_exit_codes_in_process(tmp_path, capsys):
    assert cli.main(["simulate", "--profile", "nope", "--duration", "1", "-o", str(tmp_path / "x")]) == 2
    assert "nope" in capsys.readouterr().err


def readme_walkthrough_commands() -> list[list[str]]:
    """Every `bldc-propulsion` command of the README's "Recording your own bench", as argv:
    the code block's lines (continuations joined, comments dropped) and the inline ones."""
    import re
    import shlex

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Recording your own bench", 1)[1].split("\n## ", 1)[0]
    block = section.split("```bash", 1)[1].split("```", 1)[0].replace("\\\n", " ")
    lines = [ln.split(" #")[0].strip() for ln in block.splitlines()]
    inline = [" ".join(m.split()) for m in re.findall(r"`(bldc-propulsion [^`]+)`", section)]
    return [shlex.split(ln) for ln in [*lines, *inline] if ln.startswith("bldc-propulsion ")]


def test_readme_walkthrough_commands_are_accepted_as_written():
    """Each command of the walkthrough parses (options and subcommands exist); running them on
    copies of bags/ and simulated flights was done by hand (docs/reliability.md)."""
    commands = readme_walkthrough_commands()
    assert {argv[1] for argv in commands} >= {"info", "train", "evaluate", "discrepancy", "simulate"}
    parser = cli.build_parser()
    for argv in commands:
        args = parser.parse_args(argv[1:])
        assert args.command == argv[1]
    assert any(argv[1] == "simulate" and "--namespace" in argv for argv in commands)
