"""The speed model of every kind and its .npz file: ``network`` (the paper's n-H-1 network, tanh
hidden layer, linear output), ``physics`` (the plant's constants and effect strengths:
``physics.plant_model.PlantModel``, which owns its arrays and their checks) and ``hybrid`` (the
physics model's speed plus a network trained on what it gets wrong, the physics speed among its
inputs).

File format (``format_version`` 2; version 1 files, network models without ``kind``, still load):

| key | shape / dtype | kinds | meaning |
|---|---|---|---|
| ``format_version`` | () int64 | all | 2 |
| ``kind`` | () unicode | all | ``network``, ``physics`` or ``hybrid`` |
| ``thrust_coefficient`` | () float64 | all | b in thrust = b w^2 (N s^2/rad^2); NaN: none (speed only) |
| ``metadata_json`` | () unicode | all | JSON object: provenance, costs, ``feature_params``, ``band`` (below) |
| ``input_names`` | (n,) unicode | network, hybrid | inputs in order (core/features.py; a hybrid: + ``physics_speed``) |
| ``input_min``, ``input_max`` | (n,) float64 | network, hybrid | scaling of inputs to [-1, 1] |
| ``output_min``, ``output_max`` | () float64 | network, hybrid | scaling of the output (rad/s) to [-1, 1] |
| ``W1`` (H, n), ``b1`` (H,), ``W2`` (H,), ``b2`` () | float64 | network, hybrid | network weights |
| ``pwm_tau_s`` | () float64 | network, hybrid | time constant of ``pwm_filtered`` (paper: 0.25 s) |
| ``physics_names``, ``physics_values`` | (m,) unicode, float64 | physics, hybrid | each ``PlantParams`` constant (SI) |
| ``effect_names``, ``effect_strengths`` | (e,) unicode, float64 | physics, hybrid | strengths (0 off, 1 nominal) |
| ``supply_v`` | () float64 | physics, hybrid | the stiff supply (V) that battery_voltage strength 0 gives |
| ``supply_tau_s`` | () float64 | physics, hybrid | the filter the voltage input comes through (s; 0: the terminal's) |

The metadata's ``band`` is the predicted speed's one-sigma band fitted on the validation recordings
(``core.uncertainty``, versioned); files written before bands lack it, load alike and predict no sigma.

A model trained with no thrust measured or stated has no b (``thrust_coefficient`` None, NaN in
the file) rather than another propeller's: it predicts speed only.

Files are read with ``allow_pickle=False`` (a model file cannot run code) and validated
completely; every problem is a ``ModelError("<path>: <field>: <what is wrong>")``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, NoReturn, TypeAlias, TypedDict

import numpy as np

from . import contract as c
from .atomic import OutputKind, atomic_output, describe_path, recognised_by
from .core.features import feature_class, make_features
from .core.uncertainty import BAND_KEY, band_problem
from .errors import ModelError, one_line
from .physics.fallback import NOMINAL_THRUST_COEFFICIENT
from .physics.plant_model import PHYSICS_KEYS, Fail, PlantModel, check_physics_arrays, thrust_or_none, thrust_problem
from .physics.plant_model import check_floats as _check_floats
from .physics.plant_model import check_names as _check_names

FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
#: The input of a hybrid's network that is the physics part's predicted speed (rad/s).
PHYSICS_SPEED = c.INPUT_PHYSICS_SPEED

#: A model's metadata_json: arbitrary JSON read back from the file (provenance, fit figures, band),
#: each reader checking the keys it uses (``_check_metadata`` checks the object and its known keys)
Metadata: TypeAlias = "dict[str, Any]"

_FLOAT_KEYS_SCALAR = ("output_min", "output_max", "b2", "pwm_tau_s")
_COMMON_KEYS = ("format_version", "kind", "thrust_coefficient", "metadata_json")
_NETWORK_KEYS = ("input_names", "input_min", "input_max", "output_min", "output_max",
                 "W1", "b1", "W2", "b2", "pwm_tau_s")
#: The arrays of a file of each kind.
KEYS: dict[str, tuple[str, ...]] = {
    c.NETWORK: _COMMON_KEYS + _NETWORK_KEYS,
    c.PHYSICS: _COMMON_KEYS + PHYSICS_KEYS,
    c.HYBRID: _COMMON_KEYS + _NETWORK_KEYS + PHYSICS_KEYS,
}
#: A network model's arrays (what every version 1 file holds, but ``kind``).
REQUIRED_KEYS: tuple[str, ...] = KEYS[c.NETWORK]


@dataclass
class NetworkModel:
    """Weights and scaling of the speed network (SI units: inputs as features.py makes them, rad/s)."""

    kind: ClassVar[str] = c.NETWORK
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
    thrust_coefficient: float | None = NOMINAL_THRUST_COEFFICIENT  #: None: no b, speed only
    metadata: Metadata = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.input_names = tuple(str(n) for n in self.input_names)
        self.thrust_coefficient = thrust_or_none(self.thrust_coefficient)
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
            **_common_arrays(self.kind, self.thrust_coefficient, self.metadata),
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
        }


def _common_arrays(kind: str, thrust_coefficient: float | None,
                   metadata: Mapping[str, object]) -> dict[str, np.ndarray]:
    return {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "kind": np.array(kind, dtype=np.str_),
        "thrust_coefficient": np.array(np.nan if thrust_coefficient is None else thrust_coefficient,
                                       dtype=np.float64),
        "metadata_json": np.array(json.dumps(metadata, sort_keys=True), dtype=np.str_),
    }


@dataclass
class HybridModel:
    """A ``hybrid`` model: the physics model's speed plus ``network``'s output, a correction
    trained on what the physics gets wrong; ``PHYSICS_SPEED`` is among the network's inputs.
    Thrust coefficient and metadata are the network part's."""

    kind: ClassVar[str] = c.HYBRID
    plant: PlantModel
    network: NetworkModel

    def __post_init__(self) -> None:
        if PHYSICS_SPEED not in self.network.input_names:
            raise ModelError(f"model: input_names: a hybrid's network must take {PHYSICS_SPEED} "
                             f"(has {', '.join(self.network.input_names)})")

    @property
    def thrust_coefficient(self) -> float | None:
        return self.network.thrust_coefficient

    @property
    def metadata(self) -> Metadata:
        return self.network.metadata

    def _arrays(self) -> dict[str, np.ndarray]:
        return {**self.network._arrays(), **self.plant.physics_arrays(), "kind": np.array(c.HYBRID, dtype=np.str_)}

    # --- what the estimator and evaluate run: the network's inputs; physics_speed is not clipped
    @property
    def input_names(self) -> tuple[str, ...]:
        return self.network.input_names

    @property
    def physics_index(self) -> int:
        return self.network.input_names.index(PHYSICS_SPEED)

    @property
    def input_min(self) -> np.ndarray:
        out = self.network.input_min.copy()
        out[self.physics_index] = -np.inf
        return out

    @property
    def input_max(self) -> np.ndarray:
        out = self.network.input_max.copy()
        out[self.physics_index] = np.inf
        return out

    def feature_params(self) -> dict[str, dict[str, float]]:
        return {**self.network.feature_params(), **self.plant.feature_params()}

    def forward(self, X_raw: np.ndarray) -> np.ndarray:
        """Speed (rad/s): the physics speed plus the network's correction."""
        X = np.asarray(X_raw, dtype=float)
        return X[..., self.physics_index] + self.network.forward(X)


