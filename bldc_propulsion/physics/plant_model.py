"""A physics model as a model file holds it: the plant's constants, every effect's strength and
the supply, ``PlantModel`` (kind ``physics``; the physics part of a ``hybrid``).

``model.py`` reads and writes the file (its header, the other kinds); this module owns the
physics part: its arrays (``PHYSICS_KEYS``, ``PlantModel.physics_arrays``), their checks
(``check_physics_arrays``, every problem a ``fail("<field>: <what is wrong>")``), and what the
estimator and ``evaluate`` run: one input, ``physics_speed``, the plant stepped as a stream
(``stream.py``) under these constants.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, NoReturn, cast

import numpy as np

from .. import contract as c
from ..errors import ModelError
from .params import PLANT_FIELDS, PLANT_OPTIONAL_FIELDS, PlantParams, plant_problem, strength_problem
from .stream import stream_params

#: The arrays of a model file's physics part.
PHYSICS_KEYS = ("physics_names", "physics_values", "effect_names", "effect_strengths", "supply_v", "supply_tau_s")

#: A check's way to say what is wrong: raises (a ModelError naming the file and the field).
Fail = Callable[[str], NoReturn]


class _FromCT(enum.Enum):
    FROM_CT = "from the propeller's CT"


#: ``PlantModel``'s default b: its constants' CT (``PlantParams.thrust_coefficient``), distinct
#: from None (no b), so that ``dataclasses.replace`` of a model without b keeps it without b.
FROM_CT = _FromCT.FROM_CT
#: FROM_CT typed as the field it is the default of: ``__post_init__`` replaces it, so what a
#: PlantModel holds (and the estimator's SpeedModel reads) is a float or None.
_B_FROM_CT = cast("float | None", FROM_CT)


def thrust_or_none(b: float | None) -> float | None:
    """b as a float, None when the model has none (None or NaN, as the file stores it)."""
    return None if b is None or math.isnan(float(b)) else float(b)


def thrust_problem(b: float) -> str | None:
    """Why ``b`` (NaN: none) is no thrust coefficient of a model file, or None."""
    if math.isnan(b) or (math.isfinite(b) and b >= 0):
        return None
    return f"thrust_coefficient must be >= 0 and finite, or NaN for none (got {b!r})"


@dataclass
class PlantModel:
    """A ``physics`` model: the plant's constants, every effect's strength and the stiff-supply
    voltage (what ``discrepancy --physics`` and ``train --kind physics`` fit); driven by PWM and
    the filtered battery voltage (``plant.motor_response``, ``stream.PlantStream``)."""

    kind: ClassVar[str] = c.PHYSICS
    params: PlantParams  #: a BenchParams is cut down to its plant constants
    effects: dict[str, float]  #: every contract effect
    supply_v: float  #: V: the stiff supply battery_voltage strength 0 gives (plant.Supply's v_ref)
    #: b (N s^2/rad^2); FROM_CT (default): the constants' CT gives it; None: no b (speed only)
    thrust_coefficient: float | None = _B_FROM_CT
    metadata: dict[str, Any] = field(default_factory=dict)  #: the file's metadata_json (provenance, fit figures)
    #: time constant (s) of the filter the voltage input comes through: the paper's battery
    #: filter's (None), 0 for a supply measured directly (plant.Supply)
    supply_tau_s: float | None = None

    def __post_init__(self) -> None:
        self.params = PlantParams(**{n: float(getattr(self.params, n)) for n in PLANT_FIELDS})
        self.effects = {str(k): float(v) for k, v in dict(self.effects).items()}
        self.supply_v = float(self.supply_v)
        self.supply_tau_s = float(c.PAPER_FILTER_TAU_S if self.supply_tau_s is None else self.supply_tau_s)
        if isinstance(self.thrust_coefficient, _FromCT):
            self.thrust_coefficient = self.params.thrust_coefficient
        self.thrust_coefficient = thrust_or_none(self.thrust_coefficient)
        if not isinstance(self.metadata, dict):
            raise ModelError("model: metadata must be a dict")

        def fail(msg: str) -> NoReturn:
            raise ModelError(f"model: {msg}")

        why = None if self.thrust_coefficient is None else thrust_problem(self.thrust_coefficient)
        if why:
            fail(why)
        check_physics_arrays(self.physics_arrays(), fail)

    def physics_arrays(self) -> dict[str, np.ndarray]:
        """The arrays of the model file's physics part (``PHYSICS_KEYS``)."""
        return {
            "physics_names": np.array(PLANT_FIELDS, dtype=np.str_),
            "physics_values": np.array([getattr(self.params, n) for n in PLANT_FIELDS], dtype=np.float64),
            "effect_names": np.array(list(self.effects), dtype=np.str_),
            "effect_strengths": np.array(list(self.effects.values()), dtype=np.float64),
            "supply_v": np.array(self.supply_v, dtype=np.float64),
            "supply_tau_s": np.array(self.supply_tau_s, dtype=np.float64),
        }

    @classmethod
    def of_arrays(cls, a: Mapping[str, np.ndarray], thrust_coefficient: float | None,
                  metadata: dict[str, Any]) -> PlantModel:
        """From a file's checked arrays (``check_physics_arrays``), its b and its metadata."""
        return cls(PlantParams(**dict(zip(map(str, a["physics_names"]), map(float, a["physics_values"]), strict=True))),
                   dict(zip(map(str, a["effect_names"]), map(float, a["effect_strengths"]), strict=True)),
                   float(a["supply_v"]), thrust_coefficient, metadata, float(a["supply_tau_s"]))

    # --- what the estimator and evaluate run (core/estimator.SpeedModel): one input, the speed
    @property
    def input_names(self) -> tuple[str, ...]:
        return (c.INPUT_PHYSICS_SPEED,)

    @property
    def input_min(self) -> np.ndarray:
        return np.array([-np.inf])  # nothing to clip: the physics holds everywhere it is valid

    @property
    def input_max(self) -> np.ndarray:
        return np.array([np.inf])

    def feature_params(self) -> dict[str, dict[str, float]]:
        """The ``physics_speed`` input's parameters: this model (``stream.STREAM_DEFAULTS``)."""
        assert self.supply_tau_s is not None, "__post_init__ resolves None"
        return {c.INPUT_PHYSICS_SPEED: stream_params(self.params, self.effects, self.supply_v, self.supply_tau_s)}

    def forward(self, X_raw: np.ndarray) -> np.ndarray:
        """Speed (rad/s): the ``physics_speed`` input itself."""
        return np.asarray(X_raw, dtype=float)[..., 0]


