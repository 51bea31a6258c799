"""ArduPilot DataFlash (.bin) -> ``FlightLog``, read with pymavlink's DFReader.

pymavlink is LGPL-3.0: an optional extra (``pip install bldc_propulsion[ardupilot]``), imported
only here, only when a DataFlash log is read, so that the package itself carries none of it.

Messages read (times from ``TimeUS``, us since boot):

- ``RCOU`` ``C1``..``C14``: the output pulse widths (us) of the servo channels; channel n is
  motor n-1. The motors are the channels whose ``SERVOn_FUNCTION`` parameter (logged in
  ``PARM``) is a motor function (33-40: Motor1-8, 82-85: Motor9-12); a log without those
  parameters has every channel with a pulse taken as a motor, with a warning;
- ``ESC`` ``Instance``, ``RPM``: ESC telemetry, mechanical RPM (ArduPilot converts the
  electrical RPM with SERVO_BLH_POLES); instance i is servo channel i+1, so motor i;
- ``BAT`` ``Volt``, ``Curr`` of the first battery (the lowest instance); without BAT, the
  voltage the lowest ESC instance reports, with a warning.
"""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import numpy as np

from ..errors import BadInputError, one_line
from .common import FlightLog, Series, pulse_levels, rpm_to_rad_s, select_motors

KIND = "ArduPilot DataFlash"
MAGIC = b"\xa3\x95"
#: SERVOn_FUNCTION values of motors: Motor1..Motor8, Motor9..Motor12.
MOTOR_FUNCTIONS = frozenset([*range(33, 41), *range(82, 86)])
RCOU_CHANNELS = 14
#: Most lines of what pymavlink printed that are kept as warnings.
_MAX_NOTES = 5