#: A model of any kind, as ``load_model`` returns it.
Model = NetworkModel | PlantModel | HybridModel


def _check(a: Mapping[str, np.ndarray], where: str, check_names: bool = True) -> tuple[str, Metadata]:
    """Validate the arrays of a model of any kind; ModelError(f"{where}: ...") on the first
    problem. Returns the kind and the metadata.

    With ``check_names``, also that every network input is a registered feature (a hybrid's
    ``physics_speed`` aside) and its parameters fit.
    """
    def fail(msg: str) -> NoReturn:
        raise ModelError(f"{where}: {msg}")

    kind = _check_kind(a, fail)
    b = a["thrust_coefficient"]
    if b.dtype.kind != "f" or b.shape != ():
        fail(f"thrust_coefficient must be a scalar float, got {b.dtype} shape {b.shape}")
    why = thrust_problem(float(b))  # NaN: no b
    if why:
        fail(why)
    meta = _check_metadata(a, fail)
    if kind != c.PHYSICS:
        _check_network(a, kind, meta, check_names, fail)
    if kind != c.NETWORK:
        check_physics_arrays(a, fail)
    return kind, meta


def _check_kind(a: Mapping[str, np.ndarray], fail: Fail) -> str:
    """The file's format version and kind (``network`` for version 1)."""
    fv = a["format_version"]
    if fv.shape != () or fv.dtype.kind not in "iu":
        fail(f"format_version must be a scalar integer, got {fv.dtype} shape {fv.shape}")
    if int(fv) not in READABLE_VERSIONS:
        fail(f"format_version {int(fv)} is not supported (this program reads "
             f"{', '.join(map(str, READABLE_VERSIONS))})")
    if int(fv) == 1:
        return c.NETWORK
    kind = a["kind"]
    if kind.shape != () or kind.dtype.kind != "U":
        fail(f"kind must be a scalar unicode string, got {kind.dtype} shape {kind.shape}")
    if str(kind) not in c.MODEL_KINDS:
        fail(f"kind '{kind}' is not known (known: {', '.join(c.MODEL_KINDS)})")
    return str(kind)


