"""Honest warnings and bounds, through the real CLI: inputs outside the model's training range,
a training that learnt nothing, numeric options beyond sane bounds, a wrong file as --model."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from _models import good_model
from bldc_propulsion import contract as c
from bldc_propulsion.bagio import BagWriter, open_recording
from bldc_propulsion.core.features import scale_pwm
from bldc_propulsion.model import NetworkModel, save_model
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import _streams, write_sim_bag

ROOT = Path(__file__).resolve().parents[1]


def run(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def run_all(cases: dict[str, list], cwd: Path) -> dict[str, subprocess.CompletedProcess]:
    with ThreadPoolExecutor(max_workers=6) as pool:
        return dict(zip(cases, pool.map(lambda a: run(*a, cwd=cwd), cases.values()), strict=True))


def listing(d: Path) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


@pytest.fixture(scope="module")
def home(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("warn")
    write_sim_bag(simulate("random_steps", 6.0, seed=61, soc=0.5), d / "half")
    good = good_model()

    def with_voltage_range(lo: float, hi: float) -> NetworkModel:  # PWM inputs: any value
        return NetworkModel(input_names=good.input_names, input_min=np.array([lo, -10.0, -10.0]),
                            input_max=np.array([hi, 10.0, 10.0]), output_min=0.0, output_max=900.0,
                            W1=good.W1, b1=good.b1, W2=good.W2, b2=0.0)

    save_model(with_voltage_range(12.5, 13.0), d / "full_packs.npz")  # trained on full packs only
    save_model(with_voltage_range(5.0, 20.0), d / "wide.npz")
    (d / "config.json").write_text('{"effects": {}}\n')
    return d


def test_inputs_outside_the_training_range_are_said(home, tmp_path):
    procs = run_all({
        "evaluate": ["evaluate", "--model", home / "full_packs.npz", home / "half", "--json"],
        "replay": ["replay", home / "half", "-o", tmp_path / "out", "--model", home / "full_packs.npz", "--json"],
        "inside": ["evaluate", "--model", home / "wide.npz", home / "half", "--json"],
    }, tmp_path)
    for proc in procs.values():
        assert proc.returncode == 0, proc.stderr
    for name in ("evaluate", "replay"):
        proc = procs[name]
        warn = [ln for ln in proc.stderr.splitlines() if ln.startswith("warning:")]
        assert len(warn) == 1, proc.stderr
        assert "half: inputs outside the model's training range" in warn[0]
        assert "battery_voltage 100.0 %" in warn[0] and "pwm" not in warn[0].split("(")[1].split(")")[0]
        data = json.loads(proc.stdout)
        assert data["warnings"] == [warn[0].removeprefix("warning: ")]
    rng = json.loads(procs["evaluate"].stdout)["recordings"][0]["out_of_training_range"]
    assert rng["fraction"] == 1.0 and set(rng["by_input"]) == {"battery_voltage"}
    rng = json.loads(procs["replay"].stdout)["out_of_training_range"]
    assert rng["fraction"] > 0.99 and set(rng["by_input"]) == {"battery_voltage"}
    inside = json.loads(procs["inside"].stdout)
    assert inside["warnings"] == [] and "warning" not in procs["inside"].stderr
    assert inside["recordings"][0]["out_of_training_range"]["fraction"] == 0.0


def share_of_time_above(path: Path, level: float) -> float:
    """Known truth: the share of a recording's time its PWM command (held from one /pwm
    message to the next) is above ``level``, from the raw messages."""
    with open_recording(path) as rec:
        t, pwm = rec.scalars(c.TOPIC_PWM)
    return float(np.sum(np.diff(t)[pwm[:-1] > level]) / (t[-1] - t[0]))


def test_discrepancy_says_when_inputs_leave_the_training_range(tmp_path):
    """`discrepancy --model`: a model that saw PWM only up to 0.075 (its `pwm` input 0..0.5),
    any battery voltage and any filtered PWM, on measured and holdout recordings whose command
    is above 0.075 about half the time: one warning line per recording, naming it, the input
    (pwm, no other) and the share of time the command is there; exit 0, the lines in --json."""
    for name, seed in (("measured", 81), ("holdout", 82), ("reference", 83)):
        write_sim_bag(simulate("random_steps", 12.0, seed=seed), tmp_path / name)
    good = good_model()
    save_model(NetworkModel(input_names=good.input_names, input_min=np.array([5.0, -10.0, -10.0]),
                            input_max=np.array([20.0, scale_pwm(0.075), 10.0]), output_min=0.0, output_max=900.0,
                            W1=good.W1, b1=good.b1, W2=good.W2, b2=0.0), tmp_path / "low_pwm.npz")
    truth = {name: share_of_time_above(tmp_path / name, 0.075) for name in ("measured", "holdout")}
    assert all(0.2 < f < 0.8 for f in truth.values()), truth  # the case is neither all nor nothing
    proc = run("discrepancy", "--model", tmp_path / "low_pwm.npz", "--measured", tmp_path / "measured",
               "--reference", tmp_path / "reference", "--holdout", tmp_path / "holdout",
               "--max-effects", "1", "--hidden", "3", "--max-epochs", "5", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    warn = [ln.removeprefix("warning: ") for ln in proc.stderr.splitlines() if ln.startswith("warning:")]
    data = json.loads(proc.stdout)
    assert data["warnings"] == warn
    ranges = [w for w in warn if "training range" in w]
    assert len(ranges) == 2, proc.stderr
    for name, line in zip(("measured", "holdout"), ranges, strict=True):
        assert line.startswith(f"{tmp_path / name}: inputs outside the model's training range "), line
        share = float(line.split("(pwm ")[1].split(" %")[0]) / 100
        assert abs(share - truth[name]) < 0.01, (line, truth[name])  # within 1 % of the time
        assert "battery_voltage" not in line and "pwm_filtered" not in line
        report = data["out_of_training_range"][str(tmp_path / name)]
        assert set(report["by_input"]) == {"pwm"} and abs(report["fraction"] - truth[name]) < 0.01


def test_training_that_learnt_nothing_is_refused(tmp_path):
    """Validation data the training data cannot explain (its speed runs backwards): every run's
    best network is its initial weights, and nothing is saved."""
    write_sim_bag(simulate("random_steps", 8.0, seed=51), tmp_path / "train")
    res = simulate("random_steps", 8.0, seed=52)
    with BagWriter(tmp_path / "backwards") as bag:
        for topic, t, values in _streams(res):
            for i in range(len(t)):
                if topic in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC):
                    bag.write_float64(topic, float(t[i]), float(values[i]))
                elif topic == c.TOPIC_TRUTH_SPEED:
                    bag.write_float64(c.TOPIC_ROTOR_SPEED, float(t[i]), 700.0 - float(values[i]))
    before = listing(tmp_path)
    proc = run("train", "train", "--validation", "backwards", "-o", "m.npz", "--restarts", "2", "--hidden", "4",
               cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "-o m.npz: not written: no training run improved on its initial weights" in last
    assert listing(tmp_path) == before


BOUNDS = {
    "simulate --duration": (["simulate", "--profile", "staircase", "--duration", "1e9", "-o", "b"], "--duration"),
    "simulate --seed": (["simulate", "--profile", "staircase", "--duration", "1", "--seed", "-1", "-o", "b"],
                        "--seed"),
    "train --hidden 0": (["train", "half", "--validation", "half", "-o", "m.npz", "--hidden", "0"], "--hidden"),
    "train --hidden huge": (["train", "half", "--validation", "half", "-o", "m.npz", "--hidden", "100000"],
                            "--hidden"),
    "train --restarts": (["train", "half", "--validation", "half", "-o", "m.npz", "--restarts", "100000"],
                         "--restarts"),
    "train --max-epochs": (["train", "half", "--validation", "half", "-o", "m.npz", "--max-epochs", "0"],
                           "--max-epochs"),
    "train --patience": (["train", "half", "--validation", "half", "-o", "m.npz", "--patience", "nan"],
                         "--patience"),
    "train --thrust-coefficient": (["train", "half", "--validation", "half", "-o", "m.npz",
                                    "--thrust-coefficient", "inf"], "--thrust-coefficient"),
    "discrepancy --alpha": (["discrepancy", "--physics", "--measured", "half", "--alpha", "2"], "--alpha"),
    "discrepancy --max-effects": (["discrepancy", "--physics", "--measured", "half", "--max-effects", "99"],
                                  "--max-effects"),
    "import-csv --pole-pairs": (["import-csv", "log.csv", "-o", "b", "--pole-pairs", "0"], "--pole-pairs"),
    "JSON as --model": (["evaluate", "--model", "config.json", "half"], "config.json: is a JSON file, not a model"),
    "recording as --model": (["replay", "half", "-o", "b", "--model", "half"], "half: is a rosbag2 recording"),
    "MCAP as --model": (["discrepancy", "--model", "half/half.mcap", "--measured", "half"],
                        "is an MCAP recording, not a model .npz"),
}


def test_bounds_and_wrong_file_types_are_one_line_errors(home):
    before = listing(home)
    procs = run_all({k: v[0] for k, v in BOUNDS.items()}, home)
    for name, proc in procs.items():
        assert proc.returncode == 2, (name, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and BOUNDS[name][1] in lines[0], (name, proc.stderr)
        assert "pickle" not in lines[0] and "usage" not in lines[0]
    assert listing(home) == before
