"""Train the speed model from recordings: features by the cores, weights by Levenberg-Marquardt."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypedDict, overload

import numpy as np

from .. import __version__
from .. import contract as c
from ..core.features import compute_features, with_measured_start
from ..errors import BadInputError
from ..model import HybridModel, NetworkModel
from ..priors import AIR_DENSITY_KG_M3, INCH_M, MotorPriors
from ..recordings import Signals
from ..specs import split_spec
from .band import band_metadata
from .lm import LMResult, train_lm
from .network import minmax_apply, minmax_fit, nguyen_widrow, pack, unpack


def features_of(sig: Signals, names: Sequence[str], params: dict[str, dict[str, float]] | None = None) -> np.ndarray:
    """Model inputs of one recording on its grid, computed by the estimator's feature code; a
    physics speed among them starts from the recording's measured speed when its rotor is
    already turning (``core.features.with_measured_start``)."""
    pwm_t, pwm = sig.pwm_events
    volt_t, volt = sig.voltage_events
    started = with_measured_start(names, params or {}, sig.t, sig.speed, pwm_t)
    return compute_features(sig.t, pwm_t, pwm, volt_t, volt, list(names), started)


#: Fewest measured thrust samples b is fitted from (with fewer: a stated b, or none).
MIN_THRUST_SAMPLES = 10
#: A stated b further than this from the measured one (relative to it) is warned of: one of
#: them belongs to another propeller, vehicle or air density.
THRUST_DISAGREEMENT = 0.10
#: "Airborne" for the hover condition: the rotor faster than this share of the training
#: recordings' 99th-percentile speed. A multirotor idles on the ground at 10-20 % of its top
#: speed and hovers at 40-70 %, so this keeps the flight and drops the ground and the spool-up.
AIRBORNE_SPEED_FRACTION = 0.3
MEASURED_SOURCE = "least squares on /thrust/measured"
NO_THRUST_SOURCE = "none: no thrust measured or stated"
#: What b from hover takes for granted (the model's provenance and ``train --help`` say it).
HOVER_ASSUMPTION = (
    "the vehicle's mean total thrust while airborne equals its weight m g, shared equally by its "
    "motors: b = m g / (N mean(w^2)) over the training recordings' airborne samples (rotor faster "
    f"than {AIRBORNE_SPEED_FRACTION:.0%} of their 99th-percentile speed); long climbs, descents or "
    "an unequal load between motors make it wrong")


class _ThrustFitCore(TypedDict):
    source: str
    residual_rms_n: float | None
    samples: int


class ThrustFitJson(_ThrustFitCore, total=False):
    """``ThrustFit.as_metadata``: a model's metadata ``thrust_fit``."""

    assumption: str
    warnings: list[str]


@dataclass
class ThrustFit:
    """b in thrust = b w^2 (N s^2/rad^2), where it came from and how well it fits.

    ``coefficient`` None: nothing measured or stated, so the model holds no b and predicts speed
    only (a b of another propeller would be a thrust number that is silently wrong)."""

    coefficient: float | None
    residual_rms_n: float | None  #: of a least-squares fit; None for a stated b
    samples: int  #: samples b was computed from (0: stated outright)
    source: str  #: MEASURED_SOURCE, "stated --thrust-coefficient", "hover: ...", "CT ..., ... in" or NO_THRUST_SOURCE
    assumption: str | None = None  #: what a b derived from stated numbers takes for granted
    warnings: list[str] = field(default_factory=list)

    def as_metadata(self) -> ThrustFitJson:
        """The model's provenance of b (its metadata's ``thrust_fit``)."""
        out: ThrustFitJson = {"source": self.source, "residual_rms_n": self.residual_rms_n,
                               "samples": self.samples}
        if self.assumption:
            out["assumption"] = self.assumption
        if self.warnings:
            out["warnings"] = list(self.warnings)
        return out


