"""Betaflight blackbox CSV (``blackbox_decode`` or Blackbox Explorer's export) -> ``FlightLog``.

Columns read: ``time (us)`` (Explorer: ``time``, also microseconds), ``motor[0]``..``motor[N-1]``
(the motor output: DShot 48..2047 with 0 = motor stop, or 1000..2000 us for PWM, Oneshot and
Multishot ESCs), ``eRPM[i]`` (bidirectional-DShot telemetry, logged as electrical RPM / 100:
Betaflight's own conversion is rpm = eRPM x 100 / (motor_poles / 2), as Blackbox Explorer shows
it), ``vbatLatest (V)`` and ``amperageLatest (A)`` (``blackbox_decode``'s default units; mV and mA
too). Explorer's export writes the log's header as ``"key","value"`` lines before the column
header and vbat/amperage without a unit (their scale depends on the firmware version): those
are not converted, with a warning.

The electrical/mechanical distinction is the classic unit trap (a 14-pole motor reads 7x too
fast), so eRPM is only turned into a speed with an explicit ``pole_count``. The binary ``.bbl``
/ ``.bfl`` files are not read: export them to CSV first.
"""

from __future__ import annotations

import csv
import re
from array import array
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from ..errors import BadInputError

if TYPE_CHECKING:
    import _csv  # the type csv.reader returns (typeshed's name for it)
from ..training.import_csv import _norm
from .common import (
    DSHOT_MAX,
    FlightLog,
    Series,
    check_pulse_widths,
    dshot_to_level,
    erpm_hundreds_to_rad_s,
    increasing,
    select_motors,
    us_to_level,
)

KIND = "Betaflight CSV"
#: How a binary blackbox log (.bbl, .bfl, .TXT) starts.
BBL_MAGIC = b"H Product:Blackbox flight data recorder"
BBL_REFUSAL = ("is a binary Betaflight blackbox log, which is not read: export it to CSV with "
               "Blackbox Explorer or blackbox_decode and import the CSV")
PROTOCOLS = ("dshot", "pwm")

TIME_COLUMNS = ("time (us)", "time")  # blackbox_decode, Blackbox Explorer: both microseconds
VOLTAGE_COLUMNS = {"vbatLatest (V)": 1.0, "vbatLatest (mV)": 1e-3}
CURRENT_COLUMNS = {"amperageLatest (A)": 1.0, "amperageLatest (mA)": 1e-3}
_MOTOR = re.compile(r"motor\[(\d+)\]")
_ERPM = re.compile(r"erpm\[(\d+)\]", re.IGNORECASE)
#: Explorer writes a few hundred header lines before the column header.
HEADER_SEARCH_LINES = 5000
#: Below any PWM-family output and above DShot's range: values outside it mean DShot.
_PWM_LOW_US, _PWM_HIGH_US = 900.0, 2100.0
#: Betaflight's motor protocol numbers (header ``motor_pwm_protocol``): 0-4 pulse-width
#: protocols (PWM, Oneshot125, Oneshot42, Multishot, brushed), 5-8 digital (DShot150/300/600,
#: ProShot1000).
_DIGITAL_PROTOCOLS = range(5, 9)
_PULSE_PROTOCOLS = range(0, 5)


def is_blackbox_binary(head: bytes) -> bool:
    return head.lstrip(b"\xef\xbb\xbf").startswith(BBL_MAGIC)


def looks_like_csv(head: bytes) -> bool:
    """True when the first bytes of a file hold a Betaflight CSV column header."""
    text = head.decode("utf-8", errors="replace").lower()
    return "motor[0]" in text and ("time (us)" in text or '"time"' in text or "time," in text)


def _open_rows(path: Path) -> tuple[TextIO, _csv.Reader]:
    try:
        with open(path, "rb") as raw:
            head = raw.read(4096)
    except OSError as exc:
        raise BadInputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if is_blackbox_binary(head):
        raise BadInputError(f"{path}: {BBL_REFUSAL}")
    if not head.strip():
        raise BadInputError(f"{path}: file is empty")
    if b"\x00" in head:
        raise BadInputError(f"{path}: binary file, not a Betaflight blackbox CSV")
    fh = open(path, encoding="utf-8-sig", newline="")  # noqa: SIM115 - closed by the caller
    return fh, csv.reader(fh, skipinitialspace=True)


