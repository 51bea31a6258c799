"""Where and how a model disagrees with measurements: windows, whiteness, cross-correlation, conditions.

The classical residual analysis of system identification (Ljung, *System Identification*,
ch. 16.6): a model that has captured the dynamics leaves a residual that is (i) white and
(ii) uncorrelated with past inputs. Both are tested with the usual +/-1.96/sqrt(N) bounds of a
white sequence; whiteness also by the Ljung-Box portmanteau statistic. Samples on the 100 Hz
grid are strongly correlated by the rotor itself, so the tests run on the residual decimated to
10 Hz (one sample per 0.1 s, about one rotor time constant).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np
from scipy import stats

from .. import contract as c
from ..runs import true_run_pairs

#: Decimation of the 100 Hz residual for the whiteness/cross-correlation tests (-> 10 Hz).
TEST_DECIMATION = 10
#: Lags (decimated samples) of the tests: 0..2 s.
TEST_LAGS = 20
#: Smoothing of |r| before thresholding (s), merge gap and least window length (s).
SMOOTH_S = 0.3
MERGE_GAP_S = 0.5
MIN_WINDOW_S = 0.3
#: A window is where the smoothed |r| exceeds THRESHOLD_SIGMAS x the reference noise level.
THRESHOLD_SIGMAS = 3.0
#: PWM counts as "under load" above this level (motor clearly spinning).
LOAD_PWM = c.PWM_STOP + 0.01


def robust_sigma(x: np.ndarray) -> float:
    """1.4826 x median absolute deviation: the standard deviation of the bulk, ignoring outliers."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return float("nan")
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def speed_noise(events: Sequence[tuple[np.ndarray, np.ndarray]]) -> float:
    """The measured speed's own noise (rad/s, one sigma), whatever any model says, from each
    recording's speed as measured (``Signals.speed_events``, not the grid it was interpolated
    onto): the second differences of samples at least a revolution apart (a tachometer's
    estimates over the last revolution overlap, and overlapping ones share their noise) cancel a
    locally linear speed and leave 6 sigma^2 of white noise; robust (command steps are outliers).
    Only where the rotor turns (above a tenth of its top speed): a stopped rotor reads exactly 0."""
    d2 = []
    for t, y in events:
        t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
        ok = np.isfinite(t) & np.isfinite(y)
        t, y = t[ok], y[ok]
        if len(y) < 3 or not np.max(y) > 0:
            continue
        keep, next_t = [], -np.inf
        turning = y > 0.1 * np.max(y)
        # (a loop: which sample comes next depends on the speed of the one kept before it)
        for k in range(len(y)):
            if not turning[k]:
                keep.append(-1)
                next_t = -np.inf
            elif t[k] >= next_t:
                keep.append(k)
                next_t = t[k] + 2.0 * np.pi / y[k]
        runs = np.split(np.array(keep, dtype=int), np.flatnonzero(np.array(keep) < 0))
        for run in runs:
            run = run[run >= 0]
            if len(run) >= 3:
                v = y[run]
                d2.append(v[:-2] - 2.0 * v[1:-1] + v[2:])
    x = np.concatenate(d2) if d2 else np.zeros(0)
    return float(1.4826 * np.median(np.abs(x)) / np.sqrt(6.0)) if len(x) else float("nan")


def moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1:
        return np.asarray(x, dtype=float)
    k = np.ones(n) / n
    pad = n // 2
    xp = np.pad(np.asarray(x, dtype=float), (pad, n - 1 - pad), mode="edge")
    return np.convolve(xp, k, mode="valid")