def fit_thrust_coefficient(signals: Sequence[Signals], stated: ThrustFit | float | None = None) -> ThrustFit:
    """b = sum(T w^2) / sum(w^4) over the samples with measured thrust (least squares); without
    enough of them the ``stated`` b (``stated_thrust``; a float: a b given outright), else no b.
    The measurement wins over a stated b; one that differs from it by more than
    ``THRUST_DISAGREEMENT`` is named in the fit's warnings."""
    if stated is not None and not isinstance(stated, ThrustFit):
        stated = ThrustFit(float(stated), None, 0, "given b")
    w2 = [s.speed**2 for s in signals if s.thrust is not None]
    thrust = [s.thrust for s in signals if s.thrust is not None]
    x = np.concatenate(w2) if w2 else np.zeros(0)
    y = np.concatenate(thrust) if thrust else np.zeros(0)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) >= MIN_THRUST_SAMPLES and float(np.dot(x, x)) > 0.0:
        b = float(np.dot(x, y) / np.dot(x, x))
        if not b > 0.0:
            raise BadInputError(f"/thrust/measured: the thrust does not rise with the rotor speed (least-squares "
                                f"b = {b:.4g} N s^2/rad^2 over {len(x)} samples): is the load cell's sign reversed?")
        rms = float(np.sqrt(np.mean((y - b * x) ** 2)))
        fit = ThrustFit(b, rms, int(len(x)), MEASURED_SOURCE)
        if stated is not None and stated.coefficient is not None \
                and abs(stated.coefficient - b) > THRUST_DISAGREEMENT * b:
            fit.warnings.append(
                f"the measured thrust gives b = {b:.4g} N s^2/rad^2; the {stated.source} b = "
                f"{stated.coefficient:.4g} differs by {100.0 * (stated.coefficient / b - 1.0):+.0f} % "
                "(the measured b is used: is the stated one of this propeller and vehicle?)")
        return fit
    few = [f"{len(x)} samples of /thrust/measured are too few to fit b (at least {MIN_THRUST_SAMPLES})"] \
        if w2 else []
    if stated is not None:
        return dataclasses.replace(stated, warnings=[*few, *stated.warnings])
    return ThrustFit(None, None, 0, NO_THRUST_SOURCE, warnings=few)


def hover_thrust(priors: MotorPriors, signals: Sequence[Signals]) -> ThrustFit:
    """b from the hover condition (``HOVER_ASSUMPTION``): each motor's mean thrust while airborne
    is m g / N = b mean(w^2)."""
    per_motor_n = priors.hover_thrust_n()
    if per_motor_n is None:
        raise ValueError("hover_thrust needs the vehicle's mass and motor count")
    w = np.concatenate([s.speed for s in signals]) if signals else np.zeros(0)
    w = w[np.isfinite(w)]
    top = float(np.percentile(w, 99)) if len(w) else 0.0
    airborne = w[w > AIRBORNE_SPEED_FRACTION * top] if top > 0.0 else w[:0]
    if len(airborne) < MIN_THRUST_SAMPLES:
        raise BadInputError(
            f"--vehicle-mass-kg: b from hover needs the rotor turning in the training recordings "
            f"({len(airborne)} samples faster than {AIRBORNE_SPEED_FRACTION:.0%} of their top speed)")
    b = per_motor_n / float(np.mean(airborne**2))
    return ThrustFit(b, None, int(len(airborne)),
                     f"hover: {priors.vehicle_mass_kg:g} kg, {priors.motor_count} motors", HOVER_ASSUMPTION)


def stated_thrust(priors: MotorPriors, signals: Sequence[Signals]) -> ThrustFit | None:
    """b from what the user stated, the first of: ``--thrust-coefficient``; ``--vehicle-mass-kg``
    with ``--motor-count`` (``hover_thrust`` on ``signals``, the training recordings);
    ``--propeller-ct`` with ``--prop-diameter-in`` (b = CT rho D^4 / (4 pi^2)). None: nothing
    stated. A later one stated too is not used, and the warnings say what it would give."""
    candidates: list[ThrustFit] = []
    if priors.thrust_coefficient is not None:
        candidates.append(ThrustFit(priors.thrust_coefficient, None, 0, "stated --thrust-coefficient"))
    if priors.hover_thrust_n() is not None:
        candidates.append(hover_thrust(priors, signals))
    b_ct = priors.thrust_coefficient_from_ct()
    if b_ct is not None:
        assert priors.propeller_diameter_m is not None, "b from CT needs the diameter"
        inches = priors.propeller_diameter_m / INCH_M
        candidates.append(ThrustFit(
            b_ct, None, 0, f"CT {priors.propeller_ct:g}, {inches:g} in",
            f"static thrust T = CT rho n^2 D^4 at rho = {AIR_DENSITY_KG_M3} kg/m^3 (ISA sea level), "
            "so b = CT rho D^4 / (4 pi^2)"))
    if not candidates:
        return None
    used, *others = candidates
    for o in others:
        assert o.coefficient is not None and used.coefficient is not None, "every candidate has a b"
        used.warnings.append(
            f"{o.source} would give b = {o.coefficient:.4g} N s^2/rad^2 "
            f"({100.0 * (o.coefficient / used.coefficient - 1.0):+.0f} %): not used, {used.source} comes first")
    return used


