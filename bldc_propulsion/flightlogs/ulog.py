"""PX4 ULog (.ulg) -> ``FlightLog``, read with pyulog (BSD-3, the ``px4`` extra).

Topics read (instance 0 of each; times are the messages' ``timestamp``, us since boot):

- motor commands: ``actuator_motors`` ``control[i]`` when logged (PX4 >= 1.13: normalised
  0..1 whatever the ESC protocol, NaN when disarmed; -1..0 only for reversible motors), else
  ``actuator_outputs`` ``output[i]`` (pulse widths in us for PWM outputs; other outputs, e.g.
  DShot's 0..1999, are refused rather than guessed);
- rotor speed: ``esc_status`` ``esc[i].esc_rpm``, mechanical RPM (PX4 converts the ESC's
  electrical RPM with its MOT_POLE_COUNT parameter), so no pole count is asked for;
- battery: ``battery_status`` ``voltage_filtered_v`` when logged (older PX4), else
  ``voltage_v`` (already filtered in newer PX4), and ``current_a`` (negative = not measured).

Motor i is ``control[i]`` / ``output[i]`` and ``esc[i]``: PX4 numbers ESCs as its motors.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import BadInputError, one_line
from .common import FlightLog, Series, normalized_to_level, pulse_levels, rpm_to_rad_s, select_motors

if TYPE_CHECKING:
    from pyulog import ULog  # an optional extra (pip install bldc_propulsion[px4]), without type information

KIND = "PX4 ULog"
MAGIC = b"ULog\x01\x12\x35"
TOPICS = ("actuator_motors", "actuator_outputs", "esc_status", "battery_status")


def _load(path: Path) -> tuple[ULog, list[str]]:
    """The parsed log and what pyulog printed (it prints warnings on stdout, which belongs to --json)."""
    try:
        from pyulog import ULog
    except ImportError:
        raise BadInputError(f"{path}: reading a PX4 ULog needs pyulog: pip install bldc_propulsion[px4]") from None
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            ulog = ULog(str(path), message_name_filter_list=list(TOPICS), disable_str_exceptions=True)
    except Exception as exc:  # ULogException, and whatever a damaged file makes pyulog raise
        raise BadInputError(f"{path}: cannot read as a PX4 ULog ({one_line(exc)})") from None
    notes = [f"{path}: pyulog: {line.strip()}" for line in printed.getvalue().splitlines() if line.strip()]
    if ulog.file_corruption:
        notes.append(f"{path}: the ULog is corrupt in places; pyulog skipped what it could not parse")
    return ulog, notes


def _dataset(ulog: ULog, name: str) -> dict[str, np.ndarray] | None:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0 and len(d.data.get("timestamp", ())):
            return d.data
    return None


def _indexed(data: dict[str, np.ndarray], pattern: str) -> dict[int, np.ndarray]:
    """{i: data[pattern.format(i)]} for every i the message has."""
    out = {}
    i = 0
    while pattern.format(i) in data:
        out[i] = np.asarray(data[pattern.format(i)], dtype=float)
        i += 1
    return out


def read_ulog(path: Path, *, pole_count: int | None = None, motors: list[int] | None = None) -> FlightLog:
    """Read a ULog; BadInputError (one line naming the file, topic or option) on bad input."""
    if pole_count is not None:
        raise BadInputError(f"--pole-count {pole_count}: a PX4 log's esc_status esc_rpm is already the "
                            "rotor's mechanical RPM (PX4 applies MOT_POLE_COUNT); omit --pole-count")
    ulog, warnings = _load(path)
    params = getattr(ulog, "initial_parameters", {}) or {}

    commands, rows, command_text, command_topic = _commands(path, ulog, motors, warnings)

    speeds: dict[int, Series] = {}
    esc = _dataset(ulog, "esc_status")
    if esc is not None:
        t = esc["timestamp"] * 1e-6
        rpm = _indexed(esc, "esc[{}].esc_rpm")
        count = int(np.max(esc["esc_count"])) if "esc_count" in esc else len(rpm)
        for i in commands:
            if i in rpm and i < count:
                speeds[i] = Series(t, rpm_to_rad_s(np.abs(rpm[i])))
    if not speeds:
        warnings.append(f"{path}: no esc_status esc_rpm for the imported motors: no rotor/speed written")

    voltage, current, volt_field = _battery(ulog)

    mapping = [command_text + ", held on 50 Hz frames",
               "esc_status esc[i].esc_rpm (mechanical RPM) -> rotor/speed rad/s" if speeds
               else "no esc_rpm: no rotor/speed"]
    if "MOT_POLE_COUNT" in params:
        mapping[-1] += f" (PX4's MOT_POLE_COUNT={params['MOT_POLE_COUNT']})"
    if voltage is not None:
        mapping.append(f"battery_status {volt_field} -> battery/voltage")
    if current is not None:
        mapping.append("battery_status current_a -> battery/current")
    return FlightLog(
        path=path, kind=KIND, commands=commands, speeds=speeds, voltage=voltage, current=current,
        rows=int(rows),
        command_mapping=f"imported from {KIND} {path.name}: " + "; ".join(mapping) + "; motor i -> /motor<i>",
        speed_source="esc_status esc_rpm (mechanical RPM)" if speeds else None,
        warnings=warnings,
        details={"command_topic": command_topic, "pole_count": None,
                 "mot_pole_count": params.get("MOT_POLE_COUNT")},
    )


def _commands(path: Path, ulog: ULog, motors: list[int] | None,
              warnings: list[str]) -> tuple[dict[int, Series], int, str, str]:
    """The chosen motors' commands as PWM levels: from actuator_motors when it was ever armed, else
    actuator_outputs; with the rows read, how they were mapped (in words) and the topic."""
    motors_msg = _dataset(ulog, "actuator_motors")
    outputs_msg = _dataset(ulog, "actuator_outputs")
    if motors_msg is not None and outputs_msg is not None and not any(
            np.any(np.isfinite(v)) for v in _indexed(motors_msg, "control[{}]").values()):
        motors_msg = None  # never armed by the control allocation: the outputs may still say something
    commands: dict[int, Series] = {}
    if motors_msg is not None:
        t = motors_msg["timestamp"] * 1e-6
        control = _indexed(motors_msg, "control[{}]")
        with_data = [i for i, v in control.items() if np.any(np.isfinite(v))]
        chosen = select_motors(path, with_data, motors, "actuator_motors control[i] (NaN throughout: never armed?)")
        reverse = [i for i in chosen if np.any(control[i] < 0)]
        if reverse:
            warnings.append(f"{path}: actuator_motors control[{reverse[0]}] goes below 0 (reverse thrust of a "
                            "reversible motor): taken as stopped, 0.05")
        commands = {i: Series(t, normalized_to_level(control[i])) for i in chosen}
        rows = len(t)
        command_text = ("actuator_motors control[i] 0..1 -> pwm level 0.05-0.10 (NaN, disarmed: 0.05)")
        command_topic = "actuator_motors"
    elif outputs_msg is not None:
        t = outputs_msg["timestamp"] * 1e-6
        output = _indexed(outputs_msg, "output[{}]")
        count = int(np.max(outputs_msg["noutputs"])) if "noutputs" in outputs_msg else len(output)
        with_data = [i for i, v in output.items() if i < count and np.any(np.isfinite(v) & (v != 0))]
        chosen = select_motors(path, with_data, motors, "actuator_outputs output[i]")
        commands = {i: Series(t, pulse_levels(path, f"actuator_outputs output[{i}]", output[i],
                                              "DShot or CAN outputs are not in us; log actuator_motors "
                                              "instead", warnings))
                    for i in chosen}
        rows = len(t)
        command_text = "actuator_outputs output[i] us / 20000 us -> pwm level"
        command_topic = "actuator_outputs"
    else:
        raise BadInputError(f"{path}: no actuator_motors or actuator_outputs messages (the motor commands) in the ULog")
    return commands, rows, command_text, command_topic



def _battery(ulog: ULog) -> tuple[Series | None, Series | None, str | None]:
    """The battery's voltage (the filtered one where logged) and current, each None when not
    measured, and the voltage's field."""
    voltage = current = None
    volt_field = None
    bat = _dataset(ulog, "battery_status")
    if bat is not None:
        t = bat["timestamp"] * 1e-6
        for name in ("voltage_filtered_v", "voltage_v"):
            if name in bat and np.any(bat[name] > 0):
                volt_field = name
                v = np.asarray(bat[name], dtype=float)
                voltage = Series(t, np.where(v > 0, v, np.nan))  # 0: no battery measured yet
                break
        if "current_a" in bat:
            a = np.asarray(bat["current_a"], dtype=float)
            current = Series(t, np.where(a >= 0, a, np.nan))  # -1: not measured
            if not len(current.t):
                current = None
    return voltage, current, volt_field
