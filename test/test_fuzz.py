"""Bounded fuzzing (hypothesis, derandomized, a fixed small budget) of the two parsers of
untrusted files: the thrust-stand CSV importer and the model loader.

The CSV importer either succeeds or raises BadInputError (one line naming the file); the
model loader either returns a valid model or raises ModelError. Anything else is a crash.
Crashes found here are kept as explicit regression tests at the bottom.
"""

from __future__ import annotations

import io
import itertools
import math
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from _models import good_model  # noqa: E402
from bldc_propulsion.core.estimator import ThrustEstimator
from bldc_propulsion.errors import BadInputError, ModelError
from bldc_propulsion.model import load_model, save_model
from bldc_propulsion.training import import_csv as ic

BUDGET = settings(max_examples=int(os.environ.get("BLDC_FUZZ_EXAMPLES", "120")), deadline=None, derandomize=True,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                         HealthCheck.function_scoped_fixture])
_counter = itertools.count()
_TMP = Path(tempfile.mkdtemp(prefix="bldc_fuzz_"))


def _fresh(suffix: str) -> Path:
    return _TMP / f"f{next(_counter)}{suffix}"


# --- CSV importer -----------------------------------------------------------------------------
COLUMNS = [ic.COL_TIME, ic.COL_ESC, ic.COL_VOLTAGE, ic.COL_CURRENT, ic.COL_THRUST_N,
           ic.COL_THRUST_KGF, ic.COL_RPM_ELECTRICAL, ic.COL_RPM_OPTICAL, ic.COL_TORQUE,
           ic.COL_MECH_POWER, "Comment", "", "Time (s)"]
CELL = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-3000, 3000).map(lambda v: f"{v:.4g}"),
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(["", " ", "nan", "inf", "-inf", "1e999", "1,5", "0x10", "NaN", "--", '"', "\x00", "µs"]),
    st.text(max_size=8),
)


@st.composite
def csv_texts(draw):
    cols = draw(st.lists(st.sampled_from(COLUMNS), min_size=0, max_size=8))
    sep = draw(st.sampled_from([",", ";", "\t", ",,"]))
    rows = draw(st.lists(st.lists(CELL, min_size=0, max_size=len(cols) + 2), max_size=25))
    lines = [sep.join(cols)] + [sep.join(r) for r in rows]
    if draw(st.booleans()):  # a plausible, increasing log with some damage
        t0 = draw(st.floats(-10, 10))
        for k in range(draw(st.integers(0, 30))):
            lines.append(",".join([f"{t0 + 0.1 * k:.3f}", f"{1000 + 40 * k}", "12.1", "3.2", "5.5", "", "9000",
                                   "", "0.1", "50"][:len(cols)]))
    return draw(st.sampled_from(["\n", "\r\n", "\r"])).join(lines)


def _import_must_not_crash(src: Path) -> None:
    try:
        ic.import_csv(src, _fresh(".bag"))
    except BadInputError as exc:
        text = str(exc)
        assert "\n" not in text and text  # one line
    # anything else propagates: a crash


@BUDGET
@given(csv_texts())
def test_fuzz_csv_text(text):
    src = _fresh(".csv")
    src.write_bytes(text.encode("utf-8", errors="replace"))  # lone surrogates -> "?"
    _import_must_not_crash(src)


@BUDGET
@given(st.binary(max_size=400))
def test_fuzz_csv_bytes(data):
    src = _fresh(".csv")
    src.write_bytes(data)
    _import_must_not_crash(src)


# --- model loader -----------------------------------------------------------------------------


_GOOD = _fresh(".npz")
save_model(good_model(), _GOOD)
GOOD_BYTES = _GOOD.read_bytes()
with np.load(_GOOD) as _z:
    GOOD_ARRAYS = {k: _z[k] for k in _z.files}


def _load_must_not_crash(path: Path) -> None:
    try:
        m = load_model(path)
    except ModelError as exc:
        assert str(exc).startswith(f"{path}") and "\n" not in str(exc)
        return
    # a model that loads must be usable: finite forward on in-range inputs, an estimator
    X = (m.input_min + m.input_max) / 2.0
    assert np.all(np.isfinite(m.forward(X[None, :])))
    est = ThrustEstimator(m)
    est.update_pwm(0.0, 0.07)
    est.update_voltage(0.0, 11.5)
    p = est.predict(0.1)
    assert not p.ready or (math.isfinite(p.speed_rad_s) and p.speed_rad_s >= 0)


