"""Where an imported thrust-stand log's ESC command comes from when it is not the log's own
``ESC signal (µs)`` column, for ``import-csv``.

Stands log the command only when their own software sets it. When the ESC's own tool set it
(AutoQuad ESC32 utility, Sapog CLI), the stand's command column is empty and the command is
either another column of the same log (``--command-column``, in us, duty 0..1 or percent) or
another file with its own clock (``--command-from``: the AutoQuad ESC32 utility's CSV, which
logs the duty with the ESC's RPM at ~67 Hz).

A duty cycle is mapped to the PWM level an ESC with a linear throttle would need for it:
level = 0.05 + 0.05 x duty (duty 0 = 1 ms stop pulse, duty 1 = 2 ms full). The model only needs
a command that is monotonic in the drive; the mapping is stated in the import summary.

Two clocks are aligned by the one quantity both files log, the rotor speed: both are
resampled on a common grid and cross-correlated (normalised over the overlap of each lag, so a
lag is not preferred because it overlaps more); the offset is refused when the best
correlation is weak, when thirds of the overlap, aligned alone, disagree on the offset (two
runs of the same step protocol look alike as a whole, not step by step), or when another
offset fits about as well (a profile that repeats itself).
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy import signal

from .. import contract as c
from ..errors import BadInputError

#: Units a command column may be in (``--command-unit``).
UNITS = ("us", "duty", "percent")
#: (low, high) accepted per unit: beyond them the column is not that kind of command.
#: An ESC pulse is 1-2 ms; 800 us is below any servo-protocol pulse, 2200 us above.
UNIT_RANGE = {"us": (800.0, 2200.0), "duty": (0.0, 1.0), "percent": (0.0, 100.0)}

#: Alignment by speed: the best normalised correlation needed over the overlap.
MIN_SPEED_CORRELATION = 0.99
#: Largest disagreement (s) between the offset found on the whole overlap and on each third.
MAX_LOCAL_OFFSET_S = 0.25
#: How far (s) around the global offset each third searches for its own.
LOCAL_SEARCH_S = 1.0
LOCAL_SEGMENTS = 3
#: A lag must overlap at least this share of the shorter file's span to be considered.
MIN_OVERLAP_SHARE = 0.5
#: Another peak farther than this (s) whose misfit (1 - correlation) is under twice the best's
#: makes the offset ambiguous (a profile that repeats itself).
AMBIGUOUS_BEYOND_S = 1.0
#: Bounds on the resampled grid (points per file) and on one block of the local search, so a
#: long log cannot exhaust memory.
MAX_GRID_POINTS = 1_000_000
LOCAL_CHUNK_POINTS = 4_000_000

AQ_TIME = "Timestamp"
AQ_RPM = "RPM"
AQ_DUTY = "Duty"
_AQ_FORMATS = ("%Y-%m-%d %H:%M:%S:%f", "%Y-%m-%d %H:%M:%S.%f", "%Y-%m-%d %H:%M:%S")


# --- a command column: unit and PWM level --------------------------------------------------
def unit_from_name(name: str) -> str | None:
    """The unit a column's name states in its last parentheses ("Servo 1 (µs)" -> "us")."""
    m = re.search(r"\(([^()]*)\)\s*$", name)
    unit = m.group(1).strip().lower() if m else ""
    if unit in ("µs", "\u03bcs", "us"):
        return "us"
    if unit == "%":
        return "percent"
    return None


def resolve_unit(column: str, given: str | None) -> str:
    """The unit of ``column``: ``given`` (``--command-unit``) or the one its name states;
    BadInputError when neither says, or when they contradict each other."""
    if given is not None and given not in UNITS:
        raise BadInputError(f"--command-unit {given}: must be one of {', '.join(UNITS)}")
    named = unit_from_name(column)
    if given is None:
        if named is None:
            raise BadInputError(
                f"--command-column {column!r}: its name states no unit; give --command-unit "
                f"{'|'.join(UNITS)}")
        return named
    if named is not None and named != given:
        raise BadInputError(
            f"--command-unit {given} contradicts the unit in the name of column {column!r} ({named})")
    return given


def out_of_range(value: float, unit: str) -> str:
    """What is wrong with a command ``value`` outside ``UNIT_RANGE[unit]``, for a message."""
    lo, hi = UNIT_RANGE[unit]
    if unit == "us":
        return f"{value:g} us is outside {lo:g}..{hi:g} us (not an ESC pulse width)"
    if unit == "percent":
        return f"{value:g} % is outside {lo:g}..{hi:g} %"
    return f"{value:g} is outside {lo:g}..{hi:g} (not a duty cycle; --command-unit percent?)"