def _protocol_from_header(meta: dict[str, str]) -> tuple[str | None, str]:
    """(protocol, why) from the log header Explorer exports, (None, '') when it does not say."""
    for key in ("motor_pwm_protocol", "fast_pwm_protocol"):
        value = meta.get(key)
        if value is None:
            continue
        name = value.strip().upper()
        if name.isdigit():
            number = int(name)
            if number in _DIGITAL_PROTOCOLS:
                return "dshot", f"header {key}={value}"
            if number in _PULSE_PROTOCOLS:
                return "pwm", f"header {key}={value}"
        elif "DSHOT" in name or "PROSHOT" in name:
            return "dshot", f"header {key}={value}"
        elif name.startswith(("PWM", "ONESHOT", "MULTISHOT", "BRUSHED", "STANDARD")):
            return "pwm", f"header {key}={value}"
    output = meta.get("motorOutput")
    if output:
        numbers = [int(x) for x in re.findall(r"\d+", output)]
        if len(numbers) >= 2:
            return ("dshot" if numbers[1] > _PWM_HIGH_US else "pwm"), f"header motorOutput={output}"
    return None, ""


def read_betaflight_csv(
    path: Path,
    *,
    pole_count: int | None = None,
    motors: list[int] | None = None,
    motor_protocol: str | None = None,
) -> FlightLog:
    """Read a blackbox CSV; BadInputError (one line naming the file, column or option) on bad input."""
    if motor_protocol is not None and motor_protocol not in PROTOCOLS:
        raise BadInputError(f"--motor-protocol {motor_protocol}: must be one of {', '.join(PROTOCOLS)}")
    fh, reader = _open_rows(path)
    try:
        meta, header = _header(path, reader)
        index = {}
        for k, name in enumerate(header):
            n = _norm(name)
            if n and n not in index:
                index[n] = k
        time_col = next(name for name in TIME_COLUMNS if name in index)
        # (a walrus in a comprehension binds in this function: `found`, not the motors' `m`)
        motor_cols = {int(found.group(1)): name for name in index if (found := _MOTOR.fullmatch(name))}
        erpm_cols = {int(found.group(1)): name for name in index if (found := _ERPM.fullmatch(name))}
        volt_col = next((name for name in VOLTAGE_COLUMNS if name in index), None)
        amp_col = next((name for name in CURRENT_COLUMNS if name in index), None)
        columns = [time_col, *motor_cols.values(), *erpm_cols.values(),
                   *(x for x in (volt_col, amp_col) if x is not None)]
        data = _numbers(path, reader, [index[name] for name in columns], columns)
    except UnicodeDecodeError as exc:
        raise BadInputError(f"{path}: not a UTF-8 CSV text file (undecodable byte at offset {exc.start})") from None
    except csv.Error as exc:
        raise BadInputError(f"{path}: line {reader.line_num}: not valid CSV ({exc})") from None
    finally:
        fh.close()
    col = {name: data[:, k] for k, name in enumerate(columns)}

    t_us = col[time_col]
    keep = increasing(t_us)
    skipped = int(len(t_us) - np.count_nonzero(keep))
    t = t_us[keep] * 1e-6
    if len(t) < 2:
        raise BadInputError(f"{path}: {len(t)} usable row(s) with a time; at least 2 are needed")
    warnings: list[str] = []
    if skipped:
        warnings.append(f"{path}: {skipped} row(s) without a time or not after the previous one skipped")

    with_data = [m for m, name in motor_cols.items() if np.any(np.isfinite(col[name][keep]))]
    if motor_cols and not with_data:
        names = ", ".join(motor_cols[m] for m in sorted(motor_cols))
        raise BadInputError(f"{path}: the motor columns ({names}) hold no values")
    chosen = select_motors(path, with_data, motors, "the motor columns")
    raw = {m: col[motor_cols[m]][keep] for m in chosen}

    protocol, why = _choose_protocol(path, raw, motor_protocol, meta, warnings)
    commands = _commands(path, t, raw, motor_cols, protocol)
    erpm = {m: col[erpm_cols[m]][keep] for m in chosen if m in erpm_cols}
    speeds, speed_source = _speeds(path, t, erpm, pole_count, meta, warnings)

    voltage = current = None
    if volt_col is not None:
        voltage = Series(t, col[volt_col][keep] * VOLTAGE_COLUMNS[volt_col])
    elif "vbatLatest" in index:
        warnings.append(f"{path}: column 'vbatLatest' has no unit (Blackbox Explorer's raw export: "
                        "0.1 V or 0.01 V by firmware version); not converted: decode with "
                        "blackbox_decode for 'vbatLatest (V)'")
    if amp_col is not None:
        current = Series(t, col[amp_col][keep] * CURRENT_COLUMNS[amp_col])

    return FlightLog(
        path=path, kind=KIND, commands=commands, speeds=speeds, voltage=voltage, current=current,
        rows=int(len(t)),
        command_mapping=_mapping(path, protocol, pole_count if speeds else None, volt_col, amp_col),
        speed_source=speed_source, warnings=warnings,
        details={"motor_protocol": protocol, "motor_protocol_from": why, "pole_count": pole_count,
                 "skipped_rows": skipped, "header_lines": len(meta)},
    )


