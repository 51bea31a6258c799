"""Training and evaluation from recordings, against simulator truth and hand-checked behaviour."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.bagio import BagWriter
from bldc_propulsion.core.estimator import ThrustEstimator
from bldc_propulsion.errors import BadInputError, BagError, OutputExistsError
from bldc_propulsion.model import load_model, save_model
from bldc_propulsion.recordings import load_all, load_signals
from bldc_propulsion.sim import simulate
from bldc_propulsion.sim.record import write_sim_bag
from bldc_propulsion.training.evaluate import evaluate, predict_speed
from bldc_propulsion.training.train import fit_thrust_coefficient, train_model

ROOT = Path(__file__).resolve().parents[1]
BRAKING = {"spin_down_asymmetry": 0.0}  # an actively braking ESC, as in the sample bags


def _bag(d: Path, name: str, profile: str, duration: float, seed: int, soc: float) -> Path:
    write_sim_bag(simulate(profile, duration, seed, effects=BRAKING, soc=soc), d / name)
    return d / name


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """Small recordings spanning the pack's charge, like separate bench sessions."""
    d = tmp_path_factory.mktemp("training")
    return {
        "s_full": _bag(d, "s_full", "staircase", 24, 1, 1.0),
        "t_full": _bag(d, "t_full", "triangle", 24, 2, 0.9),
        "s_half": _bag(d, "s_half", "staircase", 24, 3, 0.55),
        "t_half": _bag(d, "t_half", "triangle", 24, 4, 0.45),
        "val": _bag(d, "val", "triangle", 20, 5, 0.7),
        "test_low": _bag(d, "test_low", "staircase", 24, 6, 0.6),
    }


def _train(bags, inputs=c.DEFAULT_INPUTS, hidden=10, seed=0):
    train = load_all([bags[k] for k in ("s_full", "t_full", "s_half", "t_half")], "training")
    return train_model(train, load_all([bags["val"]], "validation"), inputs=inputs, hidden=hidden,
                       seed=seed, thrust_coefficient=2.8e-5, max_epochs=200)


@pytest.fixture(scope="module")
def trained(bags):
    return _train(bags)


def test_decoded_speed_and_filtered_voltage_match_truth(bags):
    res = simulate("staircase", 24, 1, effects=BRAKING, soc=1.0)
    sig = load_signals(bags["s_full"])
    truth = np.interp(sig.t, res.truth_t, res.truth_speed)
    steady = truth > 100
    rel = (sig.speed[steady] - truth[steady]) / truth[steady]
    assert np.sqrt(np.mean(rel**2)) < 0.02
    settled = sig.t > 3.0
    v_truth = np.interp(sig.t, res.truth_t, res.truth_voltage)
    assert np.sqrt(np.mean((sig.voltage[settled] - v_truth[settled]) ** 2)) < 0.15
    assert np.allclose(np.diff(sig.t), 0.01)


def test_decoded_speed_has_no_zero_while_a_spin_up_turns(tmp_path):
    """From rest the first speed needs a full revolution; until then the rotor is turning at up
    to ~180 rad/s. A 0 placed at the batches in between (as before) is a wrong measurement:
    the decoded speed must follow the simulator's truth through every spin-up from rest."""
    t = np.arange(0.0, 14.0, 1.0 / c.PWM_FRAME_HZ)
    level = np.full(len(t), c.PWM_STOP)
    starts = (1.0, 5.0, 9.0)
    for t0, lev in zip(starts, (0.09, 0.075, 0.10), strict=True):
        level[(t >= t0) & (t < t0 + 2.0)] = lev
    res = simulate("steps", 14.0, 3, effects=BRAKING, pwm=(t, level))
    write_sim_bag(res, tmp_path / "starts")
    sig = load_signals(tmp_path / "starts")
    truth = np.interp(sig.t, res.truth_t, res.truth_speed)
    for t0 in starts:
        near = (sig.t >= t0) & (sig.t < t0 + 0.4)
        assert truth[near].max() > 150.0
        err = sig.speed[near] - truth[near]
        # before: 0 for ~0.1 s while the truth rose to 150-180 rad/s (RMSE ~60 rad/s)
        assert np.sqrt(np.mean(err**2)) < 15.0, (t0, np.round(err, 1))
        assert np.all(sig.speed[near & (truth > 60.0)] > 0.4 * truth[near & (truth > 60.0)])
    rest = truth < 1e-6
    assert rest.sum() > 100 and np.all(sig.speed[rest & (sig.t < 0.95)] == 0.0)


def test_training_fits_and_stops_on_validation(trained):
    h = trained.lm.history
    best = trained.lm.best_epoch
    assert h.val_cost[best] == np.nanmin(h.val_cost[: trained.lm.epochs + 1])
    assert h.train_cost[best] < 0.05 * h.train_cost[0]
    assert trained.validation_rmse_rad_s < 25.0  # of a ~550 rad/s range, on another pack charge
    meta = trained.model.metadata
    assert len(meta["sources"]["train"]) == 4 and all(len(s["sha256"]) == 64 for s in meta["sources"]["train"])


