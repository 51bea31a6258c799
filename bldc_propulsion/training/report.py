"""PNG figures like the paper's and an index.html that shows them with figures of merit.

Every figure function takes plain numpy arrays in SI units (s, V, rad/s, PWM level) and an
output path, writes the PNG atomically (a report directory is rewritten as a whole, so an
existing figure is replaced) and returns the path. Nothing here reads recordings: callers in
``training`` and ``discrepancy`` extract the arrays, so figures can be made from any source.
Long signals (1 kHz battery samples over minutes) are reduced to a min/max envelope per pixel
column before plotting, which keeps the ESC modulation band visible and the figures fast.
"""

from __future__ import annotations

import html
import json
import math
import os
import sys
from collections.abc import Iterable, Mapping, Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any, TypeAlias, TypedDict
from urllib.parse import quote

import matplotlib

matplotlib.use("Agg")  # before pyplot: no display needed, same output everywhere

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import ArrayLike, NDArray  # noqa: E402

from ..atomic import atomic_output  # noqa: E402
from ..errors import BadInputError  # noqa: E402

DPI = 90
MAX_LINE_POINTS = 4000  #: per plotted line; longer signals are min/max-enveloped
MAX_SCATTER_POINTS = 20000
PathLike = str | os.PathLike[str]
#: A series a figure function accepts: anything ``np.asarray`` makes a float array of (None: empty).
Series: TypeAlias = ArrayLike | None
#: A value ``json.dumps`` writes as it is (what ``_jsonable`` makes of anything).
JsonValue: TypeAlias = None | bool | int | float | str | list["JsonValue"] | dict[str, "JsonValue"]

# -- helpers ---------------------------------------------------------------------------------


def _arr(x: Series) -> NDArray[np.float64]:
    return np.asarray(x if x is not None else [], dtype=float).ravel()


def _pair(t: Series, y: Series) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Same-length finite (t, y); a length mismatch is a caller bug, so it raises."""
    t, y = _arr(t), _arr(y)
    if len(t) != len(y):
        raise ValueError(f"time and value arrays differ in length ({len(t)} vs {len(y)})")
    ok = np.isfinite(t) & np.isfinite(y)
    return t[ok], y[ok]


def _envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_LINE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Min and max of each of ``max_points/2`` buckets, in time order: looks like the full line."""
    n = len(t)
    if n <= max_points:
        return t, y
    buckets = max_points // 2
    edges = np.linspace(0, n, buckets + 1).astype(int)
    tt, yy = [], []
    for a, b in pairwise(edges.tolist()):
        if b <= a:
            continue
        seg = y[a:b]
        i, j = int(np.argmin(seg)), int(np.argmax(seg))
        for k in sorted((i, j)):
            tt.append(t[a + k])
            yy.append(seg[k])
    return np.asarray(tt), np.asarray(yy)


def _line(ax: Axes, t: Series, y: Series, *args: str, **kwargs: Any) -> None:
    """``ax.plot`` of the finite samples, enveloped; ``kwargs`` are Line2D properties (colour,
    width, label, style: matplotlib leaves them untyped)."""
    tt, yy = _envelope(*_pair(t, y))
    ax.plot(tt, yy, *args, **kwargs)


def _no_data(ax: Axes, what: str = "no data") -> None:
    ax.text(0.5, 0.5, what, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _rmse(err: np.ndarray) -> float:
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err**2))) if len(err) else math.nan


def _save(fig: Figure, out: PathLike) -> Path:
    """Write ``fig`` as PNG atomically (replacing an older figure) and free it."""
    path = Path(out)
    try:
        with atomic_output(path, force=True) as tmp:
            fig.savefig(tmp, format="png", dpi=fig.dpi)
    finally:
        plt.close(fig)
    return path


def _figure(rows: int, cols: int, size: tuple[float, float], sharex: bool = False,
            gridspec_kw: dict[str, object] | None = None) -> tuple[Figure, NDArray[np.object_]]:
    """A figure and its (rows, cols) array of Axes (``plt.subplots``' defaults for the rest)."""
    fig, axes = plt.subplots(rows, cols, figsize=size, dpi=DPI, squeeze=False, sharex=sharex,
                             gridspec_kw=gridspec_kw)
    return fig, axes


def _name_recording(fig: Figure, recording: str) -> None:
    """Write the recording's name into the figure itself: a PNG copied out of its report still
    says what data it shows."""
    if recording:
        fig.text(0.995, 0.003, f"recording: {recording}", ha="right", va="bottom", fontsize=7, color="0.3")


# -- the paper's figures ---------------------------------------------------------------------


