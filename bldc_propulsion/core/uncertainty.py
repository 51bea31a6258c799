"""The one-sigma band of a predicted speed: how far from the prediction the measured speed lies
68 % of the time, from what the estimator knows when it predicts.

A constant sigma is not calibrated: a model's error is small with the command held and large
after the command moves (the rotor's dead time and inertia, the ESC's braking), and it moves with
the speed (constants such as Kv or CP err in proportion). So the band is

    sigma = base + per_speed w + fast |u - lowpass(u, fast_tau_s)| + slow |u - lowpass(u, slow_tau_s)|

with w the predicted speed (rad/s), u the scaled command (0 stop .. 1 full, the ``pwm`` input)
and its low-passes the ``pwm_filtered`` input's filter (``core.features.PwmLowpass``) at two time
constants: ``FAST_TAU_S``, the paper's 0.25 s (the rotor and ESC settle on it), and
``SLOW_TAU_S``, the battery filter's ~2 s (the filtered voltage a model sees lags the pack's sag
and recovery after a load change by that much). Each term is the command's recent change seen on
one time scale: 0 with the command held, the size of a step just after it.

The four coefficients are fitted (``training.band``) by linear quantile regression of the
validation recordings' |measured - predicted| at ``ONE_SIGMA`` (68.27 %, the share of a normal
distribution within one sigma): on the validation data, 68.27 % lie inside (a little more where
the floor ``MIN_SIGMA_RAD_S`` lifts the band). Residuals are
heavy-tailed (transients), so a quantile is calibrated where an RMS is not (a Laplace error's RMS
holds 76 %). Four coefficients and no cells: a table over speed bins x command-change bins knows
that the command moved but not by how much, and needs each cell filled from a few validation
recordings; here a step's size scales its term.

The model file keeps the band in its metadata (``BAND_KEY``, versioned); a model without one
(trained before bands, or the first-principles fallback) predicts no sigma, and ``band_of``
says why. The band is the offline model's error; an online adaptation of the model's parameters
adds its own uncertainty (its covariance carried to the speed) in quadrature, through
``ThrustEstimator.adaptation_speed_variance``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import contract as c
from .features import compute_features, scale_pwm

#: The model metadata's key of the band, and of why a training fitted none.
BAND_KEY = "band"
NOT_FITTED_KEY = "band_not_fitted"
#: The band's format version; a newer one is not read (the model then has no band, and says why).
BAND_VERSION = 1
#: Share of a normal distribution within one sigma of its mean: erf(1 / sqrt(2)).
ONE_SIGMA = math.erf(1.0 / math.sqrt(2.0))
#: The command-change terms' time constants (s): the paper's PWM filter (rotor and ESC) and the
#: battery filter's (the filtered voltage's lag behind the pack).
FAST_TAU_S = c.PAPER_PWM_TAU_S
SLOW_TAU_S = c.PAPER_FILTER_TAU_S
#: Least sigma published (rad/s, about 1 rpm): a sigma of 0 claims an exact speed, which a filter
#: fusing the prediction would trust without limit.
MIN_SIGMA_RAD_S = 0.1
#: The coefficients, in the metadata's order (units in their names; per_speed is rad/s per rad/s).
COEFFICIENTS = ("base_rad_s", "per_speed", "fast_rad_s", "slow_rad_s")
NO_BAND_IN_FILE = ("the model file has no uncertainty band (trained before bands were fitted): "
                   "no predicted/speed_sigma or predicted/thrust_sigma; train it again for one")


@dataclass(frozen=True)
class SpeedBand:
    """One-sigma band of the predicted speed (module doc); coefficients >= 0."""

    base_rad_s: float  #: sigma at rest with the command held (rad/s)
    per_speed: float  #: added per rad/s of predicted speed (dimensionless)
    fast_rad_s: float  #: added per unit of |u - lowpass(u, fast_tau_s)| (rad/s)
    slow_rad_s: float  #: added per unit of |u - lowpass(u, slow_tau_s)| (rad/s)
    fast_tau_s: float = FAST_TAU_S
    slow_tau_s: float = SLOW_TAU_S

    def sigma(self, speed_rad_s: float, fast_change: float, slow_change: float) -> float:
        """Sigma (rad/s) at a predicted speed and the command's two changes (``CommandChange``)."""
        s = (self.base_rad_s + self.per_speed * speed_rad_s + self.fast_rad_s * fast_change
             + self.slow_rad_s * slow_change)
        return s if s > MIN_SIGMA_RAD_S else MIN_SIGMA_RAD_S

    def sigma_array(self, speed_rad_s: np.ndarray, fast_change: np.ndarray, slow_change: np.ndarray) -> np.ndarray:
        """``sigma`` over arrays (NaN where an argument is)."""
        s = (self.base_rad_s + self.per_speed * np.asarray(speed_rad_s, dtype=float)
             + self.fast_rad_s * np.asarray(fast_change, dtype=float)
             + self.slow_rad_s * np.asarray(slow_change, dtype=float))
        return np.where(np.isnan(s), np.nan, np.maximum(s, MIN_SIGMA_RAD_S))

    def as_metadata(self, **provenance: object) -> dict[str, object]:
        """The metadata's ``band`` object (JSON); ``provenance``: what it was fitted on."""
        return {"version": BAND_VERSION, "quantile": ONE_SIGMA,
                "form": "base + per_speed w + fast |u - lp(u, fast_tau_s)| + slow |u - lp(u, slow_tau_s)|",
                **{k: float(getattr(self, k)) for k in (*COEFFICIENTS, "fast_tau_s", "slow_tau_s")},
                **provenance}

    @classmethod
    def of_metadata(cls, meta: Mapping[str, Any]) -> SpeedBand:
        """From a checked ``band`` object (``band_problem`` None) of this version: JSON read from
        the model file, whose numbers ``band_problem`` has checked."""
        return cls(*(float(meta[k]) for k in (*COEFFICIENTS, "fast_tau_s", "slow_tau_s")))


