"""RCbenchmark / Tyto Robotics thrust-stand CSV log -> rosbag2 bag with the contract's topics.

A commercial stand logs what this project's bench records, in other units and at its own
rate: the ESC command in microseconds, the supply voltage, current, thrust (N or kgf) and
speed (electrical and/or optical RPM), one row per sample (~4-50 Hz). The importer turns
such a log into a bag that ``train``, ``evaluate`` and ``discrepancy`` read like a bench
recording:

| topic | type | content |
|---|---|---|
| ``/pwm`` | Float64 | ESC us / 20000 us, zero-order hold of the logged command on a 50 Hz frame grid |
| ``/battery/voltage`` | BatteryState | supply voltage, one per row with a voltage (measured directly, so already the filtered battery voltage) |
| ``/rotor/speed`` | Float64 | rad/s, from optical RPM if it has data, else electrical RPM |
| ``/thrust/measured`` | Float64 | N (kgf x 9.80665 when the log is in kgf) |
| ``/battery/current`` | Float64 | A; an *addition* to the contract (it allows added topics), for thermal states |

Speed from the electrical column: the RCbenchmark software converts the commutation
frequency to shaft RPM with the pole count entered in its setup, so the column it writes is
already mechanical RPM (checked on real logs: its own ``Mechanical Power (W)`` equals
``Torque (N·m)`` x that column). ``pole_pairs`` is only for logs that hold raw electrical RPM
(commutation RPM = shaft RPM x pole pairs); the returned dict says which source and which
assumption were used, and warns when the speed disagrees with mechanical power / torque.

Bag times are ``t0_ns + row time`` with a fixed ``t0_ns`` so the output is reproducible.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as c
from ..atomic import RECORDING, check_output
from ..bagio import SIM_EPOCH_NS, BagWriter
from ..errors import BadInputError

#: Added topic (not in the contract's tables): supply current in amperes.
TOPIC_BATTERY_CURRENT = "battery/current"

KGF_TO_N = 9.80665
RPM_TO_RAD_S = 2.0 * math.pi / 60.0
ESC_MIN_US = 800.0  #: below any servo-protocol pulse: the column is not an ESC pulse width
ESC_MAX_US = 2200.0
#: Relative disagreement between the written speed and mechanical power / torque that warns.
SPEED_CHECK_TOLERANCE = 0.10

COL_TIME = "Time (s)"
COL_ESC = "ESC signal (µs)"
COL_VOLTAGE = "Voltage (V)"
COL_CURRENT = "Current (A)"
COL_THRUST_N = "Thrust (N)"
COL_THRUST_KGF = "Thrust (kgf)"
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


def _header_index(path: Path, header: list[str]) -> dict[str, int]:
    index: dict[str, int] = {}
    for k, name in enumerate(header):
        n = _norm(name)
        if n and n not in index:  # trailing comma -> empty name: ignored; duplicates: first wins
            index[n] = k
    for required in (COL_TIME, COL_ESC):
        if required not in index:
            found = [n for n in index][:15]
            more = ", ..." if len(index) > 15 else ""
            shown = ", ".join(repr(n) for n in found) + more if found else "no column names"
            raise BadInputError(
                f"{path}: no {required!r} column; not an RCbenchmark/Tyto log? (found: {shown})"
            )
    return index


def _parse(path: Path, text: str) -> tuple[_Table, dict[str, str]]:
    """Numeric table of the usable rows; BadInputError on the first bad cell."""
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader)
        while not any(cell.strip() for cell in header):
            header = next(reader)
    except StopIteration:
        raise BadInputError(f"{path}: no header row") from None
    except csv.Error as exc:
        raise BadInputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None
    index = _header_index(path, header)

    used = {"time": COL_TIME, "esc": COL_ESC}
    for role, name in (("voltage", COL_VOLTAGE), ("current", COL_CURRENT),
                       ("rpm_electrical", COL_RPM_ELECTRICAL), ("rpm_optical", COL_RPM_OPTICAL)):
        if name in index:
            used[role] = name
    if COL_THRUST_N in index:
        used["thrust"] = COL_THRUST_N
    elif COL_THRUST_KGF in index:
        used["thrust"] = COL_THRUST_KGF
    # only for a consistency check of the speed: never fail on these
    checks = {role: name for role, name in (("torque", COL_TORQUE), ("mech_power", COL_MECH_POWER))
              if name in index}

    values: dict[str, list[float]] = {role: [] for role in (*used, *checks)}
    lines: list[int] = []
    skipped = {"no_time_or_esc": 0, "time_not_increasing": 0}
    last_t = -math.inf
    try:
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue  # blank line
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
            t, esc = cells["time"], cells["esc"]
            if math.isnan(t) or math.isnan(esc):
                skipped["no_time_or_esc"] += 1  # app-message rows and the like
                continue
            if not ESC_MIN_US <= esc <= ESC_MAX_US:
                raise BadInputError(
                    f"{path}: line {line}, column {COL_ESC!r}: {esc:g} us is outside "
                    f"{ESC_MIN_US:g}..{ESC_MAX_US:g} us (not an ESC pulse width)"
                )
            if t <= last_t:
                skipped["time_not_increasing"] += 1  # duplicate or backwards: keep the first
                continue
            last_t = t
            lines.append(line)
            for role in values:
                values[role].append(cells[role])
    except csv.Error as exc:
        raise BadInputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None

    if len(lines) < 2:
        raise BadInputError(
            f"{path}: {len(lines)} usable row(s) with a time and an ESC signal; at least 2 are needed"
        )
    cols = {role: np.asarray(v, dtype=float) for role, v in values.items()}
    table = _Table(time=cols.pop("time"), cols=cols, lines=np.asarray(lines), skipped=skipped)
    return table, used


def _pwm_frames(t: np.ndarray, esc_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """50 Hz frame times from the first to the last row and the ESC command held at each."""
    n = int(math.floor((t[-1] - t[0]) * c.PWM_FRAME_HZ + 1e-9)) + 1
    frames = t[0] + np.arange(n) / c.PWM_FRAME_HZ
    # the command in force at a frame is the last logged one at or before it (zero-order hold)
    k = np.searchsorted(t, frames + 1e-9, side="right") - 1
    return frames, esc_us[np.clip(k, 0, len(t) - 1)] / c.PWM_PERIOD_US


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


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def import_csv(
    csv_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    force: bool = False,
    pole_pairs: int | None = None,
) -> dict[str, Any]:
    """Convert a thrust-stand CSV log into a bag at ``out_path``; returns a summary dict.

    ``pole_pairs`` (None: the electrical speed column is already shaft RPM, as the RCbenchmark
    software writes it) divides a raw commutation-RPM column. Raises ``BadInputError`` (one line
    naming the file) on bad input and when ``out_path`` may not be written (atomic.check_output);
    nothing is written then.
    """
    src, out = Path(csv_path), Path(out_path)
    if pole_pairs is not None and (isinstance(pole_pairs, bool) or int(pole_pairs) != pole_pairs
                                   or pole_pairs < 1):
        raise BadInputError(f"--pole-pairs {pole_pairs}: must be a positive integer")
    check_output(out, RECORDING, force=force, inputs=[src])
    text = _read_text(src)
    table, used = _parse(src, text)
    t = table.time
    cols = table.cols

    frames, pwm = _pwm_frames(t, cols["esc"])
    source, rpm, speed_note = _speed(table, pole_pairs)
    thrust = cols.get("thrust")
    if thrust is not None and used["thrust"] == COL_THRUST_KGF:
        thrust = thrust * KGF_TO_N

    # (topic, times, values): one message per row with a value, /pwm per 50 Hz frame
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
    streams = [s for s in streams if len(s[1])]

    times = np.concatenate([s[1] for s in streams])
    which = np.concatenate([np.full(len(s[1]), k) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s[1])) for s in streams])
    order = np.lexsort((which, times))  # message-time order, as a recorder writes it
    with BagWriter(out, force=force, t0_ns=SIM_EPOCH_NS) as bag:
        for k in order:
            topic, ts, vs = streams[which[k]]
            i = index[k]
            if topic == c.TOPIC_BATTERY_VOLTAGE:
                bag.write_battery_state(topic, float(ts[i]), float(vs[i]))
            else:
                bag.write_float64(topic, float(ts[i]), float(vs[i]))
        written = bag.messages_written

    columns_used = {role: name for role, name in used.items()
                    if not role.startswith("rpm_") or role == f"rpm_{source}"}
    warnings: list[str] = []
    ratio = _speed_check(table, rpm)
    if ratio is not None and abs(ratio - 1.0) > SPEED_CHECK_TOLERANCE:
        hint = ("omit --pole-pairs" if source == "electrical" and pole_pairs is not None
                else "check --pole-pairs / the stand's pole-count setting")
        warnings.append(
            f"{src}: mechanical power / torque in the log is {ratio:.3g} x the written "
            f"/rotor/speed ({source} RPM); {hint}"
        )
    for role, topic in (("voltage", c.TOPIC_BATTERY_VOLTAGE), ("thrust", c.TOPIC_THRUST_MEASURED)):
        if role not in used:
            warnings.append(f"{src}: no {role} column; /{topic} not written")
    if rpm is None:
        warnings.append(f"{src}: {speed_note}")
    counts = {"/" + topic: int(len(ts)) for topic, ts, _ in streams}
    skipped_total = int(sum(table.skipped.values()))
    return {
        "path": str(out),
        "source": str(src),
        "source_sha256": _sha256(text),
        "rows": int(len(t)),
        "skipped_rows": skipped_total,
        "skipped": dict(table.skipped),
        "first_line": int(table.lines[0]),
        "time_start_s": float(t[0]),
        "duration_s": float(t[-1] - t[0]),
        "mean_row_rate_hz": float((len(t) - 1) / (t[-1] - t[0])),
        "columns_used": columns_used,
        "thrust_unit_in_log": None if thrust is None else ("kgf" if used["thrust"] == COL_THRUST_KGF else "N"),
        "speed_source": source,
        "speed_assumption": speed_note,
        "pole_pairs": pole_pairs,
        "speed_check_power_over_torque_ratio": ratio,
        "pwm_frames": int(len(frames)),
        "pwm_min": float(np.min(pwm)),
        "pwm_max": float(np.max(pwm)),
        "esc_us_levels": sorted({float(x) for x in cols["esc"]})[:50],
        "speed_max_rad_s": None if rpm is None or not np.any(np.isfinite(rpm))
        else float(np.nanmax(rpm) * RPM_TO_RAD_S),
        "voltage_min_v": float(np.nanmin(cols["voltage"])) if "voltage" in cols and np.any(np.isfinite(cols["voltage"])) else None,
        "voltage_max_v": float(np.nanmax(cols["voltage"])) if "voltage" in cols and np.any(np.isfinite(cols["voltage"])) else None,
        "topics": counts,
        "added_topics": ["/" + TOPIC_BATTERY_CURRENT] if "/" + TOPIC_BATTERY_CURRENT in counts else [],
        "messages": int(written),
        "warnings": warnings,
    }


def summary_text(info: dict[str, Any]) -> str:
    """Human summary of what ``import_csv`` wrote."""
    lines = [
        f"wrote {info['path']}: {info['rows']} rows over {info['duration_s']:.2f} s "
        f"({info['skipped_rows']} skipped), {info['messages']} messages",
        f"  PWM {info['pwm_min']:.4f}..{info['pwm_max']:.4f} in {info['pwm_frames']} frames at 50 Hz",
        f"  speed: {info['speed_source'] or 'none'} ({info['speed_assumption']})",
    ]
    if info.get("voltage_min_v") is not None:
        lines.append(f"  voltage {info['voltage_min_v']:.2f}..{info['voltage_max_v']:.2f} V")
    lines.append("  topics: " + ", ".join(f"{k} ({v})" for k, v in info["topics"].items()))
    return "\n".join(lines)