def fig_battery_filter(
    t: Series,
    raw_battery_v: Series,
    filtered_v: Series,
    out: PathLike,
    pwm_t: Series = None,
    pwm: Series = None,
    recording: str = "",
) -> Path:
    """Paper Fig. 1 (and Fig. 2 below it when ``pwm`` is given).

    ``raw_battery_v`` is the ADC voltage with the divider undone (V at the battery), including
    the ESC-induced modulation; ``filtered_v`` the filter output on the same time base ``t`` (s).
    Shows why the filter is needed: the raw signal swings by volts while its mean sags slowly.
    """
    with_pwm = pwm is not None and len(_arr(pwm)) > 0
    fig, axes = _figure(2 if with_pwm else 1, 1, (8.0, 6.0 if with_pwm else 3.6), sharex=True)
    ax = axes[0, 0]
    tr, vr = _pair(t, raw_battery_v)
    if len(tr):
        _line(ax, tr, vr, color="0.65", lw=0.6, label="battery voltage (raw, divider undone)")
        _line(ax, t, filtered_v, color="C0", lw=1.6, label="digital filter output")
        ax.legend(loc="lower left", fontsize=8)
    else:
        _no_data(ax)
    ax.set_ylabel("voltage (V)")
    ax.set_title("Fig. 1: battery voltage and output of the digital filter")
    ax.grid(alpha=0.3)
    if with_pwm:
        ax2 = axes[1, 0]
        pt = _arr(pwm_t) if pwm_t is not None else _arr(t)
        _line(ax2, pt, pwm, color="C1", lw=1.0, drawstyle="steps-post")
        ax2.set_ylabel("PWM level")
        ax2.set_title(f"Fig. 2: the applied PWM command, {describe_command(pt, pwm)}")
        ax2.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


#: A command level held at least this long counts as a step (a 50 Hz ramp or chirp changes
#: every 20 ms; the bundled staircases hold each level 2-3 s, random steps about 1 s).
HELD_STEP_S = 0.2


def describe_command(t: Series, pwm: Series) -> str:
    """What a PWM command is, in words a title can carry ("held in 27 steps between 0.050 and
    0.100", "ramps between ...", "varying between ..."), so that a figure says what its data
    is rather than what the paper's figure of the same number showed."""
    tt, p = _pair(t, pwm)
    if len(p) < 2:
        return "no command recorded"
    span = f"between {float(p.min()):.3f} and {float(p.max()):.3f}"
    change = np.flatnonzero(np.diff(p) != 0.0) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(p) - 1]])
    held = tt[ends] - tt[starts]
    if len(held) and float(np.median(held)) >= HELD_STEP_S:
        return f"held in {int(np.sum(held >= HELD_STEP_S))} steps {span}"
    # a ramp keeps its direction for seconds: the direction of 0.5 s means rarely reverses
    dt = float(np.median(np.diff(tt))) if len(tt) > 1 else 0.0
    block = max(1, int(round(0.5 / dt))) if dt > 0 else 1
    n = len(p) // block
    means = p[: n * block].reshape(n, block).mean(axis=1) if n else p
    d = np.sign(np.diff(means))
    d = d[d != 0]
    reversals = int(np.sum(d[1:] != d[:-1])) if len(d) > 1 else 0
    if len(d) and reversals <= 0.1 * len(d):
        return f"ramps {span}"
    return f"a varying command {span}"


def fig_ramp(t: Series, pwm: Series, speed: Series, out: PathLike, recording: str = "") -> Path:
    """The paper's Figs. 5-6 for any recording: its PWM command and the angular speed it
    produces (rotation starts near 0.055). The titles say what the command is (steps, ramps),
    since the paper's "sweeping the applicable range" would mislabel a staircase."""
    fig, axes = _figure(2, 1, (8.0, 5.6), sharex=True)
    _line(axes[0, 0], t, pwm, color="C1", lw=1.0)
    axes[0, 0].set_ylabel("PWM level")
    axes[0, 0].set_title(f"PWM command: {describe_command(t, pwm)}", fontsize=10)
    _line(axes[1, 0], t, speed, color="C0", lw=1.0)
    axes[1, 0].set_ylabel("angular speed (rad/s)")
    axes[1, 0].set_title("measured angular speed", fontsize=10)
    axes[1, 0].set_xlabel("time (s)")
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


def fig_training(history_train: Series, history_val: Series, best_epoch: int | None, out: PathLike) -> Path:
    """Paper Fig. 12: training and validation cost per epoch (log scale), best epoch marked.

    Index ``k`` of each history is epoch ``k``; the validation curve shows where early stopping
    chose the weights (its minimum).
    """
    fig, axes = _figure(1, 1, (7.0, 4.0))
    ax = axes[0, 0]
    tiny = np.finfo(float).tiny
    drew = False
    for hist, label, color in ((history_train, "training cost", "C0"), (history_val, "validation cost", "C3")):
        h = _arr(hist)
        if len(h) == 0:
            continue
        epochs = np.arange(len(h))
        ok = np.isfinite(h)
        ax.semilogy(epochs[ok], np.maximum(h[ok], tiny), color=color, lw=1.4, label=label)
        drew = drew or bool(ok.any())
    hv = _arr(history_val)
    if best_epoch is not None and best_epoch >= 0:
        ax.axvline(best_epoch, color="k", ls="--", lw=1.0, label=f"best validation (epoch {best_epoch})")
        if best_epoch < len(hv) and np.isfinite(hv[best_epoch]):
            ax.plot([best_epoch], [max(hv[best_epoch], tiny)], "ko", ms=5)
    if drew:
        ax.legend(fontsize=8)
    else:
        _no_data(ax, "no cost history")
    ax.set_xlabel("epoch")
    ax.set_ylabel("cost J")
    ax.set_title("Fig. 12: training and validation cost per epoch (learning curve)")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return _save(fig, out)


