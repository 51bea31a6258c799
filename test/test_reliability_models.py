"""Bad model files: a clear ModelError at load naming the file and the problem.

test/test_model.py already covers: a pickled object array (test_pickled_object_array_refused),
missing arrays (test_missing_array), wrong shapes, NaN in W1, inf in b1, unknown input names,
wrong format_version, integer weights, bad metadata JSON (test_invalid_arrays), bad feature
parameters (test_bad_feature_parameters_in_metadata), a truncated file (test_truncated_file),
not an npz (test_not_an_npz). The node refusing to start / keeping its last good model on a
reload is in test/test_nodes_ros.py (test_thrust_estimator_refuses_a_bad_model,
test_thrust_estimator_keeps_the_last_good_model_on_a_bad_reload; they need rclpy).
This file adds what those do not try.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _models import good_model  # noqa: E402
from bldc_propulsion.core.estimator import ThrustEstimator
from bldc_propulsion.errors import ModelError
from bldc_propulsion.model import load_model, save_model

ROOT = Path(__file__).resolve().parents[1]




@pytest.fixture()
def arrays(tmp_path):
    p = tmp_path / "good.npz"
    save_model(good_model(), p)
    with np.load(p) as z:
        return {k: z[k] for k in z.files}


def write(path: Path, arrays: dict) -> Path:
    np.savez(path, **arrays)
    return path


def nan_of(a: np.ndarray) -> np.ndarray:
    b = np.array(a, dtype=float, copy=True)
    b.reshape(-1)[0] = np.nan
    return b


@pytest.mark.parametrize("key", ["input_min", "input_max", "output_min", "output_max", "W2", "b2",
                                 "pwm_tau_s"])
def test_nan_in_any_float_array(tmp_path, arrays, key):
    p = write(tmp_path / "m.npz", {**arrays, key: nan_of(arrays[key])})
    with pytest.raises(ModelError, match=rf"^{p}: {key} contains NaN or inf"):
        load_model(p)


def test_thrust_coefficient_nan_is_no_b_and_inf_is_refused(tmp_path, arrays):
    """NaN is how a file says the model has no b (nothing measured or stated); inf is damage."""
    p = write(tmp_path / "none.npz", {**arrays, "thrust_coefficient": np.array(np.nan)})
    assert load_model(p).thrust_coefficient is None
    p = write(tmp_path / "inf.npz", {**arrays, "thrust_coefficient": np.array(np.inf)})
    with pytest.raises(ModelError, match=rf"^{p}: thrust_coefficient must be >= 0 and finite"):
        load_model(p)


@pytest.mark.parametrize("key, value, message", [
    ("W1", lambda a: a["W1"].astype(complex), "W1 must be a float array"),
    ("W2", lambda a: a["W2"] > 0, "W2 must be a float array"),
    ("W1", lambda a: a["W1"].astype(str), "W1 must be a float array"),
    ("W1", lambda a: a["W1"][..., None], "W1 must have shape"),
    ("W1", lambda a: np.zeros((0, 3)), "W1 must have shape"),
    ("input_names", lambda a: np.array(["pwm", "pwm", "battery_voltage"]), "repeat a name"),
    ("input_names", lambda a: np.array([], dtype="<U1"), "non-empty 1-D"),
    ("input_names", lambda a: a["input_names"][None, :], "non-empty 1-D"),
    ("input_names", lambda a: np.array(["", "pwm", "battery_voltage"]), "unknown model input ''"),
    ("format_version", lambda a: np.array("1"), "format_version must be a scalar integer"),
    ("metadata_json", lambda a: np.array(5), "metadata_json must be a scalar unicode string"),
])
def test_wrong_dtype_or_structure(tmp_path, arrays, key, value, message):
    p = write(tmp_path / "m.npz", {**arrays, key: value(arrays)})
    with pytest.raises(ModelError) as info:
        load_model(p)
    assert str(info.value).startswith(f"{p}: ") and message in str(info.value)


class _Evil:
    """Unpickling this runs code: touch a file."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


@pytest.mark.parametrize("where", ["W1", "extra"])
def test_malicious_pickle_never_runs(tmp_path, arrays, where):
    marker = tmp_path / "pwned"
    evil = np.empty(1, dtype=object)
    evil[0] = _Evil(str(marker))
    p = tmp_path / "m.npz"
    np.savez(p, **{**arrays, where: evil}, allow_pickle=True)
    assert b"pwned" in p.read_bytes()  # the pickle is really in the file
    if where == "W1":
        with pytest.raises(ModelError, match="pickled|Python objects"):
            load_model(p)
    else:  # an unknown extra array is never read
        load_model(p)
    assert not marker.exists()


def test_model_needing_an_input_the_recording_lacks_waits_and_says_so():
    """A model with battery_voltage fed only /pwm: no made-up prediction, status names what is missing."""
    est = ThrustEstimator(good_model())
    for k in range(50):
        est.update_pwm(0.02 * k, 0.07)
    p = est.predict(1.0)
    assert not p.ready and np.isnan(p.speed_rad_s)
    (s,) = est.status()
    assert s.level == 1 and "waiting for battery/voltage" in s.message


def _cli(*args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "bldc_propulsion.cli", *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=120)


def test_cli_bad_model_one_line_exit_2(tmp_path, arrays):
    """replay and evaluate refuse a bad model before reading anything: one line, exit 2."""
    bad = write(tmp_path / "nan.npz", {**arrays, "W2": nan_of(arrays["W2"])})
    pickled = tmp_path / "pickled.npz"
    obj = np.empty(1, dtype=object)
    obj[0] = {"a": 1}
    np.savez(pickled, **{**arrays, "W1": obj}, allow_pickle=True)
    bag = tmp_path / "missing_bag"  # the model is checked first
    for args, model, what in ((("replay", bag, "-o", tmp_path / "out", "--model"), bad, "W2 contains NaN"),
                              (("evaluate", bag, "--model"), pickled, "Python objects")):
        proc = _cli(*args, model, cwd=tmp_path)
        assert proc.returncode == 2, proc.stderr
        assert "Traceback" not in proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and str(model) in lines[0] and what in lines[0], proc.stderr
        assert not (tmp_path / "out").exists()
