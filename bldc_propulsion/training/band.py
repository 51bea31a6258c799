"""Fit a model's one-sigma speed band (``core.uncertainty``) on its validation recordings.

The band's coefficients are the linear quantile regression, at ``ONE_SIGMA``, of |measured -
predicted| on (1, w, fast change, slow change) with every coefficient >= 0, solved as the dual
linear programme (a handful of constraints, one bounded variable per sample: HiGHS takes ~0.05 s
for 6000 samples, where the primal takes seconds). Only validation recordings: the residuals of
the training data are what the fit minimised, and the test recordings are for judging the band.

The residual is taken where ``evaluate`` takes it: on the 100 Hz grid, against the measured speed
interpolated between revolution middles (``recordings.load_signals``), the prediction made from
the inputs up to each grid time. Neighbouring samples are strongly correlated (a transient
lasts tens of them), so a long validation set is thinned to ``MAX_SAMPLES`` evenly.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linprog

from ..core.uncertainty import BAND_KEY, NOT_FITTED_KEY, ONE_SIGMA, SpeedBand, command_changes
from ..recordings import Signals

#: Most residual samples the regression takes (the rest thinned evenly): ~0.2 s of HiGHS.
MAX_SAMPLES = 20000
#: Fewest finite residual samples a band is fitted from (1 s at 100 Hz).
MIN_SAMPLES = 100


def residuals(predictions: Sequence[np.ndarray], validation: Sequence[Signals]) -> tuple[np.ndarray, np.ndarray]:
    """(X, |e|): rows (1, predicted speed, fast change, slow change) and |measured - predicted|
    (rad/s) on every recording's grid where all are known; ``predictions``: the model's speed on
    each recording's grid (``training.evaluate.predict_speed``)."""
    shape = SpeedBand(0.0, 0.0, 0.0, 0.0)  # the time constants, for the command changes
    cols, err = [], []
    for sig, pred in zip(validation, predictions, strict=True):
        fast, slow = command_changes(shape, sig.t, *sig.pwm_events)
        e = np.abs(sig.speed - pred)
        ok = np.isfinite(e) & np.isfinite(fast) & np.isfinite(slow)
        cols.append(np.column_stack([np.ones(int(ok.sum())), pred[ok], fast[ok], slow[ok]]))
        err.append(e[ok])
    return (np.vstack(cols) if cols else np.zeros((0, 4))), (np.concatenate(err) if err else np.zeros(0))


def fit_band(X: np.ndarray, e: np.ndarray) -> SpeedBand:
    """The band from ``residuals``' rows and errors (module doc), thinned to MAX_SAMPLES."""
    step = -(-len(e) // MAX_SAMPLES)  # ceil: every step-th sample
    return SpeedBand(*quantile_regression(X[::step], e[::step], ONE_SIGMA))


def quantile_regression(X: np.ndarray, y: np.ndarray, q: float) -> tuple[float, ...]:
    """Coefficients b >= 0 minimising the pinball loss of y - X b at quantile q.

    The dual: maximise y'a over q - 1 <= a <= q subject to X'a <= 0; b is the constraints'
    multipliers. Columns are scaled to a largest |value| of 1 first (HiGHS's tolerances are
    absolute), and b unscaled after."""
    scale = np.max(np.abs(X), axis=0)
    scale[scale == 0.0] = 1.0
    Xs = X / scale
    res = linprog(-y, A_ub=Xs.T, b_ub=np.zeros(X.shape[1]), bounds=(q - 1.0, q), method="highs")
    if res.status != 0:  # pragma: no cover - bounded and feasible (a = 0) by construction
        raise RuntimeError(f"quantile regression failed: {res.message}")
    b = np.maximum(-np.asarray(res.ineqlin.marginals), 0.0) / scale
    return tuple(float(v) for v in b)


def band_metadata(predictions: Sequence[np.ndarray], validation: Sequence[Signals]) -> dict[str, object]:
    """``{BAND_KEY: ...}`` for a model's metadata: the band fitted on its ``predictions`` of the
    ``validation`` recordings (``residuals``), with what it was fitted on and how much of it lies
    inside (68.27 % by construction, to rounding); with fewer than MIN_SAMPLES residuals,
    ``{NOT_FITTED_KEY: why}`` instead (the model has no band)."""
    X, e = residuals(predictions, validation)
    if len(e) < MIN_SAMPLES:
        return {NOT_FITTED_KEY: f"only {len(e)} validation samples with a measured speed (a band needs "
                                f"at least {MIN_SAMPLES})"}
    band = fit_band(X, e)
    sigma = band.sigma_array(X[:, 1], X[:, 2], X[:, 3])
    return {BAND_KEY: band.as_metadata(
        fitted_on=[s.path for s in validation], samples=len(e),
        validation_coverage_percent=100.0 * float(np.mean(e <= sigma)),
        validation_mean_sigma_rad_s=float(np.mean(sigma)))}
