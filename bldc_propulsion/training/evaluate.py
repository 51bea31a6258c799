"""How far a model's predicted speed is from the measured speed, per recording and per band."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
from scipy import signal, stats

from ..core.uncertainty import band_of, command_changes
from ..model import Model, RangeJson, RangeReport, range_report
from ..recordings import Signals
from .train import features_of

#: Command frequency bands (Hz) for chirp recordings: the paper notes the error grows with the
#: PWM signal's frequency; these bands quantify it around the rotor's ~1.5 Hz corner.
BANDS_HZ: tuple[tuple[float, float], ...] = ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 4.0))
#: Why a recording's score has no thrust error.
THRUST_NOT_RECORDED = "no /thrust/measured in the recording"
THRUST_NO_COEFFICIENT = "the model has no thrust coefficient (it predicts speed only)"


def model_inputs(model: Model, sig: Signals) -> np.ndarray:
    """The model's raw inputs on the recording's grid (rows: time), NaN while unknown."""
    return features_of(sig, model.input_names, model.feature_params())


def input_range(model: Model, sig: Signals) -> RangeReport:
    """How much of the recording lies outside the model's training range (model.range_report)."""
    return range_report(model, model_inputs(model, sig), sig.path)


def predict_speed(model: Model, sig: Signals, X: np.ndarray | None = None) -> np.ndarray:
    """Predicted speed (rad/s) on the recording's grid, clipped to >= 0 as the estimator does;
    inputs clipped to the training range, as the estimator clips them. A physics or hybrid
    model's physics starts from the recording's measured speed when its rotor is already turning
    at the start (a log cut mid-run: ``training.train.features_of``), not at rest."""
    X = model_inputs(model, sig) if X is None else X
    X = np.clip(X, model.input_min, model.input_max)
    return np.maximum(model.forward(X), 0.0)


def command_frequency(t: np.ndarray, pwm: np.ndarray) -> np.ndarray:
    """Instantaneous frequency (Hz) of the command's dominant oscillation.

    The command is detrended, low-passed at 5 Hz (zero phase) to drop the added noise, and the
    phase of its analytic signal (Hilbert transform) is differentiated and median-smoothed
    over 2 s.
    """
    fs = 1.0 / float(np.median(np.diff(t)))
    x = pwm - np.mean(pwm)
    b, a = signal.butter(2, min(5.0 / (fs / 2.0), 0.99))
    x = signal.filtfilt(b, a, x)
    phase = np.unwrap(np.angle(signal.hilbert(x)))
    f = np.gradient(phase, t) / (2.0 * np.pi)
    k = int(2.0 * fs) | 1
    return signal.medfilt(np.abs(f), k) if len(f) > k else np.abs(f)