def pwm_rate(t: np.ndarray, pwm: np.ndarray, smooth_s: float = 0.2) -> np.ndarray:
    """dPWM/dt (1/s) of the held command, smoothed over ``smooth_s`` so a step shows as a pulse."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    d = np.gradient(pwm, t) if len(t) > 1 else np.zeros(len(t))
    return moving_average(d, max(1, int(round(smooth_s / dt))))


def time_under_load(t: np.ndarray, pwm: np.ndarray) -> np.ndarray:
    """Seconds since the command last rose above LOAD_PWM (0 while below it)."""
    out = np.zeros(len(t))
    start = None
    for k in range(len(t)):
        if pwm[k] > LOAD_PWM:
            if start is None:
                start = t[k]
            out[k] = t[k] - start
        else:
            start = None
    return out


class WindowConditions(TypedDict):
    """The operating conditions of a ``Window`` in --json."""

    pwm: float
    pwm_rate_per_s: float
    pwm_direction: str
    battery_voltage_v: float
    time_under_load_s: float


class WindowJson(TypedDict):
    """``Window.as_dict``: a disagreement window as --json and the summary carry it."""

    path: str
    t_start_s: float
    t_end_s: float
    duration_s: float
    rms_residual_rad_s: float
    mean_residual_rad_s: float
    conditions: WindowConditions


@dataclass
class Window:
    """A stretch of one recording where the model disagrees with the measurement."""

    path: str
    t_start_s: float
    t_end_s: float
    rms_residual_rad_s: float
    mean_residual_rad_s: float
    pwm_mean: float
    pwm_rate_mean_per_s: float
    pwm_direction: str  # "rising", "falling", "steady"
    voltage_mean_v: float
    time_under_load_s: float

    def as_dict(self) -> WindowJson:
        return {
            "path": self.path,
            "t_start_s": self.t_start_s,
            "t_end_s": self.t_end_s,
            "duration_s": self.t_end_s - self.t_start_s,
            "rms_residual_rad_s": self.rms_residual_rad_s,
            "mean_residual_rad_s": self.mean_residual_rad_s,
            "conditions": {
                "pwm": self.pwm_mean,
                "pwm_rate_per_s": self.pwm_rate_mean_per_s,
                "pwm_direction": self.pwm_direction,
                "battery_voltage_v": self.voltage_mean_v,
                "time_under_load_s": self.time_under_load_s,
            },
        }


def find_windows(path: str, t: np.ndarray, r: np.ndarray, pwm: np.ndarray, voltage: np.ndarray,
                 threshold: float) -> tuple[list[Window], np.ndarray]:
    """Windows where the smoothed |r| exceeds ``threshold`` (rad/s); and the in-window mask."""
    r = np.where(np.isfinite(r), r, 0.0)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    a = moving_average(np.abs(r), max(1, int(round(SMOOTH_S / dt))))
    above = a > threshold
    # merge gaps shorter than MERGE_GAP_S, drop windows shorter than MIN_WINDOW_S
    merged: list[list[int]] = []
    for s, e in true_run_pairs(above):
        if merged and (t[s] - t[merged[-1][1] - 1]) < MERGE_GAP_S:
            merged[-1][1] = e
        else:
            merged.append([s, e])
    rate = pwm_rate(t, pwm)
    load = time_under_load(t, pwm)
    mask = np.zeros(len(t), dtype=bool)
    out: list[Window] = []
    for s, e in merged:
        if t[e - 1] - t[s] < MIN_WINDOW_S:
            continue
        mask[s:e] = True
        seg = slice(s, e)
        mr = float(np.mean(rate[seg]))
        thr_rate = 0.02  # PWM level per second: a 0.01 step over 0.5 s
        direction = "rising" if mr > thr_rate else "falling" if mr < -thr_rate else "steady"
        out.append(Window(
            path=path, t_start_s=float(t[s]), t_end_s=float(t[e - 1]),
            rms_residual_rad_s=float(np.sqrt(np.mean(r[seg] ** 2))),
            mean_residual_rad_s=float(np.mean(r[seg])),
            pwm_mean=float(np.mean(pwm[seg])), pwm_rate_mean_per_s=mr, pwm_direction=direction,
            voltage_mean_v=float(np.mean(voltage[seg])), time_under_load_s=float(np.mean(load[seg])),
        ))
    return out, mask


def autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """Sample autocorrelation at lags 0..lags (biased estimator, as in Ljung)."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    n = len(x)
    denom = float(np.dot(x, x)) or 1.0
    return np.array([float(np.dot(x[: n - k], x[k:])) / denom for k in range(lags + 1)])


def cross_correlation(r: np.ndarray, u: np.ndarray, lags: int) -> np.ndarray:
    """Correlation of r(t) with u(t - k) for k = 0..lags (past inputs)."""
    r = np.asarray(r, dtype=float) - np.mean(r)
    u = np.asarray(u, dtype=float) - np.mean(u)
    n = len(r)
    denom = float(np.sqrt(np.dot(r, r) * np.dot(u, u))) or 1.0
    return np.array([float(np.dot(r[k:], u[: n - k])) / denom for k in range(lags + 1)])


def ljung_box(acf: np.ndarray, n: int) -> tuple[float, float]:
    """Ljung-Box Q over lags 1..len(acf)-1 and its chi-squared p-value (H0: white)."""
    m = len(acf) - 1
    k = np.arange(1, m + 1)
    q = float(n * (n + 2) * np.sum(acf[1:] ** 2 / (n - k)))
    return q, float(stats.chi2.sf(q, m))


class Whiteness(TypedDict):
    """The residual's autocorrelation test in --json."""

    lags_outside_bounds: int
    lags_tested: int
    max_abs_autocorrelation: float
    ljung_box_q: float
    ljung_box_p: float
    white: bool


class CrossCorrelation(TypedDict):
    """The residual's cross-correlation with one input in --json."""

    max_abs: float
    at_lag_s: float
    lags_outside_bounds: int
    independent: bool


class ResidualTestsJson(TypedDict):
    """``ResidualTests.as_dict``: the residual tests as --json and the summary carry them."""

    decimated_rate_hz: float
    samples: int
    bound_95: float
    whiteness: Whiteness
    cross_correlation: dict[str, CrossCorrelation]


