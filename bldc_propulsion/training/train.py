"""Train the speed model from recordings: features by the cores, weights by Levenberg-Marquardt."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import __version__
from .. import contract as c
from ..core.features import compute_features
from ..errors import BadInputError
from ..model import NetworkModel
from ..recordings import Signals
from .lm import LMResult, train_lm
from .network import minmax_apply, minmax_fit, nguyen_widrow, pack, unpack


def features_of(sig: Signals, names: Sequence[str], params: dict[str, dict[str, float]] | None = None) -> np.ndarray:
    """Model inputs of one recording on its grid, computed by the estimator's feature code."""
    pwm_t, pwm = sig.pwm_events
    volt_t, volt = sig.voltage_events
    return compute_features(sig.t, pwm_t, pwm, volt_t, volt, list(names), params or {})


@dataclass
class ThrustFit:
    """Least-squares b in thrust = b w^2, and how well it fits."""

    coefficient: float
    residual_rms_n: float | None
    samples: int
    source: str


def fit_thrust_coefficient(signals: Sequence[Signals], default: float) -> ThrustFit:
    """b = sum(T w^2) / sum(w^4) over samples with measured thrust; else the configured b."""
    w2 = [s.speed**2 for s in signals if s.thrust is not None]
    thrust = [s.thrust for s in signals if s.thrust is not None]
    if not w2:
        return ThrustFit(default, None, 0, "configured (no /thrust/measured recorded)")
    x = np.concatenate(w2)
    y = np.concatenate(thrust)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) < 10 or float(np.dot(x, x)) <= 0.0:
        return ThrustFit(default, None, 0, "configured (too little thrust data to fit)")
    b = float(np.dot(x, y) / np.dot(x, x))
    rms = float(np.sqrt(np.mean((y - b * x) ** 2)))
    return ThrustFit(b, rms, int(len(x)), "least squares on /thrust/measured")


@dataclass
class TrainOutcome:
    model: NetworkModel
    lm: LMResult
    train: list[Signals]
    validation: list[Signals]
    thrust: ThrustFit
    train_rmse_rad_s: float
    validation_rmse_rad_s: float


def stack(signals: Sequence[Signals], names: Sequence[str], params: dict[str, dict[str, float]]) -> tuple[np.ndarray, np.ndarray]:
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
    thrust_coefficient: float,
    max_epochs: int = 1000,
    patience: int = 6,
    progress: Callable[[int, float, float, float], None] | None = None,
    phi0: np.ndarray | None = None,
    restarts: int = 1,
    start_at_zero: bool = False,
) -> TrainOutcome:
    """Fit an n-H-1 network on ``train``, early-stopped on ``validation`` (separate recordings).

    ``phi0``: initial weights (in the scaling this training derives), e.g. to continue from a
    model; default Nguyen-Widrow from ``seed``. ``restarts``: train from the Nguyen-Widrow
    weights of seeds ``seed .. seed + restarts - 1`` (after ``phi0`` when given) and keep the
    network with the least validation cost. ``start_at_zero``: those weights with the output
    layer at 0 (the network's output 0 rad/s): a hybrid's correction starts from the physics
    alone, so early stopping keeps a network only where it helps on validation. Why restarts: LM finds a local minimum, and which one
    decides how the network extrapolates between the recordings' operating points; on the
    bundled bags the validation RMSE of single 3-25-1 runs spans 16-30 rad/s over seeds, and the
    validation cost is the unbiased way to choose among them (what trainlm users do by hand).
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
    n_params = hidden * (len(inputs) + 2) + 1
    if len(y) < max(2 * n_params, 50):
        raise BadInputError(
            f"too little training data: {len(y)} samples for {n_params} weights "
            f"(record longer or use fewer --hidden)"
        )
    if len(yv) < 20:
        raise BadInputError(f"too little validation data: {len(yv)} samples")
    try:
        xmin, xmax = minmax_fit(X)
    except ValueError as exc:
        names = ", ".join(inputs)
        raise BadInputError(f"training inputs ({names}) do not vary: {exc}") from None
    ymin, ymax = float(np.min(y)), float(np.max(y))
    if not ymax > ymin:
        raise BadInputError("the measured speed does not vary in the training recordings")
    Xs, Xvs = minmax_apply(X, xmin, xmax), minmax_apply(Xv, xmin, xmax)
    ys = 2.0 * (y - ymin) / (ymax - ymin) - 1.0
    yvs = 2.0 * (yv - ymin) / (ymax - ymin) - 1.0
    runs: list[tuple[int | None, LMResult]] = []
    starts: list[int | None] = ([None] if phi0 is not None else []) + list(range(seed, seed + restarts))
    zero = 2.0 * (0.0 - ymin) / (ymax - ymin) - 1.0  # the scaled output of 0 rad/s
    for start in starts[:restarts]:
        p0 = phi0 if start is None else _zero_output(len(inputs), hidden, start, zero) if start_at_zero else None
        runs.append((start, train_lm(Xs, ys, Xvs, yvs, hidden, seed=start or 0, phi0=p0,
                                     max_epochs=max_epochs, patience=patience, progress=progress)))
    best_seed, result = min(runs, key=lambda r: r[1].val_cost)
    W1, b1, W2, b2 = unpack(result.phi, len(inputs), hidden)
    fit = fit_thrust_coefficient(train, thrust_coefficient)
    metadata: dict[str, Any] = {
        "package_version": __version__,
        "sources": {
            "train": [_source(s) for s in train],
            "validation": [_source(s) for s in validation],
        },
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
        "seed": int(seed),
        "best_seed": best_seed,  # None: the run started from the given weights (phi0)
        "restarts": [{"seed": sd, "epochs": int(r.epochs), "best_epoch": int(r.best_epoch),
                      "validation_cost": float(r.val_cost)} for sd, r in runs],
        "hidden": int(hidden),
        "samples": {"train": int(len(y)), "validation": int(len(yv))},
        "thrust_fit": {"source": fit.source, "residual_rms_n": fit.residual_rms_n, "samples": fit.samples},
        "feature_params": params,
    }
    model = NetworkModel(
        input_names=tuple(inputs),
        input_min=np.asarray(xmin, dtype=float),
        input_max=np.asarray(xmax, dtype=float),
        output_min=ymin,
        output_max=ymax,
        W1=W1,
        b1=b1,
        W2=W2,
        b2=float(b2),
        pwm_tau_s=float(pwm_tau_s),
        thrust_coefficient=float(fit.coefficient),
        metadata=metadata,
    )
    rmse = float(np.sqrt(np.mean((model.forward(X) - y) ** 2)))
    rmse_v = float(np.sqrt(np.mean((model.forward(Xv) - yv) ** 2)))
    return TrainOutcome(model, result, list(train), list(validation), fit, rmse, rmse_v)


def _zero_output(n_in: int, hidden: int, seed: int, b2: float) -> np.ndarray:
    """Nguyen-Widrow hidden weights of ``seed``, output weights 0 and output bias ``b2``."""
    W1, b1, W2, _ = unpack(nguyen_widrow(n_in, hidden, np.random.default_rng(seed)), n_in, hidden)
    return pack(W1, b1, np.zeros_like(W2), b2)


def _source(sig: Signals) -> dict[str, str]:
    """Provenance of one recording: the path as given, where it was, and its content hash."""
    return {"path": sig.path, "abs_path": os.path.abspath(sig.path.split("#", 1)[0]), "sha256": sig.sha256}
