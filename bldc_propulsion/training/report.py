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
import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

import matplotlib

matplotlib.use("Agg")  # before pyplot: no display needed, same output everywhere

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import Normalize  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from ..atomic import atomic_output  # noqa: E402

DPI = 90
MAX_LINE_POINTS = 4000  #: per plotted line; longer signals are min/max-enveloped
MAX_SCATTER_POINTS = 20000
PathLike = str | os.PathLike[str]

# -- helpers ---------------------------------------------------------------------------------


def _arr(x: Any) -> np.ndarray:
    return np.asarray(x if x is not None else [], dtype=float).ravel()


def _pair(t: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
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
    for a, b in zip(edges[:-1], edges[1:]):
        if b <= a:
            continue
        seg = y[a:b]
        i, j = int(np.argmin(seg)), int(np.argmax(seg))
        for k in sorted((i, j)):
            tt.append(t[a + k])
            yy.append(seg[k])
    return np.asarray(tt), np.asarray(yy)


def _line(ax: Any, t: Any, y: Any, *args: Any, **kwargs: Any) -> None:
    tt, yy = _envelope(*_pair(t, y))
    ax.plot(tt, yy, *args, **kwargs)


def _no_data(ax: Any, what: str = "no data") -> None:
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


def _figure(rows: int, cols: int, size: tuple[float, float], **kwargs: Any) -> tuple[Figure, Any]:
    fig, axes = plt.subplots(rows, cols, figsize=size, dpi=DPI, squeeze=False, **kwargs)
    return fig, axes


def _name_recording(fig: Figure, recording: str) -> None:
    """Write the recording's name into the figure itself: a PNG copied out of its report still
    says what data it shows."""
    if recording:
        fig.text(0.995, 0.003, f"recording: {recording}", ha="right", va="bottom", fontsize=7, color="0.3")


# -- the paper's figures ---------------------------------------------------------------------


def fig_battery_filter(
    t: Any,
    raw_battery_v: Any,
    filtered_v: Any,
    out: PathLike,
    pwm_t: Any = None,
    pwm: Any = None,
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
        ax2.set_title("Fig. 2: the applied PWM signal")
        ax2.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


def fig_ramp(t: Any, pwm: Any, speed: Any, out: PathLike, recording: str = "") -> Path:
    """Paper Figs. 5-6: PWM sweep and the angular speed it produces (start of rotation ~0.055)."""
    fig, axes = _figure(2, 1, (8.0, 5.6), sharex=True)
    _line(axes[0, 0], t, pwm, color="C1", lw=1.0)
    axes[0, 0].set_ylabel("PWM level")
    axes[0, 0].set_title("Fig. 5: PWM signal sweeping the applicable range")
    _line(axes[1, 0], t, speed, color="C0", lw=1.0)
    axes[1, 0].set_ylabel("angular speed (rad/s)")
    axes[1, 0].set_title("Fig. 6: the corresponding angular speed")
    axes[1, 0].set_xlabel("time (s)")
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    _name_recording(fig, recording)
    return _save(fig, out)


def fig_training(history_train: Any, history_val: Any, best_epoch: int | None, out: PathLike) -> Path:
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
    ax.set_title("Fig. 12: decrease of the training and checking errors")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return _save(fig, out)


def fig_validation(
    t: Any,
    pwm: Any,
    voltage: Any,
    speed_measured: Any,
    speed_predicted: Any,
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


def fig_prediction_scatter(measured: Any, predicted: Any, out: PathLike, recording: str = "") -> Path:
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
        for bar, b in zip(bars, bands):
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
    t: Any,
    pwm: Any,
    speed_measured: Any,
    predictions: Sequence[tuple[str, Any]],
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
    _line(axes[1, 0], t, speed_measured, color="0.2", lw=1.4, label="measured")
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
    x: Any, y: Any, z: Any, bins: tuple[int, int] = (20, 16), min_count: int = 5
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
    pwm: Any,
    dpwm_dt: Any,
    residual: Any,
    out: PathLike,
    voltage: Any = None,
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
BEFORE_AFTER_STYLE: dict[str, dict[str, Any]] = {
    "measured": {"color": "0.55", "lw": 3.2, "ls": "-", "zorder": 2},
    "model before": {"color": "C3", "lw": 1.1, "ls": "--", "zorder": 3},
    "model after": {"color": "C0", "lw": 1.1, "ls": "-", "zorder": 4},
}


def _fit_axes(ax: Any, t: np.ndarray, *series: np.ndarray) -> None:
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
    t: Any,
    measured: Any,
    before: Any,
    after: Any,
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


def _cell(value: Any) -> str:
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


def _table_html(caption: str, rows: Sequence[dict[str, Any]]) -> str:
    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    out = [f'<table>\n<caption>{html.escape(str(caption))}</caption>']
    out.append("<tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in columns) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(_cell(row.get(c)))}</td>" for c in columns) + "</tr>")
    out.append("</table>")
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
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}th{background:#f3f3f3}"""


def write_index(
    report_dir: PathLike,
    title: str,
    figures: Sequence[tuple[str, str]],
    tables: Sequence[tuple[str, Sequence[dict[str, Any]]]] = (),
) -> Path:
    """Write ``report_dir/index.html``: the tables of figures of merit, then each figure with
    its caption. ``figures`` are (file name relative to the report, caption). All text is
    HTML-escaped, since captions carry file paths that may contain ``<`` or ``&``."""
    d = Path(report_dir)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{html.escape(str(title))}</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{html.escape(str(title))}</h1>",
    ]
    for caption, rows in tables:
        parts.append(_table_html(caption, list(rows)))
    for name, caption in figures:
        src = html.escape(_href(d, str(name)), quote=True)
        alt = html.escape(str(caption), quote=True)
        parts.append(f'<figure><img src="{src}" alt="{alt}">'
                     f"<figcaption>{html.escape(str(caption))}</figcaption></figure>")
    parts.append("</body></html>\n")
    path = d / "index.html"
    with atomic_output(path, force=True) as tmp:
        tmp.write_text("\n".join(parts), encoding="utf-8")
    return path