def _check_metadata(a: Mapping[str, np.ndarray], fail: Fail) -> Metadata:
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
    if BAND_KEY in meta and (why := band_problem(meta[BAND_KEY])):
        fail(f"metadata_json: {BAND_KEY}: {why}")
    return meta


def _check_network(a: Mapping[str, np.ndarray], kind: str, meta: Metadata, check_names: bool,
                   fail: Fail) -> None:
    name_list = _check_names(a, "input_names", fail)
    features = [nm for nm in name_list if nm != PHYSICS_SPEED]
    if check_names:
        if kind == c.HYBRID and PHYSICS_SPEED not in name_list:
            fail(f"input_names: a hybrid's network must take {PHYSICS_SPEED} (has {', '.join(name_list)})")
        if kind == c.NETWORK and PHYSICS_SPEED in name_list:
            fail(f"input_names: {PHYSICS_SPEED} is the physics part's speed: only a hybrid model has it")
        for nm in features:
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
    _check_floats(a, shapes, fail)
    if not np.all(a["input_min"] < a["input_max"]):
        bad = [name_list[i] for i in np.flatnonzero(~(a["input_min"] < a["input_max"]))]
        fail(f"input_min must be < input_max (not so for {', '.join(bad)})")
    if not float(a["output_min"]) < float(a["output_max"]):
        fail("output_min must be < output_max")
    if not float(a["pwm_tau_s"]) > 0:
        fail("pwm_tau_s must be > 0")
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
    if check_names:
        params = {k: dict(v) for k, v in meta.get("feature_params", {}).items()}
        params.setdefault(c.INPUT_PWM_FILTERED, {})["tau_s"] = float(a["pwm_tau_s"])
        try:
            make_features(features, params)
        except ModelError as exc:
            fail(str(exc))


#: Share of the time outside the training range from which commands warn (below: a blip, e.g.
#: the filtered voltage at a recording's first sample).
RANGE_WARN_FRACTION = 0.01


class RangeJson(TypedDict):
    """``RangeReport.as_dict``: out_of_training_range in the commands' --json."""

    fraction: float
    by_input: dict[str, float]


@dataclass
class RangeReport:
    """How much of a recording the model saw only by extrapolation (inputs clipped to the
    training range ``input_min..input_max``, as the estimator clips them)."""

    where: str  #: the recording
    fraction: float  #: share of the time with any input outside the range
    by_input: dict[str, float]  #: share of the time per input (inputs that left it only)

    def as_dict(self) -> RangeJson:
        return {"fraction": self.fraction, "by_input": self.by_input}

    def warning(self) -> str | None:
        """One line for stderr when the share is worth saying (>= RANGE_WARN_FRACTION)."""
        if self.fraction < RANGE_WARN_FRACTION:
            return None
        each = ", ".join(f"{n} {100 * f:.1f} %" for n, f in self.by_input.items())
        return (f"{self.where}: inputs outside the model's training range {100 * self.fraction:.1f} % of the "
                f"time ({each}); predictions there are extrapolations (inputs clipped) and not to be trusted")


