"""RCbenchmark / Tyto Robotics thrust-stand CSV log -> rosbag2 bag with the contract's topics.

A commercial stand logs what this project's bench records, in other units and at its own
rate: the ESC command in microseconds, the supply voltage, current, thrust (N, kgf, gf or lbf) and
speed (electrical and/or optical RPM), one row per sample (~4-150 Hz). The importer turns
such a log into a bag that ``train``, ``evaluate`` and ``discrepancy`` read like a bench
recording:

| topic | type | content |
|---|---|---|
| ``/pwm`` | Float64 | ESC us / 20000 us, zero-order hold of the logged command on a 50 Hz frame grid |
| ``/battery/voltage`` | BatteryState | supply voltage, one per row with a voltage (measured: already filtered) |
| ``/rotor/speed`` | Float64 | rad/s, from optical RPM if it has data, else electrical RPM |
| ``/thrust/measured`` | Float64 | N (x 9.80665 from kgf, x 9.80665e-3 from gf, x 4.4482216152605 from lbf) |
| ``/battery/current`` | Float64 | A; an *addition* to the contract (it allows added topics), for thermal states |

Speed from the electrical column: the RCbenchmark software converts the commutation
frequency to shaft RPM with the pole count entered in its setup, so the column it writes is
already mechanical RPM (checked on real logs: its own ``Mechanical Power (W)`` equals
``Torque (N·m)`` x that column). ``pole_pairs`` is only for logs that hold raw electrical RPM
(commutation RPM = shaft RPM x pole pairs); the returned dict says which source and which
assumption were used, and warns when the speed disagrees with mechanical power / torque, and
when it reads far below what the thrust column says for half a second or more (a probe that
misses the rotor at low speed: ``_contradicted_spans``; written as read, so the user decides).

The command: the ``ESC signal (µs)`` column, unless the ESC's own tool set it (the column is
then empty, and the error says so): ``command_column`` names another column of the log (us,
duty or percent), ``command_from`` another file (the AutoQuad ESC32 utility's log) whose clock
is aligned to the log's by the speed both record (csv_command.py). Only the rows where the
command is known are imported.

Bag times are ``t0_ns + row time`` with a fixed ``t0_ns`` so the output is reproducible.
"""

from __future__ import annotations

import csv
import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as c
from ..atomic import RECORDING, check_output
from ..bagio import SIM_EPOCH_NS, BagWriter
from ..errors import BadInputError
from ..runs import true_run_pairs
from .csv_command import (
    UNIT_RANGE,
    Alignment,
    OtherLog,
    align_by_speed,
    csv_header,
    hold,
    mapping_text,
    out_of_range,
    read_autoquad,
    resolve_unit,
    to_level,
)

#: Added topic (not in the contract's tables): supply current in amperes.
TOPIC_BATTERY_CURRENT = "battery/current"

KGF_TO_N = 9.80665
GF_TO_N = 9.80665e-3
LBF_TO_N = 4.4482216152605  #: international avoirdupois pound-force, exact
RPM_TO_RAD_S = 2.0 * math.pi / 60.0
ESC_MIN_US, ESC_MAX_US = UNIT_RANGE["us"]  #: outside: the column is not an ESC pulse width
#: Relative disagreement between the written speed and mechanical power / torque that warns.
SPEED_CHECK_TOLERANCE = 0.10
#: The thrust's check of the speed (``_contradicted_spans``): a row's speed is contradicted when it
#: is off by more than this share of the speed its thrust implies (T = b w^2)...
THRUST_CHECK_SHARE = 0.5
#: ... where that thrust is a load the cell plainly reads: above this share of the log's largest
#: (a tare drift of a few grams-force stays below it) and ten times the cell's row-to-row noise,
THRUST_CHECK_MIN_SHARE = 0.01
#: ... for at least this long (s): a step's lag in the load cell, or one glitch, is no span.
THRUST_CHECK_MIN_S = 0.5

COL_TIME = "Time (s)"
COL_ESC = "ESC signal (µs)"
COL_VOLTAGE = "Voltage (V)"
COL_CURRENT = "Current (A)"
COL_THRUST_N = "Thrust (N)"
COL_THRUST_KGF = "Thrust (kgf)"
COL_THRUST_GF = "Thrust (gf)"  #: grams-force: the esc_test logs (RCbenchmark 1580/1585)
COL_THRUST_LBF = "Thrust (lbf)"
#: Thrust columns the importer reads, in the order it prefers them: (unit, factor to N).
THRUST_COLUMNS = {COL_THRUST_N: ("N", 1.0), COL_THRUST_KGF: ("kgf", KGF_TO_N),
                  COL_THRUST_GF: ("gf", GF_TO_N), COL_THRUST_LBF: ("lbf", LBF_TO_N)}