def _commands(path: Path, t: np.ndarray, raw: dict[int, np.ndarray], motor_cols: dict[int, str],
              protocol: str) -> dict[int, Series]:
    """Each chosen motor's output as PWM levels; BadInputError on a value the protocol cannot hold."""
    commands: dict[int, Series] = {}
    for m, v in raw.items():
        name = motor_cols[m]
        if protocol == "dshot":
            fin = v[np.isfinite(v)]
            bad = fin[(fin < 0) | (fin > DSHOT_MAX)]
            if len(bad):
                raise BadInputError(f"{path}: column {name!r}: {bad[0]:g} is outside DShot 0..{DSHOT_MAX} "
                                    "(give --motor-protocol pwm if the ESCs took PWM)")
            commands[m] = Series(t, dshot_to_level(v))
        else:
            check_pulse_widths(path, f"column {name!r}", v,
                               "give --motor-protocol dshot if the ESCs took DShot")
            commands[m] = Series(t, us_to_level(v))
    return commands


def _speeds(path: Path, t: np.ndarray, erpm: dict[int, np.ndarray], pole_count: int | None,
            meta: dict[str, str], warnings: list[str]) -> tuple[dict[int, Series], str | None]:
    """The chosen motors' speeds from their eRPM columns (``erpm``, the kept rows) and where they
    came from; BadInputError when there are some and no ``pole_count`` (``warnings`` gets what
    to check)."""
    speeds: dict[int, Series] = {}
    erpm_with_data = [m for m, v in erpm.items() if np.any(np.isfinite(v))]
    if not erpm_with_data:
        warnings.append(f"{path}: no eRPM column with data (bidirectional DShot telemetry not "
                        "logged): no rotor/speed written")
        if pole_count is not None:
            warnings.append(f"{path}: --pole-count {pole_count} not used (no eRPM column)")
        return speeds, None
    if pole_count is None:
        raise BadInputError(
            f"{path}: the log has eRPM columns (electrical RPM / 100, from bidirectional DShot): "
            "give --pole-count (the motor's magnet poles, e.g. 14) so that they can be turned into "
            "the rotor's speed")
    logged = meta.get("motor_poles")
    if logged and logged.strip().isdigit() and int(logged) != pole_count:
        warnings.append(f"{path}: --pole-count {pole_count} differs from the log header's "
                        f"motor_poles={logged} (Betaflight's own setting)")
    for m in erpm_with_data:
        speeds[m] = Series(t, erpm_hundreds_to_rad_s(erpm[m], pole_count))
    return speeds, f"eRPM (electrical RPM / 100) x 100 / {pole_count // 2} pole pairs"