def _number(m: object, name: str) -> float:
    try:
        v = float(getattr(m, name))
    except (AttributeError, TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def _read(path: Path) -> tuple[dict[str, list[list[float]]], dict[str, float], list[str]]:
    """(the RCOU/ESC/BAT rows as lists, the PARM values, what pymavlink printed)."""
    try:
        from pymavlink import DFReader
    except ImportError:
        raise BadInputError(f"{path}: reading an ArduPilot DataFlash log needs pymavlink (LGPL-3.0, an "
                            "optional extra): pip install bldc_propulsion[ardupilot]") from None
    printed = io.StringIO()
    rows: dict[str, list[list[float]]] = {"RCOU": [], "ESC": [], "BAT": []}
    params: dict[str, float] = {}
    try:
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(printed):
            reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
            try:
                while True:
                    m = reader.recv_match(type=["RCOU", "ESC", "BAT", "PARM"])
                    if m is None:
                        break
                    kind = m.get_type()
                    if kind == "PARM":
                        params[str(m.Name)] = _number(m, "Value")
                        continue
                    t = _number(m, "TimeUS")
                    if kind == "RCOU":
                        rows[kind].append([t, *(_number(m, f"C{k}") for k in range(1, RCOU_CHANNELS + 1))])
                    elif kind == "ESC":
                        rows[kind].append([t, _number(m, "Instance"), _number(m, "RPM"), _number(m, "Volt")])
                    else:
                        inst = _number(m, "Instance") if "Instance" in m.fmt.colhash else _number(m, "Inst")
                        rows[kind].append([t, 0.0 if math.isnan(inst) else inst, _number(m, "Volt"),
                                           _number(m, "Curr")])
            finally:
                reader.close()
    except BadInputError:
        raise
    except Exception as exc:  # DFReader raises many types on a damaged file
        raise BadInputError(f"{path}: cannot read as an ArduPilot DataFlash log ({one_line(exc)})") from None
    lines = [line.strip() for line in printed.getvalue().splitlines() if line.strip()]
    notes = [f"{path}: pymavlink: {line}" for line in lines[:_MAX_NOTES]]
    if len(lines) > _MAX_NOTES:
        notes.append(f"{path}: pymavlink: ... {len(lines) - _MAX_NOTES} more line(s)")
    return rows, params, notes


def read_dataflash(path: Path, *, pole_count: int | None = None, motors: list[int] | None = None) -> FlightLog:
    """Read a DataFlash log; BadInputError (one line naming the file, message or option) on bad input."""
    if pole_count is not None:
        raise BadInputError(f"--pole-count {pole_count}: an ArduPilot log's ESC RPM is already the rotor's "
                            "mechanical RPM (ArduPilot applies SERVO_BLH_POLES); omit --pole-count")
    rows, params, warnings = _read(path)
    if not rows["RCOU"]:
        raise BadInputError(f"{path}: no RCOU messages (the motor outputs) in the DataFlash log")
    rcou = np.asarray(rows["RCOU"], dtype=float)
    t = rcou[:, 0] * 1e-6
    channel = {n - 1: rcou[:, n] for n in range(1, RCOU_CHANNELS + 1)}
    pulsing = [i for i, v in channel.items() if np.any(np.isfinite(v) & (v != 0))]
    functions = {n: params[f"SERVO{n}_FUNCTION"] for n in range(1, 33) if f"SERVO{n}_FUNCTION" in params}
    if functions:
        motor_channels = [n - 1 for n, f in functions.items() if f in MOTOR_FUNCTIONS]
        available = [i for i in motor_channels if i in pulsing]
        where = "the RCOU channels whose SERVOn_FUNCTION is a motor"
        how = "SERVOn_FUNCTION"
    else:
        available = pulsing
        where = "the RCOU channels"
        how = "every channel with a pulse (no SERVOn_FUNCTION in the log)"
        warnings.append(f"{path}: no SERVOn_FUNCTION parameters in the log: every RCOU channel with a pulse "
                        "taken as a motor (choose with --motors)")
    chosen = select_motors(path, available, motors, where)
    hint = "not a pulse width in us"
    commands = {i: Series(t, pulse_levels(path, f"RCOU C{i + 1}", channel[i], hint, warnings)) for i in chosen}

    speeds: dict[int, Series] = {}
    voltage = current = None
    volt_text = None
    esc = np.asarray(rows["ESC"], dtype=float).reshape(-1, 4)
    for i in chosen:
        mine = esc[esc[:, 1] == i]
        if len(mine) and np.any(np.isfinite(mine[:, 2])):
            speeds[i] = Series(mine[:, 0] * 1e-6, rpm_to_rad_s(np.abs(mine[:, 2])))
    if not speeds:
        warnings.append(f"{path}: no ESC telemetry RPM for the imported motors: no rotor/speed written")
    bat = np.asarray(rows["BAT"], dtype=float).reshape(-1, 4)
    if len(bat):
        first = bat[bat[:, 1] == np.min(bat[:, 1])]
        voltage = Series(first[:, 0] * 1e-6, first[:, 2])
        current = Series(first[:, 0] * 1e-6, first[:, 3])
        volt_text = "BAT Volt -> battery/voltage"
        if not len(current.t):
            current = None
    elif len(esc) and np.any(np.isfinite(esc[:, 3])):
        first = esc[esc[:, 1] == np.min(esc[:, 1])]
        voltage = Series(first[:, 0] * 1e-6, first[:, 3])
        volt_text = f"ESC {int(first[0, 1])} Volt -> battery/voltage (no BAT messages)"
        warnings.append(f"{path}: no BAT messages: the battery voltage is the one ESC {int(first[0, 1])} reports")
    if voltage is not None and not len(voltage.t):
        voltage, volt_text = None, None

    poles = params.get("SERVO_BLH_POLES")
    mapping = [
        "RCOU Cn us / 20000 us -> pwm level of motor n-1, held on 50 Hz frames",
        ("ESC RPM (mechanical" + (f", SERVO_BLH_POLES={poles:g}" if poles is not None else "")
         + ") of instance i -> rotor/speed rad/s of motor i") if speeds else "no ESC RPM: no rotor/speed",
    ]
    if volt_text:
        mapping.append(volt_text)
    if current is not None:
        mapping.append("BAT Curr -> battery/current")
    return FlightLog(
        path=path, kind=KIND, commands=commands, speeds=speeds, voltage=voltage, current=current,
        rows=int(len(t)),
        command_mapping=f"imported from {KIND} {path.name}: " + "; ".join(mapping),
        speed_source="ESC RPM (mechanical RPM)" if speeds else None,
        warnings=warnings,
        details={"motors_from": how, "pole_count": None, "servo_blh_poles": poles},
    )