COL_RPM_ELECTRICAL = "Motor Electrical Speed (RPM)"
COL_RPM_OPTICAL = "Motor Optical Speed (RPM)"
COL_TORQUE = "Torque (N·m)"
COL_MECH_POWER = "Mechanical Power (W)"

_MAX_BYTES = 512 * 1024 * 1024  # a thrust-stand log is a few MB; refuse anything absurd


@dataclass
class _Table:
    """Numeric columns of the kept rows (NaN = empty cell) and what was skipped."""

    time: np.ndarray
    cols: dict[str, np.ndarray]
    lines: np.ndarray
    skipped: dict[str, int] = field(default_factory=dict)
    #: cells with data in ``ESC signal (µs)`` when another command is used (it is then ignored)
    esc_cells_ignored: int = 0
    #: ``Thrust (...)`` columns in a unit the importer does not know
    other_thrust: list[str] = field(default_factory=list)

    def keep(self, mask: np.ndarray, reason: str) -> None:
        """Keep only the rows of ``mask``; the others are counted as skipped for ``reason``."""
        self.skipped[reason] = int(np.count_nonzero(~mask))
        self.time, self.lines = self.time[mask], self.lines[mask]
        self.cols = {role: v[mask] for role, v in self.cols.items()}


@dataclass(frozen=True)
class _Command:
    """Where the command is read: a column (its unit and the option that named it), or
    ``column=None``: another file (``--command-from``), so a row needs only a time."""

    column: str | None = COL_ESC
    unit: str = "us"
    option: str = ""  #: "" for the default column, "--command-column" when the user named it


def _norm(name: str) -> str:
    # Greek mu (U+03BC) and micro sign (U+00B5) look the same; exports use the micro sign.
    return " ".join(name.replace("\u03bc", "\u00b5").split())


def _read_text(path: Path) -> str:
    if not path.exists():
        raise BadInputError(f"{path}: no such file")
    if path.is_dir():
        raise BadInputError(f"{path}: is a directory, not a CSV file")
    try:
        size = path.stat().st_size
        if size > _MAX_BYTES:
            raise BadInputError(f"{path}: {size} bytes is too large for a thrust-stand CSV log")
        data = path.read_bytes()
    except OSError as exc:
        raise BadInputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not data.strip():
        raise BadInputError(f"{path}: file is empty")
    if b"\x00" in data[:65536]:
        raise BadInputError(f"{path}: binary file, not a CSV text file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BadInputError(
            f"{path}: not a UTF-8 CSV text file (undecodable byte at offset {exc.start})"
        ) from None


def _header_index(path: Path, header: list[str], command: _Command) -> dict[str, int]:
    index: dict[str, int] = {}
    for k, name in enumerate(header):
        n = _norm(name)
        if n and n not in index:  # trailing comma -> empty name: ignored; duplicates: first wins
            index[n] = k
    found = [n for n in index][:15]
    more = ", ..." if len(index) > 15 else ""
    shown = ", ".join(repr(n) for n in found) + more if found else "no column names"
    if COL_TIME not in index:
        raise BadInputError(f"{path}: no {COL_TIME!r} column; not an RCbenchmark/Tyto log? (found: {shown})")
    if command.column is not None and command.column not in index:
        if command.option:
            raise BadInputError(f"{path}: no column {command.column!r} ({command.option}); found: {shown}")
        raise BadInputError(
            f"{path}: no {command.column!r} column (found: {shown}); name the command's column with "
            "--command-column NAME, or give --command-from ESC_LOG.csv"
        )
    return index