def _mapping(path: Path, protocol: str, pole_count: int | None, volt_col: str | None, amp_col: str | None) -> str:
    """How the columns were turned into the recording's topics, in words (``pole_count``: None
    when no speed was written)."""
    mapping = [
        ("motor[i] DShot 48-2047 -> pwm level 0.05-0.10 (below 48: stop, 0.05)" if protocol == "dshot"
         else "motor[i] PWM 1000-2000 us / 20000 us -> pwm level 0.05-0.10") + ", held on 50 Hz frames",
        (f"eRPM[i] (eRPM/100) x 100 / {pole_count // 2} pole pairs -> rotor/speed rad/s"
         if pole_count is not None else "no eRPM: no rotor/speed"),
    ]
    if volt_col is not None:
        mapping.append(f"{volt_col} -> battery/voltage")
    if amp_col is not None:
        mapping.append(f"{amp_col} -> battery/current")
    return f"imported from {KIND} {path.name}: " + "; ".join(mapping) + "; motor[i] -> /motor<i>"


def _header(path: Path, reader: _csv.Reader) -> tuple[dict[str, str], list[str]]:
    """(the ``"key","value"`` lines before the column header, the column header)."""
    meta: dict[str, str] = {}
    for row in reader:
        names = {_norm(cell) for cell in row}
        if "motor[0]" in names and any(name in names for name in TIME_COLUMNS):
            return meta, row
        if len(row) >= 2 and row[0].strip():
            meta.setdefault(row[0].strip(), row[1].strip())
        if reader.line_num >= HEADER_SEARCH_LINES:
            break
    raise BadInputError(f"{path}: no column header with 'time (us)' and 'motor[0]' in its first "
                        f"{HEADER_SEARCH_LINES} lines; not a Betaflight blackbox CSV")


def _numbers(path: Path, reader: _csv.Reader, cols: list[int], names: list[str]) -> np.ndarray:
    """The given columns of every data row as floats (empty or NaN cell -> NaN); a flat array of
    doubles while reading, so that a long high-rate log costs 8 bytes per value."""
    flat = array("d")
    width = len(cols)
    for row in reader:
        if not row or not any(cell.strip() for cell in row):
            continue
        values = [float("nan")] * width
        for j, k in enumerate(cols):
            cell = row[k].strip() if k < len(row) else ""
            if not cell or cell.lower() == "nan":
                continue
            try:
                v = float(cell)
            except ValueError:
                raise BadInputError(f"{path}: line {reader.line_num}, column {names[j]!r}: "
                                    f"{cell[:40]!r} is not a number") from None
            if not np.isfinite(v):
                raise BadInputError(f"{path}: line {reader.line_num}, column {names[j]!r}: {cell!r} is not finite")
            values[j] = v
        flat.extend(values)
    return np.frombuffer(flat, dtype=float).reshape(-1, width).copy()


def _choose_protocol(path: Path, raw: dict[int, np.ndarray], option: str | None, meta: dict[str, str],
                     warnings: list[str]) -> tuple[str, str]:
    """The ESC protocol of the motor values: the option, else the log header, else the values."""
    header, why = _protocol_from_header(meta)
    if option is not None:
        if header is not None and header != option:
            warnings.append(f"{path}: --motor-protocol {option} overrides the log's {why}")
        return option, "--motor-protocol"
    if header is not None:
        return header, why
    values = np.concatenate([v[np.isfinite(v)] for v in raw.values()])
    if np.any(values < _PWM_LOW_US) or np.any(values > _PWM_HIGH_US):
        return "dshot", "values outside the PWM range 900-2100"
    warnings.append(f"{path}: every motor value lies in {_PWM_LOW_US:g}..{_PWM_HIGH_US:g}: taken as "
                    "PWM microseconds; give --motor-protocol dshot if the ESCs took DShot")
    return "pwm", "values inside the PWM range 900-2100"