def range_report(model: Model, X: np.ndarray, where: str) -> RangeReport:
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
                       {n: float(f) for n, f in zip(model.input_names, per, strict=True) if f > 0})


def load_model(path: str | os.PathLike[str], kinds: Collection[str] = c.MODEL_KINDS) -> Model:
    """Read and validate a model file (never unpickles anything); ModelError unless its kind is
    one of ``kinds`` (the uses that only take networks say so)."""
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

    def read(k: str) -> np.ndarray:
        try:
            arr = np.asarray(npz[k])
        except ValueError as exc:
            if "pickle" in str(exc).lower() or "object" in str(exc).lower():
                raise ModelError(f"{p}: array '{k}' holds pickled Python objects (refused)") from None
            raise ModelError(f"{p}: array '{k}' cannot be read ({one_line(exc)})") from None
        except Exception as exc:  # any other failure to read is damage: zlib.error,
            # BadZipFile, EOFError, NotImplementedError (compression), RuntimeError (encrypted)
            raise ModelError(f"{p}: array '{k}' is damaged ({one_line(exc)})") from None
        if arr.dtype.kind == "O":  # pragma: no cover - np.load refuses these already
            raise ModelError(f"{p}: array '{k}' holds Python objects (refused)")
        return arr

    with npz:
        keys = _keys_of(npz.files, read)
        missing = [k for k in keys if k not in npz.files]
        if missing:
            raise ModelError(f"{p}: missing array(s) {', '.join(missing)}")
        arrays = {k: read(k) for k in keys}
    kind, meta = _check(arrays, str(p))
    if kind not in kinds:
        raise ModelError(f"{p}: kind {kind}: a {' or '.join(kinds)} model is needed here")
    thrust = thrust_or_none(float(arrays["thrust_coefficient"]))
    try:
        plant = PlantModel.of_arrays(arrays, thrust, meta) if kind != c.NETWORK else None
        if plant is not None and kind == c.PHYSICS:
            return plant
        network = NetworkModel(
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
            thrust_coefficient=thrust,
            metadata=meta,
        )
        return network if plant is None else HybridModel(plant, network)
    except ModelError as exc:  # feature parameters that do not fit, e.g.
        raise ModelError(f"{p}: {exc}") from None


def _keys_of(files: Collection[str], read: Callable[[str], np.ndarray]) -> tuple[str, ...]:
    """The arrays a file must hold, from its version and kind: a version 1 file is a network
    without ``kind``. A version or kind that cannot be used: only those, for ``_check`` to say
    what is wrong with them."""
    if "format_version" not in files:
        return KEYS[c.NETWORK]
    fv = read("format_version")
    if fv.shape != () or fv.dtype.kind not in "iu" or int(fv) not in READABLE_VERSIONS:
        return ("format_version",)
    if int(fv) == 1:
        return tuple(k for k in KEYS[c.NETWORK] if k != "kind")
    if "kind" not in files:
        return KEYS[c.NETWORK]
    kind = read("kind")
    if kind.shape != () or kind.dtype.kind != "U" or str(kind) not in c.MODEL_KINDS:
        return ("format_version", "kind")
    return KEYS[str(kind)]


#: A model file as an output (``atomic.check_outputs``): an existing one is what ``load_model``
#: reads, of any kind.
MODEL = OutputKind("model", "a model file (.npz)", (".npz",), recognised_by(load_model))


def _arrays(model: Model) -> dict[str, np.ndarray]:
    """The arrays of ``model``'s file: the physics part's are ``PlantModel.physics_arrays``."""
    if isinstance(model, PlantModel):
        return {**_common_arrays(c.PHYSICS, model.thrust_coefficient, model.metadata), **model.physics_arrays()}
    return model._arrays()


def save_model(model: Model, path: str | os.PathLike[str], force: bool = False) -> None:
    """Write the model atomically; refuses an existing file unless ``force`` (OutputExistsError)."""
    arrays = _arrays(model)
    _check(arrays, "model")
    with atomic_output(path, force=force, kind=MODEL) as tmp:
        # a file object: np.savez would append ".npz" to a bare temporary name
        with open(tmp, "wb") as fh:
            np.savez(fh, allow_pickle=False, **arrays)  # plain arrays only: load_model reads without pickle
