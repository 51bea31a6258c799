"""The trained speed model: an n-H-1 network (tanh hidden layer, linear output) and its .npz file.

File format (``format_version`` 1), every array required:

| key | shape / dtype | meaning |
|---|---|---|
| ``format_version`` | () int64 | 1 |
| ``input_names`` | (n,) unicode | model inputs in order (core/features.py registry) |
| ``input_min``, ``input_max`` | (n,) float64 | scaling of inputs to [-1, 1] |
| ``output_min``, ``output_max`` | () float64 | scaling of speed (rad/s) to [-1, 1] |
| ``W1`` (H, n), ``b1`` (H,), ``W2`` (H,), ``b2`` () | float64 | network weights |
| ``pwm_tau_s`` | () float64 | time constant of ``pwm_filtered`` (paper: 0.25 s) |
| ``thrust_coefficient`` | () float64 | b in thrust = b w^2 (N s^2/rad^2) |
| ``metadata_json`` | () unicode | JSON object: provenance, costs, ``feature_params`` |

Files are read with ``allow_pickle=False`` (a model file cannot run code) and validated
completely; every problem is a ``ModelError("<path>: <what is wrong>")``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import contract as c
from .atomic import MODEL, atomic_output, describe_path
from .errors import ModelError, one_line

FORMAT_VERSION = 1
#: b of a 12x4.5 propeller, CT rho D^4 / (4 pi^2) with CT ~ 0.105: rough, for when nothing is fitted
NOMINAL_THRUST_COEFFICIENT = 2.8e-5

_FLOAT_KEYS_SCALAR = ("output_min", "output_max", "b2", "pwm_tau_s", "thrust_coefficient")
REQUIRED_KEYS: tuple[str, ...] = (
    "format_version", "input_names", "input_min", "input_max", "output_min", "output_max",
    "W1", "b1", "W2", "b2", "pwm_tau_s", "thrust_coefficient", "metadata_json",
)


@dataclass
class NetworkModel:
    """Weights and scaling of the speed network (SI units: inputs as features.py makes them, rad/s)."""

    input_names: tuple[str, ...]
    input_min: np.ndarray
    input_max: np.ndarray
    output_min: float
    output_max: float
    W1: np.ndarray
    b1: np.ndarray
    W2: np.ndarray
    b2: float
    pwm_tau_s: float = c.PAPER_PWM_TAU_S
    thrust_coefficient: float = NOMINAL_THRUST_COEFFICIENT
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.input_names = tuple(str(n) for n in self.input_names)
        for k in ("input_min", "input_max", "W1", "b1", "W2"):
            setattr(self, k, np.array(getattr(self, k), dtype=float))
        for k in _FLOAT_KEYS_SCALAR:
            v = getattr(self, k)
            if np.ndim(v) != 0:
                raise ModelError(f"model: {k} must be a scalar, got shape {np.shape(v)}")
            setattr(self, k, float(v))
        if not isinstance(self.metadata, dict):
            raise ModelError("model: metadata must be a dict")
        # structure only: whether the input names are known depends on which modules have
        # registered features, so names are checked on load, on save and when features are built
        _check(self._arrays(), "model", check_names=False)

    @property
    def n_inputs(self) -> int:
        return len(self.input_names)

    @property
    def hidden(self) -> int:
        return int(self.W1.shape[0])

    def feature_params(self) -> dict[str, dict[str, float]]:
        """Parameters of the input features: the metadata's ``feature_params``, with pwm_tau_s."""
        out = {k: dict(v) for k, v in (self.metadata.get("feature_params") or {}).items()}
        out.setdefault(c.INPUT_PWM_FILTERED, {})["tau_s"] = self.pwm_tau_s
        return out

    def forward(self, X_raw: np.ndarray) -> np.ndarray:
        """Speed (rad/s) for raw inputs X_raw (m, n) -> (m,), or (n,) -> () (no clipping here)."""
        X = np.asarray(X_raw, dtype=float)
        xs = 2.0 * (X - self.input_min) / (self.input_max - self.input_min) - 1.0
        h = np.tanh(xs @ self.W1.T + self.b1)
        ys = h @ self.W2 + self.b2
        return (ys + 1.0) * (0.5 * (self.output_max - self.output_min)) + self.output_min

    def _arrays(self) -> dict[str, np.ndarray]:
        """The arrays of the .npz file."""
        return {
            "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
            "input_names": np.array(self.input_names, dtype=np.str_),
            "input_min": self.input_min,
            "input_max": self.input_max,
            "output_min": np.array(self.output_min, dtype=np.float64),
            "output_max": np.array(self.output_max, dtype=np.float64),
            "W1": self.W1,
            "b1": self.b1,
            "W2": self.W2,
            "b2": np.array(self.b2, dtype=np.float64),
            "pwm_tau_s": np.array(self.pwm_tau_s, dtype=np.float64),
            "thrust_coefficient": np.array(self.thrust_coefficient, dtype=np.float64),
            "metadata_json": np.array(json.dumps(self.metadata, sort_keys=True), dtype=np.str_),
        }