@BUDGET
@given(st.lists(st.tuples(st.integers(0, len(GOOD_BYTES) - 1), st.integers(1, 255)), min_size=1, max_size=8),
       st.one_of(st.none(), st.integers(0, len(GOOD_BYTES))))
def test_fuzz_model_bytes(flips, cut):
    data = bytearray(GOOD_BYTES)
    for pos, x in flips:
        data[pos] ^= x
    path = _fresh(".npz")
    path.write_bytes(bytes(data[:cut] if cut is not None else data))
    _load_must_not_crash(path)


ANY_ARRAY = st.one_of(
    hnp.arrays(dtype=st.one_of(hnp.floating_dtypes(), hnp.integer_dtypes(), hnp.boolean_dtypes(),
                               hnp.complex_number_dtypes(), hnp.unicode_string_dtypes(), hnp.byte_string_dtypes()),
               shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=5)),
    st.sampled_from([np.array(1e308), np.array(-1e308), np.full((4, 3), 1e300), np.array(0.0),
                     np.array(["pwm", "pwm_filtered", "battery_voltage"]), np.array('{"feature_params": 1}'),
                     np.array('{"feature_params": {"pwm_filtered": {"tau_s": -1}}}')]),
)


@BUDGET
@given(st.dictionaries(st.sampled_from(sorted(GOOD_ARRAYS)), ANY_ARRAY, min_size=1, max_size=3))
def test_fuzz_model_arrays(replace):
    arrays = {**GOOD_ARRAYS, **replace}
    path = _fresh(".npz")
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())
    _load_must_not_crash(path)


def test_fuzz_model_zip_members():
    """A zip that is not an npz, members that are not .npy, an empty archive."""
    for members in ({}, {"W1.npy": b"not npy"}, {"readme.txt": b"hello"}):
        path = _fresh(".npz")
        with zipfile.ZipFile(path, "w") as z:
            for name, data in members.items():
                z.writestr(name, data)
        _load_must_not_crash(path)


# --- regression tests of crashes the fuzzing found ----------------------------------------------
def _zip_with(path: Path, tweak) -> Path:
    """The good model file with one byte pattern of its zip headers changed by ``tweak``."""
    data = bytearray(GOOD_BYTES)
    tweak(data)
    path.write_bytes(bytes(data))
    return path


def test_regression_unsupported_compression_method(tmp_path):
    """Fuzz find: a flipped compression-method field made zipfile raise NotImplementedError."""
    def tweak(data):
        for sig, off in ((b"PK\x03\x04", 8), (b"PK\x01\x02", 10)):  # local and central headers
            pos = data.find(sig)
            while pos >= 0:
                data[pos + off] = 99  # compression method 99 (AES), unsupported
                pos = data.find(sig, pos + 4)
    path = _zip_with(tmp_path / "m.npz", tweak)
    with pytest.raises(ModelError, match="damaged|not a model"):
        load_model(path)


def test_regression_encrypted_member(tmp_path):
    """Fuzz find: a flipped flag bit (encrypted) made zipfile raise RuntimeError."""
    def tweak(data):
        for sig, off in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
            pos = data.find(sig)
            while pos >= 0:
                data[pos + off] |= 0x01
                pos = data.find(sig, pos + 4)
    path = _zip_with(tmp_path / "m.npz", tweak)
    with pytest.raises(ModelError, match="damaged|not a model"):
        load_model(path)


@pytest.mark.parametrize("change", [
    {"b2": np.array(1e308)},             # fuzz find: finite, but forward() overflowed to inf
    {"W2": np.full(4, 1e308)},
    {"W1": np.array([[1e308, -1e308, 1e308]] * 4)},  # inf - inf in the hidden layer: NaN
    {"output_min": np.array(-1.7e308), "output_max": np.array(1.7e308)},  # output span overflows
    {"input_min": np.array([-1.7e308, 0.05, 0.05]), "input_max": np.array([1.7e308, 0.1, 0.1])},
])
def test_regression_finite_but_overflowing_model(tmp_path, change):
    path = tmp_path / "m.npz"
    np.savez(path, **{**GOOD_ARRAYS, **change})
    with pytest.raises(ModelError, match="overflow"):
        load_model(path)