def fig_validation(
    t: Series,
    pwm: Series,
    voltage: Series,
    speed_measured: Series,
    speed_predicted: Series,
    out: PathLike,
    title: str = "",
) -> Path:
    """Paper Fig. 13, 2x2: PWM (top left), filtered voltage (bottom left), predicted vs
    measured speed (top right) and their difference (bottom right), on one time base ``t``."""
    fig, axes = _figure(2, 2, (11.0, 6.4), sharex=True)
    _line(axes[0, 0], t, pwm, color="C1", lw=0.9)
    axes[0, 0].set_ylabel("PWM level")
    axes[0, 0].set_title("PWM input")
    _line(axes[1, 0], t, voltage, color="C0", lw=1.2)
    axes[1, 0].set_ylabel("voltage (V)")
    axes[1, 0].set_title("filtered battery voltage")
    _line(axes[0, 1], t, speed_measured, color="0.3", lw=1.0, label="measured")
    _line(axes[0, 1], t, speed_predicted, color="C3", lw=1.0, label="predicted (model)")
    axes[0, 1].set_ylabel("angular speed (rad/s)")
    axes[0, 1].set_title("angular speed")
    axes[0, 1].legend(fontsize=8, loc="best")
    m, p = _arr(speed_measured), _arr(speed_predicted)
    err = m - p if len(m) == len(p) else np.array([])
    if len(err) and len(err) == len(_arr(t)):
        _line(axes[1, 1], t, err, color="C2", lw=0.9)
        axes[1, 1].set_title(f"error measured - predicted (RMSE {_rmse(err):.1f} rad/s)")
    else:
        _no_data(axes[1, 1])
        axes[1, 1].set_title("error measured - predicted")
    axes[1, 1].set_ylabel("error (rad/s)")
    for ax in axes[1, :]:
        ax.set_xlabel("time (s)")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.suptitle(f"Fig. 13: model validation{': ' + title if title else ''}", fontsize=10)
    fig.tight_layout()
    return _save(fig, out)