def test_thrust_coefficient_is_fitted_from_the_load_cell(trained):
    b_true = simulate("constant", 2, 0).params.thrust_coefficient
    assert trained.thrust.coefficient == pytest.approx(b_true, rel=0.01)
    assert trained.thrust.residual_rms_n < 0.05  # the load cell's 0.02 N noise


def test_thrust_fit_by_hand():
    class S:
        speed = np.linspace(100.0, 600.0, 20)
        thrust = 3e-5 * speed**2 + 0.01 * (-1.0) ** np.arange(20)

    fit = fit_thrust_coefficient([S()], 1.0)  # measured wins over a stated b (and warns: test_thrust_coefficient.py)
    x, y = S.speed**2, S.thrust
    assert fit.coefficient == pytest.approx(np.dot(x, y) / np.dot(x, x), rel=1e-12)
    given = fit_thrust_coefficient([], 2.5e-5)
    assert given.coefficient == 2.5e-5 and given.residual_rms_n is None
    assert fit_thrust_coefficient([]).coefficient is None  # nothing measured or stated: no b


def test_model_file_round_trips_into_the_estimator_core(trained, bags, tmp_path):
    """The node's streaming estimator reproduces the trainer's batch predictions."""
    path = tmp_path / "m.npz"
    save_model(trained.model, path)
    model = load_model(path)
    sig = load_signals(bags["test_low"])
    batch = predict_speed(model, sig)
    est = ThrustEstimator(model)
    events = sorted(
        [(t, 0, v) for t, v in zip(*sig.pwm_events, strict=True)]
        + [(t, 1, v) for t, v in zip(*sig.voltage_events, strict=True)]
    )
    stream = np.full(len(sig.t), np.nan)
    k = 0
    for i, tg in enumerate(sig.t):
        while k < len(events) and events[k][0] <= tg:
            t, kind, v = events[k]
            (est.update_pwm if kind == 0 else est.update_voltage)(t, v)
            k += 1
        p = est.predict(tg)
        if p.ready:
            stream[i] = p.speed_rad_s
    ok = np.isfinite(stream)
    assert ok.mean() > 0.95
    np.testing.assert_allclose(stream[ok], batch[ok], rtol=1e-9, atol=1e-9)


def test_battery_voltage_input_wins_at_a_lower_charge(bags, trained):
    """The paper's thesis: with the filtered battery voltage the model beats one without."""
    without = _train(bags, inputs=(c.INPUT_PWM, c.INPUT_PWM_FILTERED))
    sig = [load_signals(bags["test_low"])]
    rmse_with, _, _ = evaluate(trained.model, sig)
    rmse_without, _, _ = evaluate(without.model, sig)
    assert rmse_with < 0.6 * rmse_without, (rmse_with, rmse_without)


#: The chirp test's bench sessions: staircase and triangle recordings on packs at six states of
#: charge (the voltage input can only be learned from recordings that span it), validated on
#: random steps at another charge (a recording unlike the training ones, so early stopping and
#: the choice among restarts favour the network that generalises to other commands).
CHIRP_TRAINING = [("staircase", 1.0), ("triangle", 0.9), ("staircase", 0.75), ("triangle", 0.6),
                  ("staircase", 0.45), ("triangle", 0.3)]


def test_chirp_slow_part_within_two_percent(tmp_path_factory):
    """Issue 4's accuracy goal: trained on staircase and triangle, the chirp's slow part
    (< 0.5 Hz) within 2 % of the speed range (small size; benchmarks/bench_accuracy.py runs it
    at the paper's size). Measured when written: 1.73 % (best of 3 restarts by validation)."""
    d = tmp_path_factory.mktemp("chirp")
    train = [load_signals(_bag(d, f"{kind}_{soc}", kind, 24, 1 + k, soc))
             for k, (kind, soc) in enumerate(CHIRP_TRAINING)]
    val = [load_signals(_bag(d, "val", "random_steps", 20, 5, 0.7))]
    out = train_model(train, val, hidden=10, seed=0, restarts=3, thrust_coefficient=2.8e-5, max_epochs=200)
    chirp = load_signals(_bag(d, "chirp", "chirp", 50, 7, 0.85))
    _, scores, _ = evaluate(out.model, [chirp])
    slow = next(b for b in scores[0].bands if b["high_hz"] <= 0.5)
    assert slow["samples"] > 1000  # about half the recording (the chirp's first octaves)
    assert slow["rmse_percent_of_range"] < 2.0, scores[0].bands
    # the paper's observation, quantified: the error grows with the command's frequency
    fast = scores[0].bands[-1]
    assert fast["rmse_percent_of_range"] > 2.0 * slow["rmse_percent_of_range"]