@dataclass
class TrainOutcome:
    model: NetworkModel | HybridModel  #: a hybrid from fit_physics.train_hybrid
    lm: LMResult
    train: list[Signals]
    validation: list[Signals]
    thrust: ThrustFit
    train_rmse_rad_s: float
    validation_rmse_rad_s: float


def stack(signals: Sequence[Signals], names: Sequence[str],
          params: dict[str, dict[str, float]]) -> tuple[np.ndarray, np.ndarray]:
    X = np.vstack([features_of(s, names, params) for s in signals])
    y = np.concatenate([s.speed for s in signals])
    ok = np.all(np.isfinite(X), axis=1) & np.isfinite(y)
    return X[ok], y[ok]


def train_model(
    train: Sequence[Signals],
    validation: Sequence[Signals],
    *,
    inputs: Sequence[str] = c.DEFAULT_INPUTS,
    hidden: int = c.PAPER_HIDDEN,
    seed: int = 0,
    pwm_tau_s: float = c.PAPER_PWM_TAU_S,
    feature_params: dict[str, dict[str, float]] | None = None,
    thrust_coefficient: ThrustFit | float | None = None,
    max_epochs: int = 1000,
    patience: int = 6,
    progress: Callable[[int, float, float, float], None] | None = None,
    phi0: np.ndarray | None = None,
    restarts: int = 1,
    start_at_zero: bool = False,
    band: bool = True,
) -> TrainOutcome:
    """Fit an n-H-1 network on ``train``, early-stopped on ``validation`` (separate recordings).

    ``phi0``: initial weights (in the scaling this training derives), e.g. to continue from a
    model; default Nguyen-Widrow from ``seed``. ``restarts``: train from the Nguyen-Widrow
    weights of seeds ``seed .. seed + restarts - 1`` (after ``phi0`` when given) and keep the
    network with the least validation cost. ``start_at_zero``: those weights with the output
    layer at 0 (the network's output 0 rad/s): a hybrid's correction starts from the physics
    alone, so early stopping keeps a network only where it helps on validation. Why restarts: LM
    finds a local minimum, and which one decides how the network extrapolates between the
    recordings' operating points; on the
    bundled bags the validation RMSE of single 3-25-1 runs spans 16-30 rad/s over seeds, and the
    validation cost is the unbiased way to choose among them (what trainlm users do by hand).
    ``thrust_coefficient``: the stated b (``stated_thrust``), the model's when ``train`` has no
    measured thrust (``fit_thrust_coefficient``); None: the model has no b then. ``band``: see
    ``validation_band`` (off for a hybrid's network: the hybrid's band is of its own speed).
    """
    if not train or not validation:
        raise BadInputError("training needs at least one training and one validation recording")
    if hidden < 1:
        raise BadInputError(f"--hidden {hidden}: must be at least 1")
    if restarts < 1:
        raise BadInputError(f"--restarts {restarts}: must be at least 1")
    params = {c.INPUT_PWM_FILTERED: {"tau_s": pwm_tau_s}, **(feature_params or {})}
    X, y = stack(train, inputs, params)
    Xv, yv = stack(validation, inputs, params)
    _check_amounts(len(y), len(yv), hidden, len(inputs))
    sc = _Scaling.of(X, y, inputs)
    scaled = (sc.inputs(X), sc.speed(y), sc.inputs(Xv), sc.speed(yv))
    runs: list[tuple[int | None, LMResult]] = []
    starts: list[int | None] = ([None] if phi0 is not None else []) + list(range(seed, seed + restarts))
    for start in starts[:restarts]:
        p0 = (phi0 if start is None else _zero_output(len(inputs), hidden, start, sc.speed(0.0)) if start_at_zero
              else None)
        runs.append((start, train_lm(*scaled, hidden, seed=start or 0, phi0=p0,
                                     max_epochs=max_epochs, patience=patience, progress=progress)))
    best_seed, result = min(runs, key=lambda r: r[1].val_cost)
    W1, b1, W2, b2 = unpack(result.phi, len(inputs), hidden)
    fit = fit_thrust_coefficient(train, thrust_coefficient)
    metadata: dict[str, object] = {
        "package_version": __version__,
        "sources": {
            "train": [_source(s) for s in train],
            "validation": [_source(s) for s in validation],
        },
        **_lm_metadata(result, runs),
        "seed": int(seed),
        "best_seed": best_seed,  # None: the run started from the given weights (phi0)
        "restarts": [{"seed": sd, "epochs": int(r.epochs), "best_epoch": int(r.best_epoch),
                      "validation_cost": float(r.val_cost)} for sd, r in runs],
        "hidden": int(hidden),
        "samples": {"train": int(len(y)), "validation": int(len(yv))},
        "thrust_fit": fit.as_metadata(),
        "feature_params": params,
    }
    model = NetworkModel(input_names=tuple(inputs), input_min=np.asarray(sc.xmin, dtype=float),
                         input_max=np.asarray(sc.xmax, dtype=float), output_min=sc.ymin, output_max=sc.ymax,
                         W1=W1, b1=b1, W2=W2, b2=float(b2), pwm_tau_s=float(pwm_tau_s),
                         thrust_coefficient=fit.coefficient, metadata=metadata)
    rmse = float(np.sqrt(np.mean((model.forward(X) - y) ** 2)))
    rmse_v = float(np.sqrt(np.mean((model.forward(Xv) - yv) ** 2)))
    metadata.update(validation_band(model, validation) if band else {})
    return TrainOutcome(model, result, list(train), list(validation), fit, rmse, rmse_v)