def _parse(path: Path, text: str, command: _Command = _Command()) -> tuple[_Table, dict[str, str]]:
    """Numeric table of the usable rows (a time and, unless it comes from another file, a
    command); BadInputError on the first bad cell."""
    reader, header = csv_header(path, text)
    index = _header_index(path, header, command)
    used, checks = _columns(index, command)
    lo, hi = UNIT_RANGE[command.unit]
    rows_with_time = command_cells = 0

    values: dict[str, list[float]] = {role: [] for role in (*used, *checks)}
    lines: list[int] = []
    skipped = {"no_time_or_esc": 0, "time_not_increasing": 0}
    last_t = -math.inf
    try:
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue  # blank line
            cells = _cells(path, line, row, index, used, checks)
            t, esc = cells["time"], cells.get("esc", 0.0)
            rows_with_time += not math.isnan(t)
            command_cells += not (math.isnan(t) or math.isnan(esc))
            if math.isnan(t) or math.isnan(esc):
                skipped["no_time_or_esc"] += 1  # app-message rows, rows without a command
                continue
            if command.column is not None and not lo <= esc <= hi:
                raise BadInputError(
                    f"{path}: line {line}, column {command.column!r}: {out_of_range(esc, command.unit)}")
            if t <= last_t:
                skipped["time_not_increasing"] += 1  # duplicate or backwards: keep the first
                continue
            last_t = t
            lines.append(line)
            for role in values:
                values[role].append(cells[role])
    except csv.Error as exc:
        raise BadInputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None

    if command.column is not None and command_cells == 0 and rows_with_time >= 2:
        # the stand logged everything but the command: it was set elsewhere (the ESC's own tool)
        why = "" if command.option else " (the command was set outside the stand, e.g. by the ESC's own tool)"
        raise BadInputError(
            f"{path}: command column {command.column!r} is empty in all {rows_with_time} rows{why}: give it with "
            "--command-column NAME [--command-unit us|duty|percent] or --command-from ESC_LOG.csv (AutoQuad ESC32 log)")
    if len(lines) < 2:
        what = "a time" if command.column is None else f"a time and a command ({command.column!r})"
        raise BadInputError(f"{path}: {len(lines)} usable row(s) with {what}; at least 2 are needed")
    cols = {role: np.asarray(v, dtype=float) for role, v in values.items()}
    ignored = cols.pop("esc_ignored", None)
    table = _Table(time=cols.pop("time"), cols=cols, lines=np.asarray(lines), skipped=skipped,
                   esc_cells_ignored=0 if ignored is None else int(np.count_nonzero(np.isfinite(ignored))),
                   other_thrust=[n for n in index if n.startswith("Thrust (") and n not in THRUST_COLUMNS])
    return table, used


def _columns(index: dict[str, int], command: _Command) -> tuple[dict[str, str], dict[str, str]]:
    """The columns read, by role: those written (time, the command unless it comes from another
    file, voltage, current, speeds, the first thrust column in a known unit), and those only
    counted or used to check the speed (never a reason to fail)."""
    used = {"time": COL_TIME}
    if command.column is not None:
        used["esc"] = command.column  # the command, whatever its column and unit
    for role, name in (("voltage", COL_VOLTAGE), ("current", COL_CURRENT),
                       ("rpm_electrical", COL_RPM_ELECTRICAL), ("rpm_optical", COL_RPM_OPTICAL)):
        if name in index:
            used[role] = name
    thrust = next((name for name in THRUST_COLUMNS if name in index), None)
    if thrust is not None:
        used["thrust"] = thrust
    # only for a consistency check of the speed: never fail on these
    checks = {role: name for role, name in (("torque", COL_TORQUE), ("mech_power", COL_MECH_POWER))
              if name in index}
    if command.column != COL_ESC and COL_ESC in index:
        checks["esc_ignored"] = COL_ESC  # counted, to say that it was not used
    return used, checks


def _cells(path: Path, line: int, row: list[str], index: dict[str, int], used: dict[str, str],
           checks: dict[str, str]) -> dict[str, float]:
    """One row's numbers by role (NaN: an empty cell); BadInputError on a used cell that is not a
    finite number (a checked one is NaN then)."""
    cells: dict[str, float] = {}
    for role, name in used.items():
        k = index[name]
        cell = row[k].strip() if k < len(row) else ""
        if not cell:
            cells[role] = math.nan
            continue
        try:
            v = float(cell)
        except ValueError:
            raise BadInputError(
                f"{path}: line {line}, column {name!r}: {cell[:40]!r} is not a number"
            ) from None
        if not math.isfinite(v):
            raise BadInputError(f"{path}: line {line}, column {name!r}: {cell!r} is not finite")
        cells[role] = v
    for role, name in checks.items():
        k = index[name]
        try:
            cells[role] = float(row[k]) if k < len(row) and row[k].strip() else math.nan
        except ValueError:
            cells[role] = math.nan
    return cells