def is_chirp(t: np.ndarray, pwm: np.ndarray) -> tuple[bool, np.ndarray]:
    """A chirp-like recording: its command frequency rises steadily over at least 2 octaves."""
    if len(t) < 500 or np.ptp(pwm) <= 0:
        return False, np.zeros(len(t))
    f = command_frequency(t, pwm)
    core = slice(len(f) // 20, len(f) - len(f) // 20)  # Hilbert edge effects
    rho = stats.spearmanr(t[core], f[core]).statistic
    lo, hi = np.percentile(f[core], [10, 90])
    return bool(rho > 0.7 and hi > 4.0 * max(lo, 1e-3)), f


class BandCoverageJson(TypedDict):
    """``BandCoverage.as_dict``: band_coverage in evaluate's --json."""

    percent: float
    mean_sigma_rad_s: float
    samples: int


class RecordingScoreJson(TypedDict):
    """``RecordingScore.as_dict``: one recording's figures in evaluate's --json."""

    path: str
    rmse_rad_s: float
    rmse_percent_of_range: float
    max_error_rad_s: float
    speed_range_rad_s: float
    samples: int
    bands: list[dict[str, float]]
    out_of_training_range: RangeJson | None
    thrust_rmse_n: float | None
    thrust_range_n: float | None
    thrust_rmse_percent_of_range: float | None
    thrust_unavailable: str | None
    band_coverage: BandCoverageJson | None


@dataclass
class RecordingScore:
    path: str
    rmse_rad_s: float
    rmse_percent_of_range: float
    max_error_rad_s: float
    speed_range_rad_s: float
    samples: int
    bands: list[dict[str, float]] = field(default_factory=list)
    out_of_range: RangeReport | None = None
    #: thrust RMSE (N) of b w^2 against /thrust/measured, when the recording has it and the model a b
    thrust_rmse_n: float | None = None
    #: the measured thrust's range (N) over the samples scored, and the thrust RMSE in % of it
    thrust_range_n: float | None = None
    thrust_rmse_percent_of_range: float | None = None
    #: why there is no thrust RMSE (None: there is one)
    thrust_unavailable: str | None = None
    #: the model's one-sigma band here (``band_coverage``); None: the model has no band
    band: BandCoverage | None = None

    def as_dict(self) -> RecordingScoreJson:
        return {
            "path": self.path,
            "rmse_rad_s": self.rmse_rad_s,
            "rmse_percent_of_range": self.rmse_percent_of_range,
            "max_error_rad_s": self.max_error_rad_s,
            "speed_range_rad_s": self.speed_range_rad_s,
            "samples": self.samples,
            "bands": self.bands,
            "out_of_training_range": self.out_of_range.as_dict() if self.out_of_range else None,
            "thrust_rmse_n": self.thrust_rmse_n,
            "thrust_range_n": self.thrust_range_n,
            "thrust_rmse_percent_of_range": self.thrust_rmse_percent_of_range,
            "thrust_unavailable": self.thrust_unavailable,
            "band_coverage": self.band.as_dict() if self.band else None,
        }


def score(model: Model, sig: Signals) -> tuple[RecordingScore, np.ndarray]:
    """Errors of one recording, and the prediction they were computed from."""
    X = model_inputs(model, sig)
    pred = predict_speed(model, sig, X)
    err = pred - sig.speed
    ok = np.isfinite(err)
    rng = float(np.ptp(sig.speed[ok])) if ok.any() else 0.0
    rmse = float(np.sqrt(np.mean(err[ok] ** 2)))
    out = RecordingScore(
        path=sig.path,
        rmse_rad_s=rmse,
        rmse_percent_of_range=100.0 * rmse / rng if rng > 0 else float("nan"),
        max_error_rad_s=float(np.max(np.abs(err[ok]))),
        speed_range_rad_s=rng,
        samples=int(ok.sum()),
        out_of_range=range_report(model, X, sig.path),
    )
    if sig.thrust is None:
        out.thrust_unavailable = THRUST_NOT_RECORDED
    elif model.thrust_coefficient is None:
        out.thrust_unavailable = THRUST_NO_COEFFICIENT
    else:  # thrust = b w^2 from the same predicted speed
        t_err = model.thrust_coefficient * pred**2 - sig.thrust
        t_ok = np.isfinite(t_err)
        if t_ok.any():
            out.thrust_rmse_n = float(np.sqrt(np.mean(t_err[t_ok] ** 2)))
            out.thrust_range_n = float(np.ptp(sig.thrust[t_ok]))
            out.thrust_rmse_percent_of_range = (100.0 * out.thrust_rmse_n / out.thrust_range_n
                                                if out.thrust_range_n > 0 else None)
    out.bands = band_errors(sig.t, sig.pwm, err, rng)
    out.band = band_coverage(model, sig, pred)
    return out, pred


@dataclass
class BandCoverage:
    """How many measured speeds lie within the model's one-sigma band (``core.uncertainty``)
    around its prediction: about 68 % where the band is calibrated."""

    inside: int  #: samples with |measured - predicted| <= sigma
    samples: int  #: samples with a measured and a predicted speed
    sigma_sum_rad_s: float  #: sum of sigma over them (rad/s), for means over several recordings

    @property
    def percent(self) -> float:
        return 100.0 * self.inside / self.samples if self.samples else float("nan")

    @property
    def mean_sigma_rad_s(self) -> float:
        return self.sigma_sum_rad_s / self.samples if self.samples else float("nan")

    def __add__(self, other: BandCoverage) -> BandCoverage:
        return BandCoverage(self.inside + other.inside, self.samples + other.samples,
                            self.sigma_sum_rad_s + other.sigma_sum_rad_s)

    def as_dict(self) -> BandCoverageJson:
        return {"percent": self.percent, "mean_sigma_rad_s": self.mean_sigma_rad_s, "samples": self.samples}


def band_sigma(model: Model, sig: Signals, pred: np.ndarray) -> np.ndarray | None:
    """The model's one-sigma band (rad/s) around ``pred`` on the recording's grid, as the
    estimator computes it; None for a model without a band (``core.uncertainty.band_of``)."""
    band, _ = band_of(model)
    if band is None:
        return None
    return band.sigma_array(pred, *command_changes(band, sig.t, *sig.pwm_events))


def band_coverage(model: Model, sig: Signals, pred: np.ndarray) -> BandCoverage | None:
    """``BandCoverage`` of ``pred`` against the recording's measured speed (None: no band)."""
    sigma = band_sigma(model, sig, pred)
    if sigma is None:
        return None
    err = np.abs(sig.speed - pred)
    ok = np.isfinite(err) & np.isfinite(sigma)
    return BandCoverage(int(np.count_nonzero(err[ok] <= sigma[ok])), int(ok.sum()), float(np.sum(sigma[ok])))


def band_errors(t: np.ndarray, pwm: np.ndarray, err: np.ndarray, speed_range_rad_s: float) -> list[dict[str, float]]:
    """RMSE of ``err`` (rad/s, NaN where unknown) per command-frequency band (``BANDS_HZ``) of a
    chirp-like recording, absolute and in % of the speed range; [] for other recordings."""
    chirp, freq = is_chirp(t, pwm)
    if not chirp:
        return []
    ok = np.isfinite(err)
    rng = speed_range_rad_s
    # the Hilbert transform's frequency is unreliable in the first and last 5 % (edge effects;
    # they also hold the start-up step from rest), so bands leave them out
    inner = np.zeros(len(ok), dtype=bool)
    inner[len(ok) // 20: len(ok) - len(ok) // 20] = True
    bands = []
    for lo, hi in BANDS_HZ:
        sel = ok & inner & (freq >= lo) & (freq < hi)
        if sel.sum() >= 50:
            band_rmse = float(np.sqrt(np.mean(err[sel] ** 2)))
            bands.append({
                "low_hz": lo, "high_hz": hi, "samples": int(sel.sum()), "rmse_rad_s": band_rmse,
                "rmse_percent_of_range": 100.0 * band_rmse / rng if rng > 0 else float("nan"),
            })
    return bands


def evaluate(model: Model, signals: Sequence[Signals]) -> tuple[float, list[RecordingScore], list[np.ndarray]]:
    """Overall RMSE (rad/s) over all samples, per-recording scores and predictions."""
    scores, preds = zip(*(score(model, s) for s in signals), strict=True) if signals else ((), ())
    errs = np.concatenate([p - s.speed for p, s in zip(preds, signals, strict=True)])
    errs = errs[np.isfinite(errs)]
    return float(np.sqrt(np.mean(errs**2))), list(scores), list(preds)