def test_restarts_keep_the_run_with_the_least_validation_cost(bags):
    train = load_all([bags[k] for k in ("s_full", "t_half")], "training")
    val = load_all([bags["val"]], "validation")
    kw = {"hidden": 4, "thrust_coefficient": 2.8e-5, "max_epochs": 30}
    singles = [train_model(train, val, seed=s, **kw) for s in (3, 4, 5)]
    best = train_model(train, val, seed=3, restarts=3, **kw)
    costs = [o.lm.val_cost for o in singles]
    k = int(np.argmin(costs))
    assert best.model.metadata["best_seed"] == 3 + k
    assert best.lm.val_cost == costs[k]
    np.testing.assert_array_equal(best.model.W1, singles[k].model.W1)
    assert [r["validation_cost"] for r in best.model.metadata["restarts"]] == costs
    with pytest.raises(BadInputError, match="--restarts 0"):
        train_model(train, val, restarts=0, **kw)


def test_training_is_deterministic_for_a_seed(bags):
    a = _train(bags, hidden=4, seed=3)
    b = _train(bags, hidden=4, seed=3)
    np.testing.assert_array_equal(a.model.W1, b.model.W1)


# --- the command line ---------------------------------------------------------------------
def run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *args],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)


def test_train_and_evaluate_commands(bags, tmp_path):
    model = tmp_path / "m.npz"
    proc = run("train", str(bags["s_full"]), str(bags["t_half"]), "--validation", str(bags["val"]),
               "-o", str(model), "--hidden", "6", "--json", "--report", str(tmp_path / "rep"))
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert {"model", "epochs", "train_cost", "validation_cost"} <= set(info)
    assert "epoch" in proc.stderr and "mu" in proc.stderr  # one progress line per epoch
    assert (tmp_path / "rep" / "index.html").is_file()
    assert len(list((tmp_path / "rep").glob("*.png"))) >= 3
    proc = run("evaluate", "--model", str(model), str(bags["test_low"]), "--json")
    assert proc.returncode == 0, proc.stderr
    ev = json.loads(proc.stdout)
    rec = ev["recordings"][0]
    assert rec["path"] == str(bags["test_low"]) and rec["rmse_rad_s"] <= rec["max_error_rad_s"]
    assert ev["rmse_rad_s"] == pytest.approx(rec["rmse_rad_s"])
    # an existing model is never replaced without --force
    before = model.read_bytes()
    proc = run("train", str(bags["s_full"]), "--validation", str(bags["val"]), "-o", str(model))
    assert proc.returncode == 2 and "already exists" in proc.stderr
    assert model.read_bytes() == before


def test_bad_recordings_give_one_line_errors(bags, tmp_path):
    with pytest.raises(BagError, match="no such recording"):
        load_signals(tmp_path / "missing")
    with BagWriter(tmp_path / "no_tach") as bag:  # pwm and voltage but no speed source
        for k in range(200):
            bag.write_float64(c.TOPIC_PWM, k * 0.02, 0.07)
            bag.write_float64(c.TOPIC_BATTERY_ADC, k * 0.02, 6.0)
    with pytest.raises(BagError, match="neither /rotor/speed nor /tachometer/adc"):
        load_signals(tmp_path / "no_tach")
    write_sim_bag(simulate("staircase", 0.3, 1), tmp_path / "short")
    with pytest.raises(BadInputError, match="too short"):
        load_signals(tmp_path / "short")
    proc = run("train", str(bags["s_full"]), "--validation", str(bags["s_full"]), "-o", str(tmp_path / "m.npz"))
    assert proc.returncode == 2 and "both training and validation" in proc.stderr
    proc = run("train", str(tmp_path / "no_tach"), "--validation", str(bags["val"]), "-o", str(tmp_path / "m.npz"))
    errors = [line for line in proc.stderr.splitlines() if "error" in line]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert len(errors) == 1 and "no_tach" in errors[0]
    assert not (tmp_path / "m.npz").exists()


def test_too_little_data_is_refused(bags):
    train = load_all([bags["s_full"]], "training")
    with pytest.raises(BadInputError, match="too little training data"):
        train_model(train, load_all([bags["val"]], "validation"), hidden=2000, thrust_coefficient=2.8e-5)


def test_existing_model_file_is_not_overwritten(trained, tmp_path):
    path = tmp_path / "m.npz"
    save_model(trained.model, path)
    with pytest.raises(OutputExistsError):
        save_model(trained.model, path)


def test_reference_recordings_are_found_from_another_directory(bags, tmp_path, monkeypatch):
    """A model trained on relative paths still finds its training recordings elsewhere."""
    from bldc_propulsion.commands.discrepancy import reference_paths

    monkeypatch.chdir(bags["s_full"].parent)
    train = load_all(["s_full"], "training")
    outcome = train_model(train, load_all(["val"], "validation"), hidden=3, max_epochs=3,
                          thrust_coefficient=2.8e-5)
    monkeypatch.chdir(tmp_path)
    found, missing = reference_paths(outcome.model, str(tmp_path / "m.npz"))
    assert missing == [] and [os.path.realpath(p) for p in found] == [os.path.realpath(bags["s_full"])]
    assert outcome.model.metadata["sources"]["train"][0]["path"] == "s_full"