@dataclass
class ResidualTests:
    samples: int
    bound: float
    acf: np.ndarray
    ljung_box_q: float
    ljung_box_p: float
    xcorr: dict[str, np.ndarray] = field(default_factory=dict)

    def as_dict(self) -> ResidualTestsJson:
        out: ResidualTestsJson = {
            "decimated_rate_hz": 100.0 / TEST_DECIMATION,
            "samples": self.samples,
            "bound_95": self.bound,
            "whiteness": {
                "lags_outside_bounds": int(np.sum(np.abs(self.acf[1:]) > self.bound)),
                "lags_tested": int(len(self.acf) - 1),
                "max_abs_autocorrelation": float(np.max(np.abs(self.acf[1:]))) if len(self.acf) > 1 else 0.0,
                "ljung_box_q": self.ljung_box_q,
                "ljung_box_p": self.ljung_box_p,
                "white": bool(self.ljung_box_p >= 0.01),
            },
            "cross_correlation": {},
        }
        for name, xc in self.xcorr.items():
            k = int(np.argmax(np.abs(xc)))
            out["cross_correlation"][name] = {
                "max_abs": float(np.abs(xc[k])),
                "at_lag_s": k * TEST_DECIMATION / 100.0,
                "lags_outside_bounds": int(np.sum(np.abs(xc) > self.bound)),
                "independent": bool(np.all(np.abs(xc) <= self.bound)),
            }
        return out


def residual_tests(residuals: Sequence[np.ndarray], inputs: Sequence[dict[str, np.ndarray]]) -> ResidualTests:
    """Whiteness and input cross-correlation of residuals (per recording, pooled over recordings).

    Statistics are pooled as the sample-size-weighted mean of the per-recording correlations.
    """
    acfs, weights = [], []
    xcs: dict[str, list[np.ndarray]] = {}
    n_total = 0
    for r, u in zip(residuals, inputs, strict=True):
        ok = np.isfinite(r)
        rd = r[ok][::TEST_DECIMATION]
        if len(rd) <= TEST_LAGS + 2:
            continue
        n_total += len(rd)
        weights.append(len(rd))
        acfs.append(autocorrelation(rd, TEST_LAGS))
        for name, x in u.items():
            xd = np.asarray(x)[ok][::TEST_DECIMATION]
            xcs.setdefault(name, []).append(cross_correlation(rd, xd, TEST_LAGS))
    if not acfs:
        return ResidualTests(0, float("nan"), np.zeros(1), float("nan"), float("nan"))
    w = np.asarray(weights, dtype=float)
    acf = np.average(np.vstack(acfs), axis=0, weights=w)
    q, p = ljung_box(acf, n_total)
    xcorr = {k: np.average(np.vstack(v), axis=0, weights=w) for k, v in xcs.items()}
    return ResidualTests(n_total, 1.96 / np.sqrt(n_total), acf, q, p, xcorr)


#: Condition bins of the disagreement map.
PWM_BINS = (0.05, 0.06, 0.07, 0.08, 0.09, 0.1001)


def condition_bins(t: Sequence[np.ndarray], r: Sequence[np.ndarray], pwm: Sequence[np.ndarray],
                   voltage: Sequence[np.ndarray]) -> dict[str, list[dict[str, float | str]]]:
    """RMS residual per PWM level bin, per command direction, per voltage and time-under-load tercile."""
    R = np.concatenate([np.asarray(x) for x in r])
    P = np.concatenate([np.asarray(x) for x in pwm])
    V = np.concatenate([np.asarray(x) for x in voltage])
    D = np.concatenate([pwm_rate(tt, pp) for tt, pp in zip(t, pwm, strict=True)])
    L = np.concatenate([time_under_load(tt, pp) for tt, pp in zip(t, pwm, strict=True)])
    ok = np.isfinite(R)

    def rms(sel: np.ndarray) -> dict[str, float]:
        s = sel & ok
        return {"samples": int(s.sum()),
                "rms_residual_rad_s": float(np.sqrt(np.mean(R[s] ** 2))) if s.any() else float("nan"),
                "mean_residual_rad_s": float(np.mean(R[s])) if s.any() else float("nan")}

    out: dict[str, list[dict[str, float | str]]] = {
        "pwm": [], "pwm_direction": [], "voltage": [], "time_under_load": []}
    for lo, hi in zip(PWM_BINS[:-1], PWM_BINS[1:], strict=True):
        out["pwm"].append({"low": lo, "high": min(hi, c.PWM_FULL), **rms((P >= lo) & (P < hi))})
    for name, sel in (("rising", D > 0.02), ("falling", D < -0.02), ("steady", np.abs(D) <= 0.02)):
        out["pwm_direction"].append({"direction": name, **rms(sel)})
    for key, x in (("voltage", V), ("time_under_load", L)):
        qs = np.nanpercentile(x, [0, 33.3, 66.7, 100]) if len(x) else [0, 0, 0, 0]
        for lo, hi in zip(qs[:-1], qs[1:], strict=True):
            out[key].append({"low": float(lo), "high": float(hi), **rms((x >= lo) & (x <= hi))})
    return out