def validation_band(model: NetworkModel, validation: Sequence[Signals]) -> dict[str, object]:
    """The network's one-sigma speed band fitted on its validation residuals, for its metadata
    (``training.band``); the speed as ``evaluate.predict_speed`` computes it (inputs clipped to
    the training range, >= 0), which cannot be imported here (evaluate imports this module)."""
    params = model.feature_params()
    return band_metadata([np.maximum(model.forward(np.clip(features_of(s, model.input_names, params),
                                                           model.input_min, model.input_max)), 0.0)
                          for s in validation], validation)


def _check_amounts(n_train: int, n_validation: int, hidden: int, n_in: int) -> None:
    """BadInputError when the training samples are too few for the network's weights, or the
    validation samples too few to stop on."""
    n_params = hidden * (n_in + 2) + 1
    if n_train < max(2 * n_params, 50):
        raise BadInputError(
            f"too little training data: {n_train} samples for {n_params} weights "
            f"(record longer or use fewer --hidden)"
        )
    if n_validation < 20:
        raise BadInputError(f"too little validation data: {n_validation} samples")


@dataclass
class _Scaling:
    """The min-max scaling a training derives from its training data: inputs and speed to [-1, 1]."""

    xmin: np.ndarray
    xmax: np.ndarray
    ymin: float
    ymax: float

    @classmethod
    def of(cls, X: np.ndarray, y: np.ndarray, inputs: Sequence[str]) -> _Scaling:
        """BadInputError when an input or the speed does not vary."""
        try:
            xmin, xmax = minmax_fit(X)
        except ValueError as exc:
            names = ", ".join(inputs)
            raise BadInputError(f"training inputs ({names}) do not vary: {exc}") from None
        ymin, ymax = float(np.min(y)), float(np.max(y))
        if not ymax > ymin:
            raise BadInputError("the measured speed does not vary in the training recordings")
        return cls(xmin, xmax, ymin, ymax)

    def inputs(self, X: np.ndarray) -> np.ndarray:
        return minmax_apply(X, self.xmin, self.xmax)

    @overload
    def speed(self, y: float) -> float: ...

    @overload
    def speed(self, y: np.ndarray) -> np.ndarray: ...

    def speed(self, y: float | np.ndarray) -> float | np.ndarray:
        """Speed (rad/s, array or number) in the network's output scale."""
        return 2.0 * (y - self.ymin) / (self.ymax - self.ymin) - 1.0


def _lm_metadata(result: LMResult, runs: Sequence[tuple[int | None, LMResult]]) -> dict[str, object]:
    """The kept LM run's epochs, stop and cost history, and the time all runs took (model metadata)."""
    return {
        "epochs": int(result.epochs),
        "best_epoch": int(result.best_epoch),
        "stop_reason": result.stop_reason,
        "train_cost": result.train_cost,
        "validation_cost": result.val_cost,
        "history": {
            "train_cost": result.history.train_cost.tolist(),
            "validation_cost": result.history.val_cost.tolist(),
            "mu": result.history.mu.tolist(),
        },
        "training_seconds": float(sum(r.seconds for _, r in runs)),
    }


def _zero_output(n_in: int, hidden: int, seed: int, b2: float) -> np.ndarray:
    """Nguyen-Widrow hidden weights of ``seed``, output weights 0 and output bias ``b2``."""
    W1, b1, W2, _ = unpack(nguyen_widrow(n_in, hidden, np.random.default_rng(seed)), n_in, hidden)
    return pack(W1, b1, np.zeros_like(W2), b2)


def _source(sig: Signals) -> dict[str, str | None]:
    """Provenance of one recording: the path as given, where it was, and its content hash."""
    path, namespace = split_spec(sig.path.split("#", 1)[0], sig.namespace)
    return {"path": sig.path, "abs_path": os.path.abspath(path), "sha256": sig.sha256,
            "namespace": namespace}
