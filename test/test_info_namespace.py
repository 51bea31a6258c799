"""`info` and `--namespace motorN` (interfaces.md, "A quadrotor"), through the real CLI.

A vehicle recording is made here from two short simulated bench runs: motor topics under
/motor0 and /motor1, one pack, so /battery/adc at the root (motor 0's run). Commands that read
recordings pick one motor with --namespace; without it the missing-topic error lists what the
recording has and suggests the namespace.
"""

from __future__ import annotations

import hashlib
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
from bldc_propulsion.model import save_model
from bldc_propulsion.recordings import load_signals
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import _streams, write_sim_bag

ROOT = Path(__file__).resolve().parents[1]


def run(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, cwd=cwd, timeout=300)


def digest(path: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def write_vehicle_bag(path: Path, runs: list, battery_in: str | None = None) -> None:
    """Motor k's topics under /motork; the battery at the root, or under ``battery_in``."""
    rows = []
    for k, res in enumerate(runs):
        for topic, t, values in _streams(res):
            if topic.startswith(c.TRUTH_PREFIX):
                continue
            if topic == c.TOPIC_BATTERY_ADC:
                if k:
                    continue  # one pack
                name = f"{battery_in}/{topic}" if battery_in else topic
            else:
                name = f"motor{k}/{topic}"
            rows += [(float(t[i]), name, topic, values[i]) for i in range(len(t))]
    rows.sort(key=lambda r: r[0])
    with BagWriter(path) as bag:
        for t, name, topic, value in rows:
            if topic == c.TOPIC_TACH_ADC:
                bag.write_float32_array(name, t, value)
            else:
                bag.write_float64(name, t, float(value))


@pytest.fixture(scope="module")
def home(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("vehicle")
    runs = [simulate("random_steps", 6.0, seed=41), simulate("random_steps", 6.0, seed=42)]
    write_vehicle_bag(d / "vehicle", runs)
    write_vehicle_bag(d / "vehicle_own_battery", runs[:1], battery_in="motor0")
    write_sim_bag(runs[1], d / "bench")  # motor 1's run alone, recorded on the bench
    save_model(good_model(), d / "model.npz")
    return d


def test_namespace_reads_the_motor_and_the_shared_battery(home):
    """Motor 1 of the vehicle gives exactly what the same run gives on the bench, battery
    aside (it comes from the root: motor 0's run)."""
    bench = load_signals(home / "bench")
    m1 = load_signals(home / "vehicle", namespace="motor1")
    assert m1.namespace == "motor1"
    n = min(len(bench.t), len(m1.t))
    assert np.array_equal(bench.pwm[:n], m1.pwm[:n]) and np.array_equal(bench.speed[:n], m1.speed[:n])
    m0 = load_signals(home / "vehicle", namespace="/motor0/")
    assert not np.array_equal(m0.pwm[:n], m1.pwm[:n])
    assert np.array_equal(m0.voltage[:n], m1.voltage[:n])  # one pack
    own = load_signals(home / "vehicle_own_battery", namespace="motor0")
    assert np.allclose(own.voltage[:n], m0.voltage[:n])  # from /motor0/battery/adc
    with open_recording(home / "vehicle", "motor0") as rec:
        assert rec.resolve("battery/adc") == "battery/adc" and rec.resolve("pwm") == "motor0/pwm"


def test_commands_on_a_vehicle_recording(home, tmp_path):
    before = digest(home)
    cases = {
        "evaluate": ["evaluate", "--model", home / "model.npz", home / "vehicle", "--namespace", "motor1", "--json"],
        "replay": ["replay", home / "vehicle", "-o", tmp_path / "out", "--namespace", "motor1", "--json"],
        "info": ["info", home / "vehicle", "--namespace", "motor1", "--json"],
        "no namespace": ["evaluate", "--model", home / "model.npz", home / "vehicle"],
        "no namespace, replay": ["replay", home / "vehicle", "-o", tmp_path / "none"],
        "wrong namespace": ["evaluate", "--model", home / "model.npz", home / "vehicle", "--namespace", "motor7"],
        "bad namespace": ["info", home / "vehicle", "--namespace", "motor 1"],
    }
    with ThreadPoolExecutor(max_workers=4) as pool:
        procs = dict(zip(cases, pool.map(lambda a: run(*a, cwd=tmp_path), cases.values()), strict=True))
    for name in ("evaluate", "replay", "info"):
        assert procs[name].returncode == 0, procs[name].stderr
    ev = json.loads(procs["evaluate"].stdout)
    assert ev["recordings"][0]["samples"] > 400 and np.isfinite(ev["rmse_rad_s"])
    rp = json.loads(procs["replay"].stdout)
    assert rp["namespace"] == "motor1" and rp["messages_in_per_topic"]["pwm"] == 300
    with open_recording(tmp_path / "out") as rec:  # as the quadrotor launch publishes them
        assert {"motor1/rotor/speed", "motor1/predicted/speed", "battery/voltage"} <= set(rec.topics())
        assert "rotor/speed" not in rec.topics()
    info = json.loads(procs["info"].stdout)["recordings"][0]
    assert info["namespace"] == "motor1" and info["namespaces"] == ["motor0", "motor1"]
    assert info["usable_for"] == ["train", "evaluate", "discrepancy", "replay"]
    for name in ("no namespace", "no namespace, replay", "wrong namespace"):
        proc = procs[name]
        assert proc.returncode == 2, proc.stderr
        line = proc.stderr.strip().splitlines()[-1]
        assert "/motor0/pwm" in line and "/motor1/tachometer/adc" in line  # what it has
        assert "give --namespace motor0" in line, line
    assert "/motor7/pwm is missing" in procs["wrong namespace"].stderr
    assert procs["bad namespace"].returncode == 2 and "not a ROS namespace" in procs["bad namespace"].stderr
    assert not (tmp_path / "none").exists()
    assert digest(home) == before


def test_info_says_what_a_bench_recording_holds(home, tmp_path):
    proc = run("info", home / "bench", home / "vehicle", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    assert "/tachometer/adc" in text and "std_msgs/msg/Float32MultiArray" in text and "100.0 Hz" in text
    assert "Tachometer:       decodes" in text and "Usable for:       train, evaluate, discrepancy, replay" in text
    assert "Motors:           /motor0, /motor1 (read one with --namespace motor0)" in text
    proc = run("info", home / "bench", "--json", cwd=tmp_path)
    info = json.loads(proc.stdout)["recordings"][0]
    topics = {t["topic"]: t for t in info["topics"]}
    assert topics["/pwm"]["count"] == 300 and abs(topics["/pwm"]["rate_hz"] - 50.0) < 0.1
    assert topics["/battery/adc"]["gaps"] == 0
    assert 0.05 <= info["pwm"]["min"] < info["pwm"]["max"] <= 0.10
    assert 10.0 < info["battery_voltage_v"]["min"] <= info["battery_voltage_v"]["max"] < 13.0
    assert info["tachometer"]["decodes"] and info["tachometer"]["max_rad_s"] > 100


def test_info_finds_gaps_and_says_why_a_recording_is_not_usable(tmp_path):
    res = simulate("random_steps", 6.0, seed=43)
    with BagWriter(tmp_path / "gappy") as bag:  # PWM with 2 s missing, no tachometer
        for topic, t, values in _streams(res):
            if topic in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC):
                for i in range(len(t)):
                    if topic != c.TOPIC_PWM or not 2.0 <= t[i] < 4.0:
                        bag.write_float64(topic, float(t[i]), float(values[i]))
    proc = run("info", tmp_path / "gappy", "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)["recordings"][0]
    pwm = next(t for t in info["topics"] if t["topic"] == "/pwm")
    assert pwm["gaps"] == 1 and abs(pwm["max_gap_s"] - 2.02) < 0.01
    assert info["usable_for"] == ["replay"]
    assert "neither /rotor/speed nor /tachometer/adc" in info["not_usable"]["train"]


def test_simulate_records_one_motor_of_a_vehicle(tmp_path):
    """`simulate --namespace motor3` writes what a quadrotor records of motor 3 (interfaces.md:
    its topics under /motor3, /battery/adc at the root); `info` without --namespace says which
    one to give, and train, evaluate and replay with it give exactly the numbers of the same
    seeds recorded on the bench."""
    bags = {(kind, ns): tmp_path / f"{kind}_{ns or 'bench'}" for kind in ("train", "val") for ns in ("motor3", None)}

    def simulate(key):
        kind, ns = key
        seed = {"train": "71", "val": "72"}[kind]
        return run("simulate", "--profile", "random_steps", "--duration", "6", "--seed", seed, "-o", bags[key],
                   "--json", *(["--namespace", ns] if ns else []), cwd=tmp_path)

    with ThreadPoolExecutor(max_workers=2) as pool:
        for proc in pool.map(simulate, bags):
            assert proc.returncode == 0, proc.stderr
    vehicle, bench = bags["train", "motor3"], bags["train", None]
    with open_recording(vehicle) as v, open_recording(bench) as b:
        assert set(v.topics()) == {t if t == c.TOPIC_BATTERY_ADC else f"motor3/{t}" for t in b.topics()}
    with open_recording(vehicle, "motor3") as v, open_recording(bench) as b:
        for topic in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_THRUST_MEASURED):
            assert all(np.array_equal(x, y) for x, y in zip(v.scalars(topic), b.scalars(topic), strict=True)), topic
    proc = run("info", vehicle, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "--namespace motor3" in proc.stdout and "Usable for:       nothing" in proc.stdout
    info = json.loads(run("info", vehicle, "--json", cwd=tmp_path).stdout)["recordings"][0]
    assert info["usable_for"] == [] and info["not_usable"]["train"].endswith("give --namespace motor3")

    train = ["--hidden", "3", "--restarts", "1", "--max-epochs", "5", "--json"]
    ns = ["--namespace", "motor3"]
    cases = {
        "train vehicle": ["train", vehicle, "--validation", bags["val", "motor3"],
                          "-o", tmp_path / "v.npz", *train, *ns],
        "train bench": ["train", bench, "--validation", bags["val", None], "-o", tmp_path / "b.npz", *train],
        "train vehicle, no namespace": ["train", vehicle, "--validation", bags["val", "motor3"],
                                        "-o", tmp_path / "none.npz", *train],
    }
    with ThreadPoolExecutor(max_workers=2) as pool:
        procs = dict(zip(cases, pool.map(lambda a: run(*a, cwd=tmp_path), cases.values()), strict=True))
    fitted = {}
    for name in ("train vehicle", "train bench"):
        assert procs[name].returncode == 0, procs[name].stderr
        fitted[name] = json.loads(procs[name].stdout)
    for key in ("epochs", "train_cost", "validation_cost"):
        assert fitted["train vehicle"][key] == fitted["train bench"][key], key
    mv, mb = np.load(tmp_path / "v.npz"), np.load(tmp_path / "b.npz")
    for key in ("W1", "b1", "W2", "b2", "input_min", "input_max", "output_min", "output_max"):
        assert np.array_equal(mv[key], mb[key]), key
    bad = procs["train vehicle, no namespace"]
    assert bad.returncode == 2 and "give --namespace motor3" in bad.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "none.npz").exists()

    model = tmp_path / "b.npz"
    cases = {
        "evaluate vehicle": ["evaluate", "--model", model, vehicle, "--json", *ns],
        "evaluate bench": ["evaluate", "--model", model, bench, "--json"],
        "replay vehicle": ["replay", vehicle, "-o", tmp_path / "rv", "--model", model, "--json", *ns],
        "replay bench": ["replay", bench, "-o", tmp_path / "rb", "--model", model, "--json"],
    }
    with ThreadPoolExecutor(max_workers=2) as pool:
        procs = dict(zip(cases, pool.map(lambda a: run(*a, cwd=tmp_path), cases.values()), strict=True))
    for proc in procs.values():
        assert proc.returncode == 0, proc.stderr
    ev, eb = (json.loads(procs[f"evaluate {k}"].stdout) for k in ("vehicle", "bench"))
    assert ev["rmse_rad_s"] == eb["rmse_rad_s"] and np.isfinite(eb["rmse_rad_s"])
    assert ev["recordings"][0]["max_error_rad_s"] == eb["recordings"][0]["max_error_rad_s"]
    with open_recording(tmp_path / "rv", "motor3") as v, open_recording(tmp_path / "rb") as b:
        assert "motor3/predicted/speed" in v.topics() and "battery/voltage" in v.topics()
        for topic in (c.TOPIC_ROTOR_SPEED, c.TOPIC_PREDICTED_SPEED):
            assert all(np.array_equal(x, y) for x, y in zip(v.scalars(topic), b.scalars(topic), strict=True)), topic
        assert all(np.array_equal(x, y) for x, y in zip(v.battery_voltages(), b.battery_voltages(), strict=True))


def test_a_namespace_per_recording_trains_on_one_motor_and_validates_on_another(home, tmp_path):
    """BAG@NS (specs.py): motor 0 and motor 1 of one flight are two recordings; the suffix wins
    over --namespace; one motor given twice is still refused, and an output never replaces the
    recording named with a suffix."""
    bag = home / "vehicle"
    m1 = load_signals(f"{bag}@motor1", namespace="motor0")  # the suffix wins
    direct = load_signals(bag, namespace="motor1")
    assert m1.namespace == "motor1" and np.array_equal(m1.speed, direct.speed)
    assert m1.key != load_signals(f"{bag}@motor0").key
    before = digest(home)
    ok = run("train", f"{bag}@motor0", "--validation", f"{bag}@motor1", "-o", tmp_path / "m.npz",
             "--hidden", "5", "--restarts", "2", "--max-epochs", "40", "--patience", "40", "--json",
             cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    sources = json.loads(ok.stdout)
    assert sources["model"].endswith("m.npz")
    same = run("train", f"{bag}@motor0", "--validation", bag, "--namespace", "motor0", "-o", tmp_path / "n.npz",
               cwd=tmp_path)
    assert same.returncode == 2 and "same recording as training recording" in same.stderr
    ev = run("evaluate", "--model", tmp_path / "m.npz", f"{bag}@motor0", f"{bag}@motor1", "--json", cwd=tmp_path)
    assert ev.returncode == 0, ev.stderr
    assert [r["path"] for r in json.loads(ev.stdout)["recordings"]] == [f"{bag}@motor0", f"{bag}@motor1"]
    onto = run("replay", f"{bag}@motor1", "-o", bag, "--force", cwd=tmp_path)
    assert onto.returncode == 2 and "an output never replaces an input" in onto.stderr
    assert digest(home) == before