def _pwm_frames(t: np.ndarray, t_cmd: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """50 Hz frame times from the first to the last row and the PWM level in force at each:
    the last command logged (at ``t_cmd``) at or before the frame (zero-order hold)."""
    n = int(math.floor((t[-1] - t[0]) * c.PWM_FRAME_HZ + 1e-9)) + 1
    frames = t[0] + np.arange(n) / c.PWM_FRAME_HZ
    return frames, hold(t_cmd, level, frames)


def _speed(table: _Table, pole_pairs: int | None) -> tuple[str | None, np.ndarray | None, str]:
    """(source, rpm of the shaft per row or None, note on the assumption)."""
    optical = table.cols.get("rpm_optical")
    electrical = table.cols.get("rpm_electrical")
    if optical is not None and np.any(np.nan_to_num(optical) != 0.0):
        return "optical", optical, "optical tachometer: shaft RPM, independent of the pole count"
    if electrical is not None and np.any(np.isfinite(electrical)):
        if pole_pairs is None:
            note = ("electrical speed column taken as shaft RPM (the RCbenchmark software already "
                    "divides by the pole count set in its setup); pass pole_pairs only if the log "
                    "holds raw commutation RPM")
            return "electrical", electrical, note
        note = (f"electrical speed column taken as commutation RPM and divided by "
                f"pole_pairs={pole_pairs} (assumed motor: {2 * pole_pairs} poles)")
        return "electrical", electrical / pole_pairs, note
    return None, None, "no speed column with data: /rotor/speed not written"


def thrust_law_samples(path: str | os.PathLike[str], pole_pairs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(shaft speed rad/s, thrust N) of every row of a stand log that has both, whatever its
    command: the thrust law T = b w^2 needs no command, and four of the esc_test logs were
    commanded from outside the stand. BadInputError when the log has no speed or no thrust."""
    src = Path(path)
    table, used = _parse(src, _read_text(src), _Command(column=None))
    _, rpm, _ = _speed(table, pole_pairs)
    if rpm is None or "thrust" not in used:
        raise BadInputError(f"{src}: no {'speed' if rpm is None else 'thrust'} column with data: no thrust law")
    _, factor = THRUST_COLUMNS[used["thrust"]]
    w, thrust = rpm * RPM_TO_RAD_S, table.cols["thrust"] * factor
    ok = np.isfinite(w) & np.isfinite(thrust)
    return w[ok], thrust[ok]


def _speed_check(table: _Table, rpm: np.ndarray | None) -> float | None:
    """Median of (mechanical power / torque) / written speed: 1.0 when consistent."""
    torque, power = table.cols.get("torque"), table.cols.get("mech_power")
    if rpm is None or torque is None or power is None:
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        implied = np.abs(power) / np.abs(torque) / RPM_TO_RAD_S
        ratio = implied / rpm
    ok = (np.abs(torque) > 1e-3) & (np.abs(power) > 1.0) & (rpm > 100.0) & np.isfinite(ratio)
    if np.count_nonzero(ok) < 3:
        return None
    return float(np.median(ratio[ok]))


@dataclass(frozen=True)
class _Contradiction:
    """Rows of a log (its own clock, s) whose speed column the thrust column contradicts."""

    start_s: float
    stop_s: float
    speed_rad_s: float  #: the column's median there
    implied_rad_s: float  #: the thrust's median implied speed there


def _contradicted_spans(t: np.ndarray, rpm: np.ndarray | None,
                        thrust_n: np.ndarray | None) -> tuple[list[_Contradiction], float | None]:
    """Spans where the thrust says the rotor turns at a speed the speed column does not read, and
    the b the implied speed came from (None: no check, the log lacks a column or fast rows).

    A stand's speed probe (optical, or the electrical probe on a phase wire) can miss the rotor at
    low speed and read 0 or flicker while the load cell plainly reads a thrust; training and
    evaluate would take that reading as the rotor's speed. b is the median T / w^2 over the rows
    above half the log's top speed, where a probe reads; the propeller's b varies some per cent
    with speed, far inside THRUST_CHECK_SHARE."""
    if rpm is None or thrust_n is None:
        return [], None
    has_speed = np.isfinite(rpm)
    ok = has_speed & np.isfinite(thrust_n)
    t_speed, w_speed = t[has_speed], rpm[has_speed] * RPM_TO_RAD_S
    t, w, thrust = t[ok], rpm[ok] * RPM_TO_RAD_S, thrust_n[ok]
    if len(t) < 10 or not np.any(w > 0):
        return [], None
    fast = w >= 0.5 * w.max()
    b = float(np.median(thrust[fast] / w[fast] ** 2))
    if not b > 0:
        return [], None
    step = np.diff(thrust)
    noise = 1.4826 * float(np.median(np.abs(step - np.median(step)))) / math.sqrt(2.0)
    implied = np.sqrt(np.clip(thrust, 0.0, None) / b)
    loaded = thrust > max(10.0 * noise, THRUST_CHECK_MIN_SHARE * float(thrust.max()))
    read = _median_around(t_speed, w_speed, t, THRUST_CHECK_MIN_S / 2.0)
    bad = loaded & (np.abs(read - implied) > THRUST_CHECK_SHARE * implied)
    spans = [_Contradiction(float(t[i]), float(t[j - 1]), float(np.median(read[i:j])),
                            float(np.median(implied[i:j])))
             for i, j in true_run_pairs(bad) if t[j - 1] - t[i] >= THRUST_CHECK_MIN_S]
    return spans, b


def _median_around(t: np.ndarray, v: np.ndarray, at: np.ndarray, half_s: float) -> np.ndarray:
    """Per time in ``at``, the median of ``v`` over the samples within ``half_s`` of it (``t``
    increasing). Why a median and not the row's reading: a probe losing the rotor flickers
    (esc_test F80 at 1100 us: 160-2475 rpm from one row to the next under a steady 19.5 gf), so
    single rows now and then land within THRUST_CHECK_SHARE of the thrust's speed and break a
    span into pieces shorter than THRUST_CHECK_MIN_S; a step's own rows are a few in a window."""
    lo = np.searchsorted(t, at - half_s, side="left")
    hi = np.searchsorted(t, at + half_s, side="right")
    return np.array([float(np.median(v[i:j])) for i, j in zip(lo.tolist(), hi.tolist(), strict=True)])


def _thrust_check(src: Path, t: np.ndarray, rpm: np.ndarray | None, thrust_n: np.ndarray | None,
                  dropped: bool = False) -> tuple[list[_Contradiction], list[str]]:
    """The spans where the thrust contradicts the speed column (``_contradicted_spans``) and one
    warning line naming them all (none: no line); ``dropped``: the speed is left out there."""
    spans, b = _contradicted_spans(t, rpm, thrust_n)
    if not spans or b is None:
        return spans, []
    where = "; ".join(f"{s.start_s:.1f}-{s.stop_s:.1f} s reads {s.speed_rad_s:.0f} rad/s where the thrust says "
                      f"about {s.implied_rad_s:.0f}" for s in spans)
    total = sum(s.stop_s - s.start_s for s in spans)
    return spans, [f"{src}: the thrust contradicts the speed column for {total:.1f} s (log time {where}; "
                   f"T = b w^2 with b = {b:.3g} N s^2/rad^2 from the rows above half the top speed): the speed "
                   f"probe misses the rotor there, or the load cell reads something else (a drifted zero, a hand "
                   "on the stand); " + (
                       "/rotor/speed is left out there (--drop-contradicted): training and evaluate skip the gap"
                       if dropped else
                       "/rotor/speed is written as read, and training and evaluate take it as the rotor's speed "
                       "(--drop-contradicted leaves it out)")]


def _without(t: np.ndarray, rpm: np.ndarray | None, spans: Sequence[_Contradiction]) -> np.ndarray | None:
    """``rpm`` with the rows of ``spans`` (their first to last contradicted row) set to NaN, so
    that /rotor/speed has a gap there."""
    if rpm is None or not spans:
        return rpm
    out = rpm.copy()
    for sp in spans:
        out[(t >= sp.start_s) & (t <= sp.stop_s)] = np.nan
    return out


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _command_spec(column: str | None, unit: str | None,
                  other: str | os.PathLike[str] | None) -> tuple[_Command, Path | None]:
    """Where the command is read, from the options; BadInputError on a contradiction."""
    if unit is not None and column is None:
        raise BadInputError(f"--command-unit {unit}: only with --command-column (it is the unit of that column)")
    if column is not None and other is not None:
        raise BadInputError("--command-column and --command-from: give the command one way, not both")
    if other is not None:
        return _Command(column=None, unit="percent", option="--command-from"), Path(other)
    if column is not None:
        name = _norm(column)
        if not name:
            raise BadInputError("--command-column: the column name is empty")
        return _Command(name, resolve_unit(name, unit), "--command-column"), None
    return _Command(), None


def _align_other(src: Path, other_src: Path, table: _Table, rpm: np.ndarray | None) -> tuple[OtherLog, Alignment]:
    """The ESC's own log (``--command-from``) and its clock's offset to the log's."""
    if table.esc_cells_ignored:
        raise BadInputError(
            f"{src}: has its own command in {COL_ESC!r} ({table.esc_cells_ignored} rows); --command-from "
            "would replace it: omit --command-from")
    if other_src.resolve() == src.resolve():
        raise BadInputError(f"--command-from {other_src}: is the log being imported itself")
    other = read_autoquad(other_src, _read_text(other_src))
    if rpm is None or np.count_nonzero(np.isfinite(rpm)) < 3:
        raise BadInputError(f"{src}: no speed column with data; --command-from aligns the two files' clocks "
                            "by the speed both log")
    return other, align_by_speed(table.time, rpm, other.t, other.rpm, log_name=str(src), other_name=str(other_src))


def _command_warnings(src: Path, command: _Command, table: _Table, unit: str,
                      alignment: Alignment | None) -> list[str]:
    """What a user should check about the command read (never silent about a guess)."""
    out = []
    if command.option == "--command-column" and table.esc_cells_ignored:
        out.append(f"{src}: {COL_ESC!r} has data in {table.esc_cells_ignored} rows, not used: the command "
                   f"was read from {command.column!r} (--command-column)")
    if command.column is not None and unit == "percent" and 0.0 < np.max(table.cols["esc"]) <= 1.0:
        out.append(f"{src}: column {command.column!r} read as percent never exceeds 1 %; if it holds a duty "
                   "cycle 0..1, give --command-unit duty")
    if alignment is not None and alignment.speed_ratio is not None \
            and abs(alignment.speed_ratio - 1.0) > SPEED_CHECK_TOLERANCE:
        out.append(f"{src}: the --command-from file's RPM is {alignment.speed_ratio:.3g} x this log's speed once "
                   "aligned: one of them is not shaft RPM (check --pole-pairs)")
    return out


def import_csv(
    csv_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    force: bool = False,
    pole_pairs: int | None = None,
    command_column: str | None = None,
    command_unit: str | None = None,
    command_from: str | os.PathLike[str] | None = None,
    drop_contradicted: bool = False,
) -> dict[str, Any]:
    """Convert a thrust-stand CSV log into a bag at ``out_path``; returns a summary dict.

    ``pole_pairs`` (None: the electrical speed column is already shaft RPM, as the RCbenchmark
    software writes it) divides a raw commutation-RPM column. The command is the
    ``ESC signal (µs)`` column unless ``command_column`` names another (in ``command_unit``: us,
    duty or percent; None: the unit its name states) or ``command_from`` gives the AutoQuad
    ESC32 log of the same run (its Duty, its clock aligned to the log's by speed). Raises
    ``BadInputError`` (one line naming the file) on bad input and when ``out_path`` may not be
    written (atomic.check_output); nothing is written then.
    """
    src, out = Path(csv_path), Path(out_path)
    if pole_pairs is not None and (isinstance(pole_pairs, bool) or int(pole_pairs) != pole_pairs
                                   or pole_pairs < 1):
        raise BadInputError(f"--pole-pairs {pole_pairs}: must be a positive integer")
    command, other_src = _command_spec(command_column, command_unit, command_from)
    check_output(out, RECORDING, force=force, inputs=[src, other_src])
    text = _read_text(src)
    table, used = _parse(src, text, command)
    source, rpm, speed_note = _speed(table, pole_pairs)
    cmd = _command_source(src, other_src, command, table, rpm)
    rpm = cmd.rpm
    t = table.time
    cols = table.cols

    frames, pwm = _pwm_frames(t, cmd.t, cmd.level)
    thrust_unit, thrust_factor = THRUST_COLUMNS[used["thrust"]] if "thrust" in used else (None, None)
    thrust = cols.get("thrust")  # (in the log's unit; present only when "thrust" is used)
    thrust_n = None if thrust is None else thrust * thrust_factor
    contradicted, thrust_lines = _thrust_check(src, t, rpm, thrust_n, drop_contradicted)
    left_out = contradicted if drop_contradicted else []
    streams = _streams(t, cols, frames, pwm, _without(t, rpm, left_out), thrust_n)

    written = _write_bag(out, force, streams, f"imported from RCbenchmark / Tyto CSV {src.name}: ESC command "
                         f"({cmd.unit}{_whence(cmd, other_src)}) -> pwm level, held on 50 Hz frames; "
                         f"speed: {speed_note}")

    columns_used = {role: name for role, name in used.items()
                    if not role.startswith("rpm_") or role == f"rpm_{source}"}
    ratio = _speed_check(table, rpm)
    warnings = (_data_warnings(src, table, used, rpm, ratio, source, speed_note, pole_pairs) + thrust_lines
                + _command_warnings(src, command, table, cmd.unit, cmd.alignment))
    counts = {"/" + topic: int(len(ts)) for topic, ts, _ in streams}
    other_info = cmd.other_info
    return {
        "path": str(out),
        "source": str(src),
        "source_sha256": _sha256(text),
        **_rows_summary(table),
        "columns_used": columns_used,
        "thrust_unit_in_log": thrust_unit,
        "thrust_factor_to_n": thrust_factor,
        "command": {"column": command.column if other_info is None else other_info["column"],
                    "file": None if other_info is None else other_info["path"],
                    "unit": cmd.unit, "mapping": mapping_text(cmd.unit)},
        "command_from": other_info,
        "alignment": None if cmd.alignment is None else cmd.alignment.as_dict(),
        "command_levels": sorted({round(float(x), 12) for x in cmd.level})[:50],
        "speed_source": source,
        "speed_assumption": speed_note,
        "pole_pairs": pole_pairs,
        "speed_check_power_over_torque_ratio": ratio,
        "speed_contradicted_by_thrust_s": [[sp.start_s, sp.stop_s] for sp in contradicted],
        "speed_left_out_s": [[sp.start_s, sp.stop_s] for sp in left_out],
        **_signal_ranges(frames, pwm, cols, cmd.unit, rpm),
        "topics": counts,
        "added_topics": ["/" + TOPIC_BATTERY_CURRENT] if "/" + TOPIC_BATTERY_CURRENT in counts else [],
        "messages": int(written),
        "warnings": warnings,
    }


def _write_bag(out: Path, force: bool, streams: list[tuple[str, np.ndarray, np.ndarray]], source: str) -> int:
    """The streams merged in time order into the bag at ``out``, after ``/import/source``; the
    number of messages written."""
    first_t = min(float(s[1].min()) for s in streams)
    with BagWriter(out, force=force, t0_ns=SIM_EPOCH_NS) as bag:
        bag.write_import_source(source, first_t)
        bag.write_merged(streams)
        return int(bag.messages_written)


def _whence(cmd: _CommandSource, other_src: Path | None) -> str:
    """Where the command came from, when not the log's own column (for ``/import/source``)."""
    return ("" if cmd.alignment is None or other_src is None
            else f" from {Path(other_src).name}'s Duty, shifted {cmd.alignment.offset_s:+.3f} s")


@dataclass
class _CommandSource:
    """The command as imported: its times (s, the log's clock) and PWM levels, its unit, and with
    ``--command-from`` the other file's alignment and summary (``rpm``: the log's speed per row,
    cut to the rows kept)."""

    t: np.ndarray
    level: np.ndarray
    unit: str
    rpm: np.ndarray | None
    alignment: Alignment | None = None
    other_info: dict[str, Any] | None = None


def _command_source(src: Path, other_src: Path | None, command: _Command, table: _Table,
                    rpm: np.ndarray | None) -> _CommandSource:
    """The log's own command column, or the ``--command-from`` file aligned to the log by speed;
    then only the log's rows within the other file's time span are kept (``table`` changes)."""
    if other_src is None:
        return _CommandSource(table.time, to_level(table.cols["esc"], command.unit), command.unit, rpm)
    other, alignment = _align_other(src, other_src, table, rpm)
    unit = "percent"  # the ESC32 utility logs Duty in %
    t_cmd, level_cmd = other.t + alignment.offset_s, to_level(other.duty_percent, unit)
    inside = (table.time >= t_cmd[0]) & (table.time <= t_cmd[-1])
    table.keep(inside, "outside_command_log")
    rpm = None if rpm is None else rpm[inside]
    if len(table.time) < 2:
        raise BadInputError(f"{src}: fewer than 2 rows within the time span of {other_src} (--command-from)")
    other_info = {"path": str(other_src), "rows": int(len(other.t)), "skipped_rows": other.skipped,
                  "first_timestamp": other.first_timestamp, "column": "Duty", "sha256": other.sha256}
    return _CommandSource(t_cmd, level_cmd, unit, rpm, alignment, other_info)


def _streams(t: np.ndarray, cols: dict[str, np.ndarray], frames: np.ndarray, pwm: np.ndarray,
             rpm: np.ndarray | None, thrust: np.ndarray | None) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(topic, times, values): one message per row with a value, /pwm per 50 Hz frame; topics
    with no value left out."""
    streams: list[tuple[str, np.ndarray, np.ndarray]] = [(c.TOPIC_PWM, frames, pwm)]
    if "voltage" in cols:
        streams.append((c.TOPIC_BATTERY_VOLTAGE, t, cols["voltage"]))
    if rpm is not None:
        streams.append((c.TOPIC_ROTOR_SPEED, t, rpm * RPM_TO_RAD_S))
    if thrust is not None:
        streams.append((c.TOPIC_THRUST_MEASURED, t, thrust))
    if "current" in cols:
        streams.append((TOPIC_BATTERY_CURRENT, t, cols["current"]))
    streams = [(topic, ts[np.isfinite(v)], v[np.isfinite(v)]) for topic, ts, v in streams]
    return [s for s in streams if len(s[1])]


def _data_warnings(src: Path, table: _Table, used: dict[str, str], rpm: np.ndarray | None, ratio: float | None,
                   source: str | None, speed_note: str, pole_pairs: int | None) -> list[str]:
    """What a user should check about the speed, voltage and thrust written (or not written)."""
    warnings: list[str] = []
    if ratio is not None and abs(ratio - 1.0) > SPEED_CHECK_TOLERANCE:
        hint = ("omit --pole-pairs" if source == "electrical" and pole_pairs is not None
                else "check --pole-pairs / the stand's pole-count setting")
        warnings.append(
            f"{src}: mechanical power / torque in the log is {ratio:.3g} x the written "
            f"/rotor/speed ({source} RPM); {hint}"
        )
    for role, topic in (("voltage", c.TOPIC_BATTERY_VOLTAGE), ("thrust", c.TOPIC_THRUST_MEASURED)):
        if role == "thrust" and role not in used and table.other_thrust:
            units = ", ".join(u for u, _ in THRUST_COLUMNS.values())
            warnings.append(f"{src}: column {table.other_thrust[0]!r}: thrust unit not one of {units}; "
                            f"/{topic} not written")
        elif role not in used:
            warnings.append(f"{src}: no {role} column; /{topic} not written")
    if rpm is None:
        warnings.append(f"{src}: {speed_note}")
    return warnings


def _rows_summary(table: _Table) -> dict[str, Any]:
    """The rows imported and skipped, and the time they span (``import_csv``'s summary)."""
    t = table.time
    return {
        "rows": int(len(t)),
        "skipped_rows": int(sum(table.skipped.values())),
        "skipped": dict(table.skipped),
        "first_line": int(table.lines[0]),
        "time_start_s": float(t[0]),
        "duration_s": float(t[-1] - t[0]),
        "mean_row_rate_hz": float((len(t) - 1) / (t[-1] - t[0])),
    }


def _signal_ranges(frames: np.ndarray, pwm: np.ndarray, cols: dict[str, np.ndarray], unit: str,
                   rpm: np.ndarray | None) -> dict[str, Any]:
    """The ranges of the command, speed and voltage written (``import_csv``'s summary)."""
    volts = cols["voltage"] if "voltage" in cols and np.any(np.isfinite(cols["voltage"])) else None
    return {
        "pwm_frames": int(len(frames)),
        "pwm_min": float(np.min(pwm)),
        "pwm_max": float(np.max(pwm)),
        "esc_us_levels": sorted({float(x) for x in cols["esc"]})[:50] if "esc" in cols and unit == "us" else [],
        "speed_max_rad_s": None if rpm is None or not np.any(np.isfinite(rpm))
        else float(np.nanmax(rpm) * RPM_TO_RAD_S),
        "voltage_min_v": None if volts is None else float(np.nanmin(volts)),
        "voltage_max_v": None if volts is None else float(np.nanmax(volts)),
    }


def summary_text(info: dict[str, Any]) -> str:
    """Human summary of what ``import_csv`` wrote."""
    lines = [
        f"wrote {info['path']}: {info['rows']} rows over {info['duration_s']:.2f} s "
        f"({info['skipped_rows']} skipped), {info['messages']} messages",
        f"  PWM {info['pwm_min']:.4f}..{info['pwm_max']:.4f} in {info['pwm_frames']} frames at 50 Hz",
        f"  speed: {info['speed_source'] or 'none'} ({info['speed_assumption']})",
    ]
    cmd = info.get("command")
    if cmd:
        where = f"{cmd['column']!r}" + (f" of {cmd['file']}" if cmd["file"] else "")
        lines.append(f"  command: {where} in {cmd['unit']}, {cmd['mapping']}")
    al = info.get("alignment")
    if al:
        share = al["speed_rms_share_of_range"]
        lines.append(
            f"  clocks aligned by speed: log time = {cmd['file'] if cmd else 'command file'} time "
            f"{al['offset_s']:+.3f} s (correlation {al['correlation']:.4f} over {al['overlap_s']:.1f} s; "
            f"speed RMS after the shift {al['speed_rms_rpm']:.0f} rpm"
            + (f" = {100 * share:.1f} % of the range)" if share is not None else ")"))
    if info.get("thrust_unit_in_log"):
        lines.append(f"  thrust: {info['columns_used']['thrust']!r} in {info['thrust_unit_in_log']}, "
                     f"x {info['thrust_factor_to_n']:.10g} -> N")
    if info.get("voltage_min_v") is not None:
        lines.append(f"  voltage {info['voltage_min_v']:.2f}..{info['voltage_max_v']:.2f} V")
    lines.append("  topics: " + ", ".join(f"{k} ({v})" for k, v in info["topics"].items()))
    return "\n".join(lines)