def to_level(values: np.ndarray, unit: str) -> np.ndarray:
    """PWM level (pulse width / 20 ms) of command ``values`` in ``unit``."""
    v = np.asarray(values, dtype=float)
    if unit == "us":
        return v / c.PWM_PERIOD_US
    duty = v / 100.0 if unit == "percent" else v
    return c.PWM_STOP + (c.PWM_FULL - c.PWM_STOP) * duty


def mapping_text(unit: str) -> str:
    """The mapping ``to_level`` applies, for the summary."""
    if unit == "us":
        return "level = us / 20000 us"
    if unit == "percent":
        return "level = 0.05 + 0.05 x percent / 100 (duty 0 -> 1 ms stop, 100 % -> 2 ms full)"
    return "level = 0.05 + 0.05 x duty (duty 0 -> 1 ms stop, 1 -> 2 ms full)"


# --- the AutoQuad ESC32 utility's log ------------------------------------------------------
@dataclass
class OtherLog:
    """The command file's rows: times on its own clock (s from its first row)."""

    path: Path
    t: np.ndarray
    rpm: np.ndarray
    duty_percent: np.ndarray
    first_timestamp: str
    skipped: int
    sha256: str


def _parse_time(text: str) -> datetime | None:
    for fmt in _AQ_FORMATS:
        try:
            return datetime.strptime(text, fmt)
        except ValueError:
            continue
    return None


class CsvRows(Protocol):
    """``csv.reader``'s reader as the readers use it: the rows, and the line reached (errors name it)."""

    @property
    def line_num(self) -> int: ...

    def __iter__(self) -> Iterator[list[str]]: ...

    def __next__(self) -> list[str]: ...


def csv_header(path: Path, text: str, option: str = "") -> tuple[CsvRows, list[str]]:
    """(the csv reader after the header, the header: the first non-blank row); BadInputError
    naming ``path`` (and the option that gave it) when there is none or the CSV is broken."""
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader)
        while not any(cell.strip() for cell in header):
            header = next(reader)
    except StopIteration:
        raise BadInputError(f"{path}: no header row{f' ({option})' if option else ''}") from None
    except csv.Error as exc:
        raise BadInputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None
    return reader, header


def read_autoquad(path: Path, text: str) -> OtherLog:
    """Rows of an AutoQuad ESC32 utility CSV (``Timestamp``, ``RPM``, ``Duty`` in percent);
    BadInputError (one line naming ``path``) on anything else."""
    reader, header = csv_header(path, text, "--command-from")
    index = {cell.strip(): k for k, cell in reversed(list(enumerate(header))) if cell.strip()}
    missing = [n for n in (AQ_TIME, AQ_RPM, AQ_DUTY) if n not in index]
    if missing:
        shown = ", ".join(repr(n) for n in list(index)[:12]) or "no column names"
        raise BadInputError(
            f"{path}: no {', '.join(repr(n) for n in missing)} column; --command-from reads an "
            f"AutoQuad ESC32 log ({AQ_TIME}, {AQ_RPM}, {AQ_DUTY} in %) (found: {shown})")
    kt, kr, kd = index[AQ_TIME], index[AQ_RPM], index[AQ_DUTY]
    first: datetime | None = None
    first_text = ""
    t: list[float] = []
    rpm: list[float] = []
    duty: list[float] = []
    skipped = 0
    try:
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue
            cells = [row[k].strip() if k < len(row) else "" for k in (kt, kr, kd)]
            if not all(cells):
                skipped += 1
                continue
            stamp = _parse_time(cells[0])
            if stamp is None:
                raise BadInputError(f"{path}: line {line}, column {AQ_TIME!r}: {cells[0][:40]!r} is not "
                                    "a date and time like 2019-11-07 18:45:58:868")
            values = []
            for name, cell in ((AQ_RPM, cells[1]), (AQ_DUTY, cells[2])):
                try:
                    v = float(cell)
                except ValueError:
                    raise BadInputError(
                        f"{path}: line {line}, column {name!r}: {cell[:40]!r} is not a number") from None
                if not math.isfinite(v):
                    raise BadInputError(f"{path}: line {line}, column {name!r}: {cell!r} is not finite")
                values.append(v)
            if not 0.0 <= values[1] <= 100.0:
                raise BadInputError(f"{path}: line {line}, column {AQ_DUTY!r}: {values[1]:g} % is outside 0..100 %")
            if first is None:
                first, first_text = stamp, cells[0]
            ts = (stamp - first).total_seconds()
            if t and ts < t[-1]:
                skipped += 1  # the clock went back: keep the earlier rows
                continue
            t.append(ts)
            rpm.append(values[0])
            duty.append(values[1])
    except csv.Error as exc:
        raise BadInputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None
    if len(t) < 2 or t[-1] <= t[0]:
        raise BadInputError(f"{path}: {len(t)} usable row(s) with a {AQ_TIME}, {AQ_RPM} and {AQ_DUTY}; "
                            "at least 2 over some time are needed (--command-from)")
    return OtherLog(path, np.asarray(t), np.asarray(rpm), np.asarray(duty), first_text, skipped,
                    hashlib.sha256(text.encode("utf-8")).hexdigest())