# --- checks of a file's arrays -------------------------------------------------------------------
def check_floats(a: Mapping[str, np.ndarray], shapes: Mapping[str, tuple[int, ...]], fail: Fail) -> None:
    """Each named array a float array of its shape, finite."""
    for k, shape in shapes.items():
        arr = a[k]
        if arr.dtype.kind != "f":
            fail(f"{k} must be a float array, got dtype {arr.dtype}")
        if arr.shape != shape:
            fail(f"{k} must have shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            fail(f"{k} contains NaN or inf")


def check_names(a: Mapping[str, np.ndarray], key: str, fail: Fail) -> list[str]:
    """A non-empty 1-D unicode array of distinct names."""
    names = a[key]
    if names.ndim != 1 or names.dtype.kind != "U" or len(names) == 0:
        fail(f"{key} must be a non-empty 1-D unicode array, got {names.dtype} shape {names.shape}")
    out = [str(x) for x in names]
    if len(set(out)) != len(out):
        fail(f"{key} repeat a name: {', '.join(out)}")
    return out


def check_physics_arrays(a: Mapping[str, np.ndarray], fail: Fail) -> None:
    """Every plant constant and effect strength, by name, within its physical range; the supply."""
    for names_key, values_key, known in (("physics_names", "physics_values", PLANT_FIELDS),
                                         ("effect_names", "effect_strengths", c.EFFECTS)):
        names = check_names(a, names_key, fail)
        unknown = [n for n in names if n not in known]
        if unknown:
            fail(f"{names_key}: '{unknown[0]}' is not known (known: {', '.join(known)})")
        missing = [n for n in known if n not in names and n not in PLANT_OPTIONAL_FIELDS]
        if missing:
            fail(f"{names_key}: missing {', '.join(missing)}")
        check_floats(a, {values_key: (len(names),)}, fail)
    params = dict(zip(map(str, a["physics_names"]), map(float, a["physics_values"]), strict=True))
    bad = plant_problem(PlantParams(**params))
    if bad:
        fail(f"physics_values: {bad[0]} {bad[1]}")
    for name, value in zip(map(str, a["effect_names"]), map(float, a["effect_strengths"]), strict=True):
        why = strength_problem(name, value)
        if why:
            fail(f"effect_strengths: {name} {why}")
    check_floats(a, {"supply_v": (), "supply_tau_s": ()}, fail)
    if not float(a["supply_v"]) > 0:
        fail(f"supply_v {float(a['supply_v'])!r} must be a voltage > 0")
    if not float(a["supply_tau_s"]) >= 0:
        fail(f"supply_tau_s {float(a['supply_tau_s'])!r} must be >= 0")