def _check(a: dict[str, np.ndarray], where: str, check_names: bool = True) -> dict[str, Any]:
    """Validate the arrays of a model; ModelError(f"{where}: ...") on the first problem.

    With ``check_names``, also that every input is a registered feature and its parameters fit.
    """
    from .core.features import feature_class, make_features  # late: features needs no model

    def fail(msg: str) -> None:
        raise ModelError(f"{where}: {msg}")

    fv = a["format_version"]
    if fv.shape != () or fv.dtype.kind not in "iu":
        fail(f"format_version must be a scalar integer, got {fv.dtype} shape {fv.shape}")
    if int(fv) != FORMAT_VERSION:
        fail(f"format_version {int(fv)} is not supported (this program reads {FORMAT_VERSION})")
    names = a["input_names"]
    if names.ndim != 1 or names.dtype.kind != "U" or len(names) == 0:
        fail(f"input_names must be a non-empty 1-D unicode array, got {names.dtype} shape {names.shape}")
    name_list = [str(x) for x in names]
    if len(set(name_list)) != len(name_list):
        fail(f"input_names repeat a name: {', '.join(name_list)}")
    for nm in name_list if check_names else ():
        try:
            feature_class(nm)
        except ModelError as exc:
            fail(str(exc))
    n = len(name_list)
    W1 = a["W1"]
    if W1.ndim != 2 or W1.shape[1] != n or W1.shape[0] < 1:
        fail(f"W1 must have shape (H, {n}), got {W1.shape}")
    H = W1.shape[0]
    shapes = {"input_min": (n,), "input_max": (n,), "b1": (H,), "W2": (H,), "W1": (H, n),
              **{k: () for k in _FLOAT_KEYS_SCALAR}}
    for k, shape in shapes.items():
        arr = a[k]
        if arr.dtype.kind != "f":
            fail(f"{k} must be a float array, got dtype {arr.dtype}")
        if arr.shape != shape:
            fail(f"{k} must have shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            fail(f"{k} contains NaN or inf")
    if not np.all(a["input_min"] < a["input_max"]):
        bad = [name_list[i] for i in np.flatnonzero(~(a["input_min"] < a["input_max"]))]
        fail(f"input_min must be < input_max (not so for {', '.join(bad)})")
    if not float(a["output_min"]) < float(a["output_max"]):
        fail("output_min must be < output_max")
    if not float(a["pwm_tau_s"]) > 0:
        fail("pwm_tau_s must be > 0")
    if not float(a["thrust_coefficient"]) >= 0:
        fail("thrust_coefficient must be >= 0")
    # finite arrays can still overflow in use (a float128 beyond float64, 1e308 weights):
    # bound every intermediate of forward() for inputs inside the scaling range
    with np.errstate(over="ignore", invalid="ignore"):
        f = {k: np.asarray(a[k], dtype=np.float64) for k in shapes}
        huge = [k for k in shapes if not np.all(np.isfinite(f[k]))]
        if huge:
            fail(f"{huge[0]} does not fit a 64-bit float")
        span_in = f["input_max"] - f["input_min"]
        pre = np.sum(np.abs(f["W1"]), axis=1) + np.abs(f["b1"])  # |hidden pre-activation|
        reach = float(np.sum(np.abs(f["W2"])) + abs(float(f["b2"])))  # |scaled output|
        span_out = float(f["output_max"]) - float(f["output_min"])
        worst = (reach + 1.0) * 0.5 * span_out + abs(float(f["output_min"]))
        ok = (np.all(np.isfinite(span_in)) and np.all(span_in > 0) and np.all(np.isfinite(pre))
              and np.isfinite(worst))
    if not ok:
        fail("weights or scaling too large: the speed would overflow (not finite)")
    mj = a["metadata_json"]
    if mj.shape != () or mj.dtype.kind != "U":
        fail(f"metadata_json must be a scalar unicode string, got {mj.dtype} shape {mj.shape}")
    try:
        meta = json.loads(str(mj))
    except ValueError as exc:
        fail(f"metadata_json is not valid JSON ({exc})")
    if not isinstance(meta, dict):
        fail("metadata_json must hold a JSON object")
    fp = meta.get("feature_params", {})
    if not isinstance(fp, dict) or not all(isinstance(v, dict) for v in fp.values()):
        fail("metadata_json: feature_params must map input names to parameter objects")
    if check_names:
        params = {k: dict(v) for k, v in fp.items()}
        params.setdefault(c.INPUT_PWM_FILTERED, {})["tau_s"] = float(a["pwm_tau_s"])
        try:
            make_features(name_list, params)
        except ModelError as exc:
            fail(str(exc))
    return meta


#: Share of the time outside the training range from which commands warn (below: a blip, e.g.
#: the filtered voltage at a recording's first sample).
RANGE_WARN_FRACTION = 0.01


@dataclass
class RangeReport:
    """How much of a recording the model saw only by extrapolation (inputs clipped to the
    training range ``input_min..input_max``, as the estimator clips them)."""

    where: str  #: the recording
    fraction: float  #: share of the time with any input outside the range
    by_input: dict[str, float]  #: share of the time per input (inputs that left it only)

    def as_dict(self) -> dict[str, Any]:
        return {"fraction": self.fraction, "by_input": self.by_input}

    def warning(self) -> str | None:
        """One line for stderr when the share is worth saying (>= RANGE_WARN_FRACTION)."""
        if self.fraction < RANGE_WARN_FRACTION:
            return None
        each = ", ".join(f"{n} {100 * f:.1f} %" for n, f in self.by_input.items())
        return (f"{self.where}: inputs outside the model's training range {100 * self.fraction:.1f} % of the "
                f"time ({each}); predictions there are extrapolations (inputs clipped) and not to be trusted")


def range_report(model: NetworkModel, X: np.ndarray, where: str) -> RangeReport:
    """RangeReport of raw inputs ``X`` (rows: time, columns: ``model.input_names``); rows with
    an unknown (NaN) input are not counted."""
    X = np.asarray(X, dtype=float)
    ok = np.all(np.isfinite(X), axis=1)
    X = X[ok]
    if not len(X):
        return RangeReport(where, 0.0, {})
    out = (X < model.input_min) | (X > model.input_max)
    per = out.mean(axis=0)
    return RangeReport(where, float(out.any(axis=1).mean()),
                       {n: float(f) for n, f in zip(model.input_names, per) if f > 0})


def load_model(path: str | os.PathLike[str]) -> NetworkModel:
    """Read and validate a model file (never unpickles anything)."""
    p = Path(path)
    if not p.exists():
        raise ModelError(f"{p}: no such model file")
    if p.is_dir():
        raise ModelError(f"{p}: is {describe_path(p)}, not a model file")
    with open(p, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":  # say what the file is, before numpy talks of pickles
            raise ModelError(f"{p}: is {describe_path(p)}, not a model .npz file (the zip archive "
                             "`bldc-propulsion train` writes)")
    try:
        npz = np.load(p, allow_pickle=False)
    except Exception as exc:  # a damaged zip raises many types (struct.error, NotImplementedError, ...)
        raise ModelError(f"{p}: not a model .npz file ({one_line(exc)})") from None
    if not isinstance(npz, np.lib.npyio.NpzFile):
        raise ModelError(f"{p}: not a model .npz archive (a single array)")
    with npz:
        missing = [k for k in REQUIRED_KEYS if k not in npz.files]
        if missing:
            raise ModelError(f"{p}: missing array(s) {', '.join(missing)}")
        arrays: dict[str, np.ndarray] = {}
        for k in REQUIRED_KEYS:
            try:
                arrays[k] = np.asarray(npz[k])
            except ValueError as exc:
                if "pickle" in str(exc).lower() or "object" in str(exc).lower():
                    raise ModelError(f"{p}: array '{k}' holds pickled Python objects (refused)") from None
                raise ModelError(f"{p}: array '{k}' cannot be read ({one_line(exc)})") from None
            except Exception as exc:  # any other failure to read is damage: zlib.error,
                # BadZipFile, EOFError, NotImplementedError (compression), RuntimeError (encrypted)
                raise ModelError(f"{p}: array '{k}' is damaged ({one_line(exc)})") from None
    for k, arr in arrays.items():
        if arr.dtype.kind == "O":  # pragma: no cover - np.load refuses these already
            raise ModelError(f"{p}: array '{k}' holds Python objects (refused)")
    meta = _check(arrays, str(p))
    try:
        return NetworkModel(
            input_names=tuple(str(x) for x in arrays["input_names"]),
            input_min=arrays["input_min"],
            input_max=arrays["input_max"],
            output_min=float(arrays["output_min"]),
            output_max=float(arrays["output_max"]),
            W1=arrays["W1"],
            b1=arrays["b1"],
            W2=arrays["W2"],
            b2=float(arrays["b2"]),
            pwm_tau_s=float(arrays["pwm_tau_s"]),
            thrust_coefficient=float(arrays["thrust_coefficient"]),
            metadata=meta,
        )
    except ModelError as exc:  # feature parameters that do not fit, e.g.
        raise ModelError(f"{p}: {exc}") from None


def save_model(model: NetworkModel, path: str | os.PathLike[str], force: bool = False) -> None:
    """Write the model atomically; refuses an existing file unless ``force`` (OutputExistsError)."""
    arrays = model._arrays()
    _check(arrays, "model")
    with atomic_output(path, force=force, kind=MODEL) as tmp:
        # a file object: np.savez would append ".npz" to a bare temporary name
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