def hold(t_src: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Zero-order hold: at each ``t`` the last value at or before it (of equal times, the last)."""
    k = np.searchsorted(t_src, t + 1e-9, side="right") - 1
    return values[np.clip(k, 0, len(t_src) - 1)]


# --- two clocks aligned by the speed both files log ---------------------------------------
@dataclass(frozen=True)
class Alignment:
    """log time = other file's time + ``offset_s``, and how well the speeds agree after it."""

    offset_s: float
    correlation: float  #: normalised correlation of the two speeds at the offset, over the overlap
    overlap_s: float
    grid_step_s: float
    local_offsets_s: tuple[float | None, ...]  #: per third of the overlap, minus offset_s (None: flat)
    speed_rms_rpm: float  #: RMS of (other - log) speed after the shift, over the overlap
    speed_range_rpm: float  #: max - min of the log's speed over the overlap
    speed_ratio: float | None  #: median other / log speed where both spin (1: same unit)

    def as_dict(self) -> dict[str, object]:
        return {
            "offset_s": self.offset_s, "correlation": self.correlation, "overlap_s": self.overlap_s,
            "grid_step_s": self.grid_step_s, "local_offsets_s": list(self.local_offsets_s),
            "speed_rms_rpm": self.speed_rms_rpm, "speed_range_rpm": self.speed_range_rpm,
            "speed_rms_share_of_range": self.speed_rms_rpm / self.speed_range_rpm if self.speed_range_rpm > 0 else None,
            "speed_ratio_other_over_log": self.speed_ratio,
        }


def _strictly_increasing(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Finite samples, the last of each run of equal times (np.interp needs increasing times)."""
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    last = np.r_[np.diff(t) > 0, True]
    return t[last], v[last]


def _pearson_by_lag(x: np.ndarray, y: np.ndarray, min_n: int) -> tuple[np.ndarray, np.ndarray]:
    """(lags, r): x[i] paired with y[i - lag], r over the overlap of each lag (-inf where the
    overlap is shorter than ``min_n`` or one side is flat there)."""
    ox, oy = np.ones_like(x), np.ones_like(y)

    def corr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return signal.correlate(a, b, mode="full", method="fft")

    n = np.rint(corr(ox, oy))
    sx, sy = corr(x, oy), corr(ox, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = corr(x, y) - sx * sy / n
        vx = corr(x * x, oy) - sx * sx / n
        vy = corr(ox, y * y) - sy * sy / n
        r = cov / np.sqrt(vx * vy)
    ok = (n >= min_n) & (vx > 1e-6 * n) & (vy > 1e-6 * n) & np.isfinite(r)
    return signal.correlation_lags(len(x), len(y)), np.where(ok, r, -np.inf)


def _peak(r: np.ndarray, k: int) -> float:
    """Sub-sample position of the peak at index k (parabola through k-1, k, k+1)."""
    if 0 < k < len(r) - 1 and np.isfinite(r[k - 1]) and np.isfinite(r[k + 1]):
        den = r[k - 1] - 2.0 * r[k] + r[k + 1]
        if den < 0:
            return k + float(np.clip(0.5 * (r[k - 1] - r[k + 1]) / den, -0.5, 0.5))
    return float(k)


def _local_offset(ta: np.ndarray, va: np.ndarray, tb: np.ndarray, vb: np.ndarray, lo: float,
                  hi: float, offset: float, step: float, flat: float) -> float | None:
    """Offset (minus ``offset``) that best aligns the speeds over log times [lo, hi] alone,
    searched within +-LOCAL_SEARCH_S; None when the log's speed hardly moves there."""
    g = np.arange(lo, hi, step)
    x = np.interp(g, ta, va)
    if len(g) < 3 or np.std(x) < flat:
        return None
    d = np.arange(-LOCAL_SEARCH_S, LOCAL_SEARCH_S + step / 2, step)
    xc = x - x.mean()
    r = np.empty(len(d))
    chunk = max(1, LOCAL_CHUNK_POINTS // len(g))  # lags at a time: bounded memory on long logs
    for a in range(0, len(d), chunk):
        dd = d[a:a + chunk]
        y = np.interp((g[None, :] - offset - dd[:, None]).ravel(), tb, vb).reshape(len(dd), len(g))
        yc = y - y.mean(axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            r[a:a + chunk] = (yc @ xc) / np.sqrt((yc * yc).sum(axis=1) * (xc @ xc))
    r = np.where(np.isfinite(r), r, -np.inf)
    k = int(np.argmax(r))
    return float(d[0] + _peak(r, k) * step)


def align_by_speed(t_log: np.ndarray, rpm_log: np.ndarray, t_other: np.ndarray, rpm_other: np.ndarray,
                   *, log_name: str, other_name: str) -> Alignment:
    """The offset between two clocks that best lines up two records of the same rotor speed
    (log time = other time + offset); BadInputError (one line naming both files) when the
    speeds do not line up at one offset: the files are not one run, or a clock drifts."""
    ta, va = _strictly_increasing(np.asarray(t_log, float), np.asarray(rpm_log, float))
    tb, vb = _strictly_increasing(np.asarray(t_other, float), np.asarray(rpm_other, float))
    for name, t, v in ((log_name, ta, va), (other_name, tb, vb)):
        if len(t) < 3 or not np.ptp(v) > 0:
            raise BadInputError(f"{name}: the speed never changes ({len(t)} samples): nothing to align "
                                "the two clocks on (--command-from)")
    span_a, span_b = ta[-1] - ta[0], tb[-1] - tb[0]
    step = float(np.clip(0.5 * min(np.median(np.diff(ta)), np.median(np.diff(tb))), 1e-3, 0.05))
    step = max(step, max(span_a, span_b) / MAX_GRID_POINTS)
    ga, gb = ta[0] + np.arange(int(span_a / step) + 1) * step, tb[0] + np.arange(int(span_b / step) + 1) * step
    x, y = np.interp(ga, ta, va), np.interp(gb, tb, vb)
    x, y = (x - x.mean()) / x.std(), (y - y.mean()) / y.std()
    lags, r = _pearson_by_lag(x, y, max(3, int(MIN_OVERLAP_SHARE * min(len(x), len(y)))))
    k = int(np.argmax(r))
    best = float(r[k])
    if not np.isfinite(best):
        raise BadInputError(f"{other_name}: its RPM and the speed of {log_name} never vary together over "
                            "half of the shorter file: nothing to align the two clocks on (--command-from)")
    offset = float(ta[0] - tb[0] + (lags[0] + _peak(r, k)) * step)
    lo, hi = max(ta[0], tb[0] + offset), min(ta[-1], tb[-1] + offset)

    flat = 0.05 * float(np.std(np.interp(np.arange(lo, hi, step), ta, va)))
    edges = np.linspace(lo, hi, LOCAL_SEGMENTS + 1)
    local = tuple(_local_offset(ta, va, tb, vb, edges[s], edges[s + 1], offset, step, flat)
                  for s in range(LOCAL_SEGMENTS))
    local_text = ", ".join("flat" if d is None else f"{d:+.2f}" for d in local)
    if not best >= MIN_SPEED_CORRELATION or any(d is not None and abs(d) > MAX_LOCAL_OFFSET_S for d in local):
        raise BadInputError(
            f"{other_name}: its RPM does not line up with the speed of {log_name} at one time offset "
            f"(best: correlation {best:.3f} at {offset:+.2f} s, need >= {MIN_SPEED_CORRELATION}; each "
            f"third of the overlap alone moves it by {local_text} s, allowed +-{MAX_LOCAL_OFFSET_S} s): "
            "not a record of the same run? (--command-from)")
    # another peak nearly as good, away from this one: a profile that repeats itself
    peaks = signal.find_peaks(np.where(np.isfinite(r), r, -2.0))[0]
    peaks = peaks[np.abs(lags[peaks] - lags[k]) * step > AMBIGUOUS_BEYOND_S]
    if len(peaks):
        second = int(peaks[np.argmax(r[peaks])])
        if 1.0 - float(r[second]) < 2.0 * (1.0 - best):
            raise BadInputError(
                f"{other_name}: its RPM lines up with the speed of {log_name} about as well at {offset:+.2f} s "
                f"as at {ta[0] - tb[0] + lags[second] * step:+.2f} s (correlation {best:.4f} and "
                f"{float(r[second]):.4f}): the run repeats itself, so the clock offset is ambiguous (--command-from)")

    inside = (tb + offset >= lo) & (tb + offset <= hi)
    log_at = np.interp(tb[inside] + offset, ta, va)
    resid = vb[inside] - log_at
    spinning = (np.abs(log_at) > 0.1 * np.max(np.abs(va))) & (np.abs(vb[inside]) > 0.1 * np.max(np.abs(vb)))
    over = va[(ta >= lo) & (ta <= hi)]
    ratio = float(np.median(vb[inside][spinning] / log_at[spinning])) if np.count_nonzero(spinning) >= 3 else None
    return Alignment(
        offset_s=offset, correlation=best, overlap_s=float(hi - lo), grid_step_s=step, local_offsets_s=local,
        speed_rms_rpm=float(np.sqrt(np.mean(resid**2))) if len(resid) else math.nan,
        speed_range_rpm=float(np.ptp(over)) if len(over) else math.nan,
        speed_ratio=ratio,
    )