def fig_prediction_scatter(measured: Series, predicted: Series, out: PathLike, recording: str = "") -> Path:
    """Predicted vs measured speed with the identity line: bias and saturation show at a glance."""
    m, p = _pair(measured, predicted)
    fig, axes = _figure(1, 1, (5.2, 5.0))
    ax = axes[0, 0]
    if len(m):
        step = max(1, len(m) // MAX_SCATTER_POINTS)
        ax.plot(m[::step], p[::step], ".", ms=2, alpha=0.4, color="C0", rasterized=True)
        lo, hi = float(min(m.min(), p.min())), float(max(m.max(), p.max()))
        if hi <= lo:
            lo, hi = lo - 1.0, hi + 1.0
        ax.plot([lo, hi], [lo, hi], "k--", lw=1.0, label="predicted = measured")
        ss = float(np.sum((m - m.mean()) ** 2))
        r2 = 1.0 - float(np.sum((m - p) ** 2)) / ss if ss > 0 else math.nan
        ax.set_title(f"RMSE {_rmse(m - p):.1f} rad/s, R² {r2:.4f}, n = {len(m)}", fontsize=9)
        ax.legend(fontsize=8, loc="upper left")
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
    else:
        _no_data(ax)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("measured speed (rad/s)")
    ax.set_ylabel("predicted speed (rad/s)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


def fig_band_error(bands: Sequence[dict[str, float]], out: PathLike, recording: str = "") -> Path:
    """Speed error (RMSE) per band of command frequency: the paper's observation that the model
    degrades as the command gets faster, as bars labelled with their share of the speed range."""
    fig, axes = _figure(1, 1, (6.4, 3.8))
    ax = axes[0, 0]
    if bands:
        labels = [f"{b['low_hz']:.1f}-{b['high_hz']:.1f}" for b in bands]
        rmse = [float(b["rmse_rad_s"]) for b in bands]
        bars = ax.bar(labels, rmse, color="C0")
        for bar, b in zip(bars, bands, strict=True):
            ax.annotate(f"{b['rmse_percent_of_range']:.2f} %", (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                        ha="center", va="bottom", fontsize=8)
        ax.set_ylim(0, max(rmse) * 1.18 if max(rmse) > 0 else 1.0)
    else:
        _no_data(ax, "not a chirp-like recording: no frequency bands")
    ax.set_xlabel("command frequency band (Hz)")
    ax.set_ylabel("RMSE (rad/s)")
    ax.set_title("speed error per command frequency (label: % of the speed range)", fontsize=10)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


def fig_compare(
    t: Series,
    pwm: Series,
    speed_measured: Series,
    predictions: Sequence[tuple[str, Series]],
    out: PathLike,
    recording: str = "",
) -> Path:
    """Several models on one recording, on one time base ``t``: the PWM input (top), the
    measured speed with every model's prediction (middle) and each model's error (bottom), so
    where one kind beats another shows at a glance. ``predictions``: (label, speed rad/s)."""
    fig, axes = _figure(3, 1, (11.0, 8.0), sharex=True, gridspec_kw={"height_ratios": [1, 2, 1.4]})
    _line(axes[0, 0], t, pwm, color="C1", lw=0.9)
    axes[0, 0].set_ylabel("PWM level")
    axes[0, 0].set_title("PWM input")
    # measured as a wide grey band beneath the models: a model that follows it cannot hide it
    _line(axes[1, 0], t, speed_measured, color="0.6", lw=3.0, label="measured", zorder=1)
    m = _arr(speed_measured)
    colors = ("C3", "C0", "C2", "C4", "C5", "C6")
    for k, (label, pred) in enumerate(predictions):
        color = colors[k % len(colors)]
        _line(axes[1, 0], t, pred, color=color, lw=0.9, label=label)
        err = m - _arr(pred)
        _line(axes[2, 0], t, err, color=color, lw=0.8, label=f"{label}: RMSE {_rmse(err):.1f} rad/s")
    axes[1, 0].set_ylabel("angular speed (rad/s)")
    axes[1, 0].set_title("measured and predicted speed")
    axes[1, 0].legend(fontsize=8, loc="best")
    axes[2, 0].set_ylabel("error (rad/s)")
    axes[2, 0].set_title("error measured - predicted")
    axes[2, 0].legend(fontsize=8, loc="best")
    axes[2, 0].set_xlabel("time (s)")
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.suptitle(f"models side by side{': ' + recording if recording else ''}", fontsize=10)
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


def thrust_error(measured_n: Series, predicted_n: Series) -> tuple[float, float, float]:
    """(RMSE N, measured thrust range N, RMSE in % of that range) of predicted thrust, over the
    samples where both are finite: the figures ``fig_thrust`` states."""
    m, p = _arr(measured_n), _arr(predicted_n)
    if len(m) != len(p):
        raise ValueError(f"measured and predicted thrust differ in length ({len(m)} vs {len(p)})")
    ok = np.isfinite(m) & np.isfinite(p)
    if not ok.any():
        return math.nan, math.nan, math.nan
    rmse = _rmse(m[ok] - p[ok])
    span = float(np.ptp(m[ok]))
    return rmse, span, 100.0 * rmse / span if span > 0 else math.nan


def thrust_error_text(measured_n: Series, predicted_n: Series) -> str:
    """"RMSE 0.031 N (1.2 % of the 2.53 N thrust range)": the figure's title and a report's
    headline say it in the same words."""
    rmse, span, pct = thrust_error(measured_n, predicted_n)
    return f"RMSE {rmse:.3f} N ({pct:.1f} % of the {span:.2f} N thrust range)"


def fig_thrust(
    t: Series,
    thrust_measured: Series,
    thrust_predicted: Series,
    out: PathLike,
    recording: str = "",
    coefficient: float | None = None,
) -> Path:
    """Thrust, the product's output, against the load cell: measured and predicted (b w^2 of
    the predicted speed) over time (top) and the error measured - predicted in N (bottom, with
    its RMSE in N and in % of the measured thrust range in the title)."""
    t_, m, p = _arr(t), _arr(thrust_measured), _arr(thrust_predicted)
    fig, axes = _figure(2, 1, (9.0, 5.8), sharex=True)
    top, bottom = axes[0, 0], axes[1, 0]
    b = f", b = {coefficient:.4g} N s²/rad²" if coefficient is not None else ""
    if len(t_) and len(m) == len(p) == len(t_):
        _line(top, t_, m, color="0.55", lw=2.4, label="measured (load cell)")
        _line(top, t_, p, color="C3", lw=1.0, label=f"predicted b·ω²{b}")
        top.legend(fontsize=8, loc="best")
        err = m - p
        _line(bottom, t_, err, color="C2", lw=0.9)
        bottom.axhline(0.0, color="k", lw=0.6)
        bottom.set_title(f"thrust error measured - predicted: {thrust_error_text(m, p)}", fontsize=10)
    else:
        _no_data(top)
        _no_data(bottom)
        bottom.set_title("thrust error measured - predicted", fontsize=10)
    top.set_ylabel("thrust (N)")
    top.set_title(f"{recording + ': ' if recording else ''}measured and predicted thrust", fontsize=10)
    bottom.set_ylabel("error (N)")
    bottom.set_xlabel("time (s)")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


# -- discrepancy figures ---------------------------------------------------------------------


def _edges(x: np.ndarray, bins: int) -> np.ndarray:
    """``bins`` equal bins over the data; a constant (or empty) input gets a small range."""
    if len(x) == 0:
        return np.linspace(-0.5, 0.5, bins + 1)
    lo, hi = float(x.min()), float(x.max())
    if hi - lo <= 1e-12 * max(1.0, abs(lo)):
        pad = max(abs(lo) * 0.01, 1e-6)
        lo, hi = lo - pad, hi + pad
    return np.linspace(lo, hi, bins + 1)


def binned_mean_2d(
    x: Series, y: Series, z: Series, bins: tuple[int, int] = (20, 16), min_count: int = 5
) -> tuple[np.ndarray, np.ndarray, np.ma.MaskedArray, np.ndarray]:
    """(x edges, y edges, mean of z per bin masked where fewer than ``min_count``, counts).

    Arrays are (len(x edges)-1, len(y edges)-1); non-finite samples are dropped.
    """
    x, y, z = _arr(x), _arr(y), _arr(z)
    n = min(len(x), len(y), len(z))
    x, y, z = x[:n], y[:n], z[:n]
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    x, y, z = x[ok], y[ok], z[ok]
    ex, ey = _edges(x, bins[0]), _edges(y, bins[1])
    counts, _, _ = np.histogram2d(x, y, bins=(ex, ey))
    sums, _, _ = np.histogram2d(x, y, bins=(ex, ey), weights=z)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / counts
    mask = (counts < max(1, min_count)) | ~np.isfinite(mean)
    return ex, ey, np.ma.masked_array(np.where(mask, 0.0, mean), mask=mask), counts


def fig_disagreement_map(
    pwm: Series,
    dpwm_dt: Series,
    residual: Series,
    out: PathLike,
    voltage: Series = None,
    *,
    bins: tuple[int, int] = (20, 16),
    min_count: int = 5,
) -> Path:
    """Where the model is wrong: mean residual (measured - model, rad/s) per PWM level x PWM rate.

    A diverging colormap centred at 0 separates over- from under-prediction; bins with fewer than
    ``min_count`` samples are left blank so that sparse corners do not look meaningful. Fast
    commands (large |dPWM/dt|) with a one-signed residual point at dynamics (lag, delay); a
    residual along PWM at rate 0 at static effects (deadband). With ``voltage`` a second panel
    shows residual vs battery voltage (sag/discharge not captured).
    """
    with_v = voltage is not None and len(_arr(voltage)) > 0
    fig, axes = _figure(1, 2 if with_v else 1, (12.0 if with_v else 7.0, 4.8))
    ax = axes[0, 0]
    ex, ey, mean, counts = binned_mean_2d(pwm, dpwm_dt, residual, bins, min_count)
    finite = mean.compressed()
    vmax = float(np.max(np.abs(finite))) if finite.size else 0.0
    vmax = vmax if vmax > 0 and math.isfinite(vmax) else 1.0
    mesh = ax.pcolormesh(ex, ey, mean.T, cmap="RdBu_r", norm=Normalize(-vmax, vmax), shading="flat")
    fig.colorbar(mesh, ax=ax, label="mean residual measured - model (rad/s)")
    if not finite.size:
        _no_data(ax, f"no bin with ≥ {min_count} samples")
    ax.set_xlabel("PWM level")
    ax.set_ylabel("PWM rate of change (1/s)")
    ax.set_title(f"disagreement map (n = {int(counts.sum())}, blank: < {min_count} samples)", fontsize=10)
    if with_v:
        ax2 = axes[0, 1]
        v, r = _arr(voltage), _arr(residual)
        n = min(len(v), len(r))
        v, r = v[:n], r[:n]
        ok = np.isfinite(v) & np.isfinite(r)
        v, r = v[ok], r[ok]
        if len(v):
            step = max(1, len(v) // MAX_SCATTER_POINTS)
            ax2.plot(v[::step], r[::step], ".", ms=2, alpha=0.3, color="0.4", rasterized=True)
            ev = _edges(v, 15)
            idx = np.clip(np.digitize(v, ev) - 1, 0, len(ev) - 2)
            cnt = np.bincount(idx, minlength=len(ev) - 1)
            sm = np.bincount(idx, weights=r, minlength=len(ev) - 1)
            keep = cnt >= max(1, min_count)
            centres = 0.5 * (ev[:-1] + ev[1:])
            ax2.plot(centres[keep], sm[keep] / cnt[keep], "o-", color="C3", lw=1.5, label="binned mean")
            ax2.legend(fontsize=8)
        else:
            _no_data(ax2)
        ax2.axhline(0.0, color="k", lw=0.8)
        ax2.set_xlabel("battery voltage (V)")
        ax2.set_ylabel("residual (rad/s)")
        ax2.set_title("residual vs battery voltage", fontsize=10)
        ax2.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, out)


#: How the before/after figure draws each line: measured as a wide grey band beneath the models,
#: so that a model that follows it closely (the point of adding an effect) cannot hide it;
#: before dashed red, after solid blue, each distinct in colour and style.
class LineStyle(TypedDict):
    """Line2D properties of one line of the before/after figure."""

    color: str
    lw: float
    ls: str
    zorder: int


BEFORE_AFTER_STYLE: dict[str, LineStyle] = {
    "measured": {"color": "0.55", "lw": 3.2, "ls": "-", "zorder": 2},
    "model before": {"color": "C3", "lw": 1.1, "ls": "--", "zorder": 3},
    "model after": {"color": "C0", "lw": 1.1, "ls": "-", "zorder": 4},
}


def _fit_axes(ax: Axes, t: np.ndarray, *series: np.ndarray) -> None:
    """x limits = the recording's time span; y limits = the finite values of ``series`` with a
    5 % margin (shaded windows or an empty series never widen them)."""
    tt = t[np.isfinite(t)]
    if len(tt) and tt.max() > tt.min():
        ax.set_xlim(float(tt.min()), float(tt.max()))
    vals = np.concatenate([s[np.isfinite(s)] for s in series]) if series else np.zeros(0)
    if len(vals):
        lo, hi = float(vals.min()), float(vals.max())
        pad = 0.05 * (hi - lo) if hi > lo else max(1.0, 0.05 * abs(hi))
        ax.set_ylim(lo - pad, hi + pad)


def fig_before_after(
    t: Series,
    measured: Series,
    before: Series,
    after: Series,
    out: PathLike,
    windows: Iterable[tuple[float, float]] = (),
    recording: str = "",
) -> Path:
    """Model error before vs after adding an effect, disagreement windows (t0, t1 in s) shaded.

    Top: measured speed (a grey band the models are drawn over) and both models; bottom: both
    errors with their RMSE, so the reader sees that the error shrank where the windows are and
    did not grow elsewhere. The title and a footer name the recording.
    """
    t_, m = _arr(t), _arr(measured)
    b, a = _arr(before), _arr(after)
    fig, axes = _figure(2, 1, (9.0, 6.0), sharex=True)
    top, bottom = axes[0, 0], axes[1, 0]
    for label, y in (("measured", m), ("model before", b), ("model after", a)):
        _line(top, t_, y, label=label, **BEFORE_AFTER_STYLE[label])
    top.set_ylabel("angular speed (rad/s)")
    _fit_axes(top, t_, m, b, a)
    if len(m) == len(b) == len(a) == len(t_) and len(t_):
        eb, ea = m - b, m - a
        _line(bottom, t_, eb, label=f"before (RMSE {_rmse(eb):.1f} rad/s)",
              **BEFORE_AFTER_STYLE["model before"])
        _line(bottom, t_, ea, label=f"after (RMSE {_rmse(ea):.1f} rad/s)", **BEFORE_AFTER_STYLE["model after"])
        bottom.legend(fontsize=8, loc="best")
        _fit_axes(bottom, t_, eb, ea, np.zeros(1))
    else:
        _no_data(bottom)
    bottom.axhline(0.0, color="k", lw=0.6)
    bottom.set_ylabel("error measured - model (rad/s)")
    bottom.set_xlabel("time (s)")
    n_windows = 0
    for w in windows:
        w0, w1 = float(w[0]), float(w[1])
        if not (math.isfinite(w0) and math.isfinite(w1)):
            continue
        n_windows += 1
        for ax in (top, bottom):
            ax.axvspan(min(w0, w1), max(w0, w1), color="gold", alpha=0.25, lw=0, zorder=1,
                       label="disagreement window" if n_windows == 1 and ax is top else None)
    if top.lines:
        top.legend(fontsize=8, loc="best")
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    top.set_title(f"{recording + ': ' if recording else ''}model before and after adding the effect "
                  f"({n_windows} window(s) shaded)", fontsize=10)
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


# -- index.html ------------------------------------------------------------------------------


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not math.isfinite(v):
            return str(v)
        return f"{v:.4g}" if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5) else f"{v:.4f}".rstrip("0").rstrip(".")
    if isinstance(value, (list, tuple, np.ndarray)):
        return ", ".join(_cell(v) for v in list(value)[:20]) + (", ..." if len(value) > 20 else "")
    return str(value)


def _td(value: object) -> str:
    """A table cell: numbers right-aligned (digits line up), text left-aligned (it reads)."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    return ('<td class="n">' if number else "<td>") + html.escape(_cell(value)) + "</td>"


def _table_html(caption: str, rows: Sequence[Mapping[str, object]]) -> str:
    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    out = [f'<div class="table"><table>\n<caption>{html.escape(str(caption))}</caption>']
    out.append("<tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in columns) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(_td(row.get(c)) for c in columns) + "</tr>")
    out.append("</table></div>")
    return "\n".join(out)


def _href(report_dir: Path, figure: str) -> str:
    p = Path(figure)
    if p.is_absolute():
        try:
            p = p.resolve().relative_to(report_dir.resolve())
        except ValueError:
            pass  # outside the report: keep the absolute path
    return quote(p.as_posix(), safe="/:")


_CSS = """body{font-family:sans-serif;max-width:1200px;margin:1em auto;padding:0 1em;color:#222}
figure{margin:1.5em 0}img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.9em;color:#444}
table{border-collapse:collapse;margin:1em 0;font-size:.9em}caption{text-align:left;font-weight:bold}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}th{background:#f3f3f3}
td.n{text-align:right}
dl.headline{display:grid;grid-template-columns:max-content auto;gap:.2em 1em;margin:.6em 0;
background:#f6f8fa;border:1px solid #dde;padding:.6em 1em}dl.headline dt{font-weight:bold}dl.headline dd{margin:0}
p.note{color:#7a4b00}div.table{overflow-x:auto}nav ol{margin:.3em 0;font-size:.9em}"""


def _headline_html(headline: Sequence[tuple[str, str]]) -> str:
    items = "".join(f"<dt>{html.escape(str(k))}</dt><dd>{html.escape(str(v))}</dd>" for k, v in headline)
    return f'<dl class="headline">{items}</dl>'


def _jsonable(value: object) -> JsonValue:
    """Plain JSON values (NaN and infinity as None, numpy scalars and arrays as numbers/lists)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in list(value)]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(float(value)) else None
    return value if value is None or isinstance(value, str) else str(value)


#: Written beside every report's index.html: its title, headline, figures and tables as JSON, so
#: that an index of several reports (``write_reports_index``) reads numbers, not HTML.
REPORT_JSON = "report.json"


class ReportHeadline(TypedDict):
    """One headline figure of ``report.json``."""

    label: str
    text: str


class ReportFigure(TypedDict):
    """One figure of ``report.json``: its file relative to the report, and its caption."""

    file: str
    caption: str


class ReportTable(TypedDict):
    """One table of ``report.json``: its caption and rows (column -> plain JSON value)."""

    caption: str
    rows: list[dict[str, JsonValue]]


class ReportJson(TypedDict, total=False):
    """What ``report.json`` holds. A file of an older version may lack any key: readers use ``get``."""

    title: str
    headline: list[ReportHeadline]
    notes: list[str]
    figures: list[ReportFigure]
    tables: list[ReportTable]


def write_index(
    report_dir: PathLike,
    title: str,
    figures: Sequence[tuple[str, str]],
    tables: Sequence[tuple[str, Sequence[Mapping[str, object]]]] = (),
    headline: Sequence[tuple[str, str]] = (),
    notes: Sequence[str] = (),
) -> Path:
    """Write ``report_dir/index.html``: the headline figures (label, text) a reader needs first,
    notes (what is missing and why), a list of the figures, the tables of figures of merit,
    then each figure with its caption; and ``report.json`` (``REPORT_JSON``) with the same
    content. ``figures`` are (file name relative to the report, caption); the first is the
    report's main figure (the thumbnail of an index of reports). All text is HTML-escaped,
    since captions carry file paths that may contain ``<`` or ``&``."""
    d = Path(report_dir)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(str(title))}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(str(title))}</h1>",
    ]
    if headline:
        parts.append(_headline_html(headline))
    parts += [f'<p class="note">{html.escape(str(n))}</p>' for n in notes]
    if len(figures) > 1:
        links = "".join(f'<li><a href="#fig-{k}">{html.escape(str(caption))}</a></li>'
                        for k, (_, caption) in enumerate(figures))
        parts.append(f'<nav><b>figures</b><ol>{links}</ol></nav>')
    for caption, rows in tables:
        parts.append(_table_html(caption, list(rows)))
    for k, (name, caption) in enumerate(figures):
        src = html.escape(_href(d, str(name)), quote=True)
        alt = html.escape(str(caption), quote=True)
        parts.append(f'<figure id="fig-{k}"><img src="{src}" alt="{alt}">'
                     f"<figcaption>{html.escape(str(caption))}</figcaption></figure>")
    parts.append("</body></html>\n")
    summary = {
        "title": str(title),
        "headline": [{"label": str(k), "text": str(v)} for k, v in headline],
        "notes": [str(n) for n in notes],
        "figures": [{"file": _href(d, str(name)), "caption": str(caption)} for name, caption in figures],
        "tables": [{"caption": str(caption), "rows": _jsonable(list(rows))} for caption, rows in tables],
    }
    with atomic_output(d / REPORT_JSON, force=True) as tmp:
        tmp.write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    path = d / "index.html"
    with atomic_output(path, force=True) as tmp:
        tmp.write_text("\n".join(parts), encoding="utf-8")
    return path


# -- an index of several reports (the demo's) ---------------------------------------------------


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def headline_from_tables(tables: Sequence[ReportTable]) -> list[tuple[str, str]]:
    """Headline of a report that states none (the discrepancy report, discrepancy/results.py),
    from its tables as ``report.json`` holds them, found by caption: the effects added ("added
    ..."), those not added ("not added ..." or "considered ..."), each with its status where the
    table has one, and the holdout RMSE before and after ("the gap"). Others are left out."""
    def effects(rows: list[dict[str, JsonValue]], heading: str) -> str:
        """Effect names, each with its status less what the heading already says."""
        out = []
        for r in rows:
            status = str(r.get("status") or "")
            if status.startswith("added (") and status.endswith(")"):  # "added (new in ...)": under "added"
                status = status[len("added ("):-1]
            if status.endswith(heading):  # "considered, not added" under "not added"
                status = ""
            out.append(str(r.get("effect")) + (f" ({status})" if status else ""))
        return ", ".join(out)

    out: list[tuple[str, str]] = []
    for table in tables:
        caption, rows = str(table.get("caption", "")), table.get("rows") or []
        if caption.startswith("added"):
            out.append(("effects added", effects(rows, "added") or "none"))
        elif caption.startswith(("not added", "considered")) and rows:
            out.append(("not added", effects(rows, "not added")))
        elif caption == "the gap" and rows:
            before, after = _number(rows[0].get("holdout RMSE before")), _number(rows[0].get("after"))
            if before is not None and after is not None:
                out.append(("holdout RMSE before → after", f"{before:.2f} → {after:.2f} rad/s"))
    return out


def read_report(report_dir: PathLike) -> ReportJson | None:
    """A report's ``report.json`` (None when the folder holds no report of this version)."""
    path = Path(report_dir) / REPORT_JSON
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


_INDEX_CSS = """.step{display:flex;gap:1.2em;align-items:flex-start;border-top:1px solid #ddd;padding:1em 0}
.step>a{flex:none}.step img{width:380px}.step h2{margin:0 0 .2em;font-size:1.15em}.sub{color:#555;margin:0 0 .5em}"""


def write_reports_index(
    directory: PathLike,
    steps: Sequence[tuple[str, str]] | None = None,
    title: str = "bldc_propulsion reports",
) -> Path:
    """Write ``directory/index.html``: one row per report, with a thumbnail of its main figure
    (linking to the report) and its headline numbers, so that a reader sees every step's result
    at a glance. ``steps``: (sub-folder, what the step does) in order; default every sub-folder
    holding a report, by name. A step whose report is missing says so."""
    d = Path(directory)
    if steps is None:
        steps = [(p.name, p.name) for p in sorted(d.iterdir()) if (p / REPORT_JSON).is_file()]
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(title)}</title>",
        f"<style>{_CSS}\n{_INDEX_CSS}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
    ]
    for folder, what in steps:
        rep = read_report(d / folder)
        link = html.escape(quote(f"{folder}/index.html", safe="/"), quote=True)
        if rep is None:
            older = (d / folder / "index.html").is_file()  # a report of a version before report.json
            heading = f'<a href="{link}">{html.escape(what)}</a>' if older else html.escape(what)
            why = ("its report has no report.json (an older version wrote it): no headline" if older
                   else f"no report in {folder}/ (the step did not run or failed)")
            parts.append(f'<section class="step"><div><h2>{heading}</h2><p class="sub">{html.escape(why)}</p>'
                         "</div></section>")
            continue
        figs = rep.get("figures") or []
        thumb = ""
        if figs:
            src = html.escape(quote(f"{folder}/{figs[0]['file']}", safe="/:"), quote=True)
            alt = html.escape(str(figs[0].get("caption", "")), quote=True)
            thumb = f'<a href="{link}"><img src="{src}" alt="{alt}" title="{alt}"></a>'
        headline = [(h["label"], h["text"]) for h in rep.get("headline") or []] \
            or headline_from_tables(rep.get("tables") or [])
        parts.append(
            f'<section class="step">{thumb}<div><h2><a href="{link}">{html.escape(what)}</a></h2>'
            f'<p class="sub">{html.escape(str(rep.get("title", "")))} · {len(figs)} figure(s)</p>'
            + (_headline_html(headline) if headline else "") + "</div></section>")
    parts.append("</body></html>\n")
    path = d / "index.html"
    with atomic_output(path, force=True) as tmp:
        tmp.write_text("\n".join(parts), encoding="utf-8")
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m bldc_propulsion.training.report demo-index DIR [FOLDER=TEXT ...]``: the index
    of the reports in DIR (scripts/demo.sh writes demo/index.html with it)."""
    import argparse

    prog = "python -m bldc_propulsion.training.report demo-index"
    p = argparse.ArgumentParser(prog=prog, description="write DIR/index.html: a thumbnail and the headline "
                                                       "numbers of each report in DIR")
    p.add_argument("directory", metavar="DIR")
    p.add_argument("steps", nargs="*", metavar="FOLDER=TEXT",
                   help="the reports in order, each a sub-folder of DIR and what its step does "
                        "(default: every sub-folder holding a report)")
    p.add_argument("--title", default="bldc_propulsion reports", help="the page's title")
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] != "demo-index":  # one subcommand for now; the name says what it writes
        print(f"usage: {prog} DIR [FOLDER=TEXT ...] [--title TITLE]", file=sys.stderr)
        return 2
    args = p.parse_intermixed_args(argv[1:])  # --title before or after the steps
    try:
        d = Path(args.directory)
        if not d.is_dir():
            raise BadInputError(f"{d}: not a directory")
        steps = []
        for item in args.steps:
            folder, sep, what = item.partition("=")
            if not sep or not folder.strip():
                raise BadInputError(f"{item!r}: expected FOLDER=TEXT")
            steps.append((folder.strip(), what.strip() or folder.strip()))
    except BadInputError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(write_reports_index(d, steps or None, title=args.title))
    return 0


if __name__ == "__main__":
    sys.exit(main())
