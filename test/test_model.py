"""Model file: round trip, and every way a file can be wrong is a ModelError naming file and problem."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from bldc_propulsion.core.estimator import ThrustEstimator
from bldc_propulsion.errors import ModelError, OutputExistsError
from bldc_propulsion.model import REQUIRED_KEYS, NetworkModel, load_model, save_model


def model(hidden=25, seed=0) -> NetworkModel:
    rng = np.random.default_rng(seed)
    return NetworkModel(
        input_names=("battery_voltage", "pwm", "pwm_filtered"),
        input_min=np.array([9.5, 0.0, 0.0]),
        input_max=np.array([12.6, 1.0, 1.0]),
        output_min=0.0,
        output_max=650.0,
        W1=rng.normal(size=(hidden, 3)),
        b1=rng.normal(size=hidden),
        W2=rng.normal(size=hidden) / hidden,
        b2=0.1,
        pwm_tau_s=0.3,
        thrust_coefficient=2.5e-5,
        metadata={"epochs": 12, "sources": [{"path": "a", "sha256": "00"}],
                  "feature_params": {"pwm_filtered": {"tau_s": 0.3}}},
    )


def arrays_of(m: NetworkModel) -> dict[str, np.ndarray]:
    return m._arrays()


def write_npz(path, arrays, allow_pickle=False):
    with open(path, "wb") as fh:
        np.savez(fh, allow_pickle=allow_pickle, **arrays)


def test_round_trip_identical_predictions(tmp_path):
    m = model()
    path = tmp_path / "m.npz"
    save_model(m, path)
    assert path.exists() and not list(tmp_path.glob(".*partial*"))
    m2 = load_model(path)
    assert m2.input_names == m.input_names
    for k in ("input_min", "input_max", "W1", "b1", "W2"):
        np.testing.assert_array_equal(getattr(m2, k), getattr(m, k))
    assert (m2.b2, m2.pwm_tau_s, m2.thrust_coefficient) == (m.b2, m.pwm_tau_s, m.thrust_coefficient)
    assert m2.metadata == m.metadata
    X = np.random.default_rng(1).uniform([9.5, 0, 0], [12.6, 1, 1], size=(100, 3))
    np.testing.assert_array_equal(m.forward(X), m2.forward(X))
    preds = []
    for mm in (m, m2):
        est = ThrustEstimator(mm)
        est.update_voltage(0.0, 11.0)
        out = []
        for k, lvl in enumerate((0.05, 0.07, 0.09, 0.06)):
            est.update_pwm(k * 0.5, lvl)
            out.append(est.predict(k * 0.5 + 0.2))
        preds.append(out)
    assert preds[0] == preds[1]
    # the file holds exactly the documented arrays with their dtypes
    with np.load(path, allow_pickle=False) as z:
        assert set(z.files) == set(REQUIRED_KEYS)
        assert z["format_version"].dtype == np.int64 and z["format_version"].shape == ()
        assert z["input_names"].dtype.kind == "U"
        assert z["metadata_json"].shape == () and json.loads(str(z["metadata_json"]))["epochs"] == 12
        assert z["W1"].dtype == np.float64


def test_save_refuses_existing_file(tmp_path):
    path = tmp_path / "m.npz"
    save_model(model(), path)
    before = path.read_bytes()
    with pytest.raises(OutputExistsError):
        save_model(model(seed=2), path)
    assert path.read_bytes() == before
    save_model(model(seed=2), path, force=True)
    assert path.read_bytes() != before


def test_save_name_without_npz_suffix_kept(tmp_path):
    path = tmp_path / "model_file"
    save_model(model(), path)
    assert path.exists() and not (tmp_path / "model_file.npz").exists()
    load_model(path)


def test_feature_params_from_model():
    assert model().feature_params()["pwm_filtered"]["tau_s"] == 0.3


def test_nonexistent_file(tmp_path):
    with pytest.raises(ModelError, match="no such model file"):
        load_model(tmp_path / "missing.npz")


def test_not_an_npz(tmp_path):
    p = tmp_path / "junk.npz"
    p.write_text("this is not a model\n")
    with pytest.raises(ModelError, match=str(p.name)):
        load_model(p)
    q = tmp_path / "single.npy"
    np.save(q, np.zeros(3))
    with pytest.raises(ModelError, match="archive"):
        load_model(q)
    with pytest.raises(ModelError, match="directory"):
        load_model(tmp_path)


def test_pickled_object_array_refused(tmp_path):
    a = arrays_of(model())
    a["metadata_json"] = np.array([{"evil": os.getcwd}], dtype=object)
    p = tmp_path / "pickled.npz"
    write_npz(p, a, allow_pickle=True)
    with pytest.raises(ModelError, match="pickled"):
        load_model(p)


@pytest.mark.parametrize("key", ["W2", "input_names", "format_version", "metadata_json"])
def test_missing_array(tmp_path, key):
    a = arrays_of(model())
    del a[key]
    p = tmp_path / "m.npz"
    write_npz(p, a)
    with pytest.raises(ModelError, match=f"{p}: missing array.*{key}"):
        load_model(p)


@pytest.mark.parametrize("key, value, message", [
    ("W1", np.ones((25, 4)), "W1 must have shape"),
    ("b1", np.ones(24), "b1 must have shape"),
    ("W2", np.ones((25, 1)), "W2 must have shape"),
    ("b2", np.ones(1), "b2 must have shape"),
    ("input_min", np.zeros(2), "input_min must have shape"),
    ("W1", np.full((25, 3), np.nan), "W1 contains NaN"),
    ("b1", np.full(25, np.inf), "b1 contains NaN or inf"),
    ("input_names", np.array(["battery_voltage", "pwm", "warp_drive"]), "unknown model input 'warp_drive'"),
    ("input_names", np.array([1, 2, 3]), "input_names must be"),
    ("input_max", np.array([9.0, 1.0, 1.0]), "input_min must be < input_max"),
    ("output_max", np.array(-1.0), "output_min must be < output_max"),
    ("format_version", np.array(3, dtype=np.int64), "format_version 3 is not supported"),
    ("format_version", np.array(1.0), "format_version must be a scalar integer"),
    ("W1", np.ones((25, 3), dtype=np.int64), "W1 must be a float array"),
    ("metadata_json", np.array("{not json"), "metadata_json is not valid JSON"),
    ("metadata_json", np.array("[1, 2]"), "JSON object"),
    ("pwm_tau_s", np.array(0.0), "pwm_tau_s must be > 0"),
    ("thrust_coefficient", np.array(-1e-5), "thrust_coefficient must be >= 0"),
])
def test_invalid_arrays(tmp_path, key, value, message):
    a = arrays_of(model())
    a[key] = value
    p = tmp_path / "bad.npz"
    write_npz(p, a)
    with pytest.raises(ModelError) as info:
        load_model(p)
    assert str(info.value).startswith(f"{p}: ")
    assert message in str(info.value)


def test_bad_feature_parameters_in_metadata(tmp_path):
    a = arrays_of(model())
    a["metadata_json"] = np.array(json.dumps({"feature_params": {"pwm_filtered": {"speed_of_light": 3}}}))
    p = tmp_path / "bad.npz"
    write_npz(p, a)
    with pytest.raises(ModelError, match="speed_of_light"):
        load_model(p)


def test_truncated_file(tmp_path):
    p = tmp_path / "m.npz"
    save_model(model(), p)
    data = p.read_bytes()
    q = tmp_path / "trunc.npz"
    q.write_bytes(data[: len(data) // 2])
    with pytest.raises(ModelError, match=str(q.name)):
        load_model(q)


def test_constructor_validates_structure_names_checked_on_use(tmp_path):
    with pytest.raises(ModelError, match="input_min must be < input_max"):
        model().__class__(**{**model().__dict__, "input_min": np.array([13.0, 0.0, 0.0])})
    with pytest.raises(ModelError, match="W1 must have shape"):
        NetworkModel(("pwm", "pwm_filtered"), [0, 0], [1, 1], 0.0, 1.0, np.ones((2, 3)), np.zeros(2), np.ones(2), 0.0)
    # which names are known depends on the registered features: checked on save, load and use
    m = NetworkModel(("pwm", "nope"), [0, 0], [1, 1], 0.0, 1.0, np.ones((2, 2)), np.zeros(2), np.ones(2), 0.0)
    with pytest.raises(ModelError, match="unknown model input 'nope'"):
        save_model(m, tmp_path / "m.npz")
    assert not (tmp_path / "m.npz").exists()
    with pytest.raises(ModelError, match="nope"):
        ThrustEstimator(m)


def test_forward_shapes():
    m = model()
    assert np.shape(m.forward(np.array([11.0, 0.5, 0.5]))) == ()
    assert m.forward(np.ones((7, 3))).shape == (7,)