def band_problem(meta: object) -> str | None:
    """What is wrong with a model file's ``band`` object, None if usable or of a newer version
    (``band_of`` says why such a band is not used)."""
    if not isinstance(meta, Mapping):
        return "must be a JSON object"
    version = meta.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        return f"version must be an integer >= 1, got {version!r}"
    if version > BAND_VERSION:
        return None
    for k in (*COEFFICIENTS, "fast_tau_s", "slow_tau_s"):
        v = meta.get(k)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0.0:
            return f"{k} must be a finite number >= 0, got {v!r}"
    if not (meta["fast_tau_s"] > 0.0 and meta["slow_tau_s"] > 0.0):
        return "fast_tau_s and slow_tau_s must be > 0"
    return None


def band_of(model: object) -> tuple[SpeedBand | None, str]:
    """The model's band, or None and why it has none (diagnostics and evaluate say it); any
    object: what it reads (``is_fallback``, ``metadata``) it looks up with getattr."""
    if getattr(model, "is_fallback", False):
        return None, "first-principles fallback: no validation residuals, so no uncertainty band"
    metadata = getattr(model, "metadata", None) or {}
    meta = metadata.get(BAND_KEY)
    if meta is None:
        why = metadata.get(NOT_FITTED_KEY)
        return None, f"no uncertainty band: {why}" if why else NO_BAND_IN_FILE
    why = band_problem(meta)
    if why:  # a model built in code with a bad band (files are checked on load)
        return None, f"the model's band is not usable: {why}"
    if meta["version"] > BAND_VERSION:
        return None, (f"the model's band is version {meta['version']}, newer than this program reads "
                      f"({BAND_VERSION}): no sigma published")
    return SpeedBand.of_metadata(meta), f"fitted on {meta.get('samples', '?')} validation samples"


class CommandChange:
    """The command's two recent changes |u - lowpass(u, tau)| (fast, slow) as a stream: the
    estimator's twin of ``command_changes``, written out for its cost (two exponentials per
    command and per prediction): a low-pass y of a held u is u + (y0 - u) exp(-dt / tau), so its
    distance from u decays by exp(-dt / tau) and a new command adds the step (equal to the batch
    to ~1e-15)."""

    __slots__ = ("_rate_fast", "_rate_slow", "_t", "_u", "_e_fast", "_e_slow")

    def __init__(self, band: SpeedBand) -> None:
        self._rate_fast = 1.0 / band.fast_tau_s
        self._rate_slow = 1.0 / band.slow_tau_s
        self.reset()

    def reset(self) -> None:
        self._t: float | None = None  #: the latest command's time
        self._u = 0.0  #: the latest command, scaled
        self._e_fast = self._e_slow = 0.0  #: each low-pass minus u, at _t

    def update_pwm(self, t: float, level: float) -> None:
        """An accepted PWM level at t (the estimator checks it); filters start in steady state."""
        u = scale_pwm(level)
        if self._t is not None:
            dt = t - self._t
            step = self._u - u
            self._e_fast = self._e_fast * math.exp(-dt * self._rate_fast) + step
            self._e_slow = self._e_slow * math.exp(-dt * self._rate_slow) + step
        self._t, self._u = t, u

    def at(self, t: float) -> tuple[float, float]:
        """(fast, slow) change at t >= the latest command; 0 before the first (none seen to move)."""
        if self._t is None:
            return 0.0, 0.0
        dt = t - self._t
        return abs(self._e_fast) * math.exp(-dt * self._rate_fast), abs(self._e_slow) * math.exp(-dt * self._rate_slow)


def command_changes(band: SpeedBand, grid_t: np.ndarray, pwm_t: np.ndarray,
                    pwm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(fast, slow) command change on sorted grid times from the PWM events (samples the
    estimator rejects dropped as it drops them; 0 before the first command, as ``CommandChange``)."""
    none = np.zeros(0)
    X = compute_features(grid_t, pwm_t, pwm, none, none, [c.INPUT_PWM, c.INPUT_PWM_FILTERED],
                         {c.INPUT_PWM_FILTERED: {"tau_s": band.fast_tau_s}})
    slow = compute_features(grid_t, pwm_t, pwm, none, none, [c.INPUT_PWM_FILTERED],
                            {c.INPUT_PWM_FILTERED: {"tau_s": band.slow_tau_s}})[:, 0]
    fast = np.abs(X[:, 0] - X[:, 1])
    slow = np.abs(X[:, 0] - slow)
    return np.where(np.isnan(fast), 0.0, fast), np.where(np.isnan(slow), 0.0, slow)


def thrust_sigma(thrust_coefficient: float, speed_rad_s: float, speed_sigma_rad_s: float) -> float:
    """One-sigma of thrust = b w^2 from the speed's, to first order: 2 b w sigma_w (N)."""
    return 2.0 * thrust_coefficient * speed_rad_s * speed_sigma_rad_s
