"""What the flight-log importers share: the unit mappings and the motors table -> bag writing.

A flight controller logs the motor commands in its ESC protocol's units (DShot 48..2047, PWM
microseconds, PX4's normalised 0..1), the rotor speed from ESC telemetry (electrical or
mechanical RPM), and the pack's voltage and current, each at its own rate. Every reader turns
its format into a ``FlightLog`` in the contract's units (PWM level, rad/s, V, A) and states the
mapping it applied in one sentence; ``write_recording`` writes that as a vehicle recording
(interfaces.md, "A quadrotor"):

| topic | type | content |
|---|---|---|
| ``/import/source`` | String | the mapping sentence, once at the start (``info`` prints it) |
| ``/motorN/pwm`` | Float64 | PWM level, the command in force at each 50 Hz frame (zero-order hold, as import-csv) |
| ``/motorN/rotor/speed`` | Float64 | rad/s, one per telemetry sample |
| ``/battery/voltage`` | BatteryState | V, at the root (one pack) |
| ``/battery/current`` | Float64 | A, at the root; an added topic, as import-csv writes it |

N is the motor's index in the log (0-based), so that ``--namespace motorN`` names the same
motor the log does. Bag times are the log's times minus its earliest one, from a fixed epoch,
so the same log always makes the same bag.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import numpy as np

from .. import contract as c
from ..bagio import SIM_EPOCH_NS, BagWriter
from ..core.features import zero_order_hold
from ..errors import BadInputError
from ..training.import_csv import ESC_MAX_US, ESC_MIN_US, RPM_TO_RAD_S, TOPIC_BATTERY_CURRENT

#: DShot throttle values: 0 is the motor-stop command, 1-47 are special commands.
DSHOT_MIN = 48
DSHOT_MAX = 2047
#: Most motors a flight log names (Betaflight logs up to 8, ArduPilot's RCOU 14, PX4 12-16).
MAX_MOTORS = 16
#: Tolerance of a frame time against a row logged at the same instant (logs count in us).
_SAME_INSTANT_S = 0.5e-6


# --- command and speed mappings ------------------------------------------------------------
def dshot_to_level(value: np.ndarray) -> np.ndarray:
    """DShot throttle 48..2047 -> PWM level 0.05..0.10 (0 % .. 100 % throttle, linear); below
    48 (the stop command and special commands) the motor is stopped: 0.05."""
    v = np.asarray(value, dtype=float)
    frac = np.clip((v - DSHOT_MIN) / (DSHOT_MAX - DSHOT_MIN), 0.0, 1.0)
    return c.PWM_STOP + (c.PWM_FULL - c.PWM_STOP) * frac


def us_to_level(us: np.ndarray) -> np.ndarray:
    """Pulse width (us) -> PWM level: pulse / the 20 ms frame, as the bench records it."""
    return np.asarray(us, dtype=float) / c.PWM_PERIOD_US


def normalized_to_level(x: np.ndarray) -> np.ndarray:
    """PX4's normalised motor command 0..1 -> PWM level 0.05..0.10; NaN (disarmed) -> 0.05,
    below 0 (reverse thrust of a reversible motor) -> 0.05."""
    v = np.nan_to_num(np.asarray(x, dtype=float), nan=0.0)
    return c.PWM_STOP + (c.PWM_FULL - c.PWM_STOP) * np.clip(v, 0.0, 1.0)


def erpm_hundreds_to_rad_s(value: np.ndarray, pole_count: int) -> np.ndarray:
    """Betaflight's logged eRPM (electrical RPM / 100) -> rotor rad/s: x 100 / pole pairs."""
    return np.asarray(value, dtype=float) * 100.0 / (pole_count // 2) * RPM_TO_RAD_S


def rpm_to_rad_s(rpm: np.ndarray) -> np.ndarray:
    """Mechanical (shaft) RPM -> rad/s."""
    return np.asarray(rpm, dtype=float) * RPM_TO_RAD_S


def check_pulse_widths(path: Path, what: str, us: np.ndarray, hint: str) -> None:
    """BadInputError when a column said to hold ESC pulse widths holds something else."""
    v = us[np.isfinite(us)]
    bad = v[(v < ESC_MIN_US) | (v > ESC_MAX_US)]
    if len(bad):
        raise BadInputError(f"{path}: {what}: {bad[0]:g} is outside {ESC_MIN_US:g}..{ESC_MAX_US:g} us, "
                            f"not an ESC pulse width ({hint})")


def pulse_levels(path: Path, what: str, us: np.ndarray, hint: str, warnings: list[str]) -> np.ndarray:
    """Logged output pulse widths (us) -> PWM level. A 0 is an output sending no pulse (a
    flight stack logs it before arming or with the output disabled): the ESC stops, 0.05."""
    us = np.asarray(us, dtype=float)
    zero = us == 0
    check_pulse_widths(path, what, us[~zero], hint)
    if np.any(zero):
        warnings.append(f"{path}: {what} is 0 (no pulse) in {int(np.count_nonzero(zero))} sample(s): "
                        "taken as stopped, 0.05")
    return np.where(zero, c.PWM_STOP, us_to_level(us))


# --- options -------------------------------------------------------------------------------
def parse_motors(text: str | None) -> list[int] | None:
    """``--motors 0,1,2,3`` -> [0, 1, 2, 3]; None -> None (every motor with data)."""
    if text is None:
        return None
    out: list[int] = []
    for item in text.split(","):
        item = item.strip()
        if not item.isdigit() or int(item) >= MAX_MOTORS:
            raise BadInputError(f"--motors {text}: {item!r} is not a motor index 0..{MAX_MOTORS - 1} "
                                "(a comma-separated list such as 0,1,2,3)")
        if int(item) in out:
            raise BadInputError(f"--motors {text}: motor {item} is listed twice")
        out.append(int(item))
    return out


def check_pole_count(pole_count: int | None) -> int | None:
    """The motor's magnet poles: an even whole number (a 12N14P motor has 14 poles, 7 pairs)."""
    if pole_count is None:
        return None
    if isinstance(pole_count, bool) or int(pole_count) != pole_count or pole_count < 2 or pole_count % 2:
        raise BadInputError(f"--pole-count {pole_count}: must be an even whole number >= 2 "
                            "(the motor's magnet poles, e.g. 14 for a 12N14P motor)")
    return int(pole_count)


def select_motors(path: Path, available: list[int], wanted: list[int] | None, where: str) -> list[int]:
    """The motors to import: ``wanted`` (--motors) if each is in the log, else all available."""
    if not available:
        raise BadInputError(f"{path}: {where} hold no motor command")
    if wanted is None:
        return sorted(available)
    missing = [m for m in wanted if m not in available]
    if missing:
        raise BadInputError(f"--motors {','.join(map(str, wanted))}: motor {missing[0]} has no command "
                            f"in {path} (motors with data: {','.join(map(str, sorted(available)))})")
    return list(wanted)


def increasing(t: np.ndarray) -> np.ndarray:
    """Mask of the rows whose time is after every earlier row's (a duplicate or a clock that went
    back keeps the first), and finite."""
    t = np.asarray(t, dtype=float)
    fin = np.isfinite(t)
    prev = np.maximum.accumulate(np.where(fin, t, -np.inf))
    before = np.concatenate([[-np.inf], prev[:-1]])
    return fin & (t > before)


# --- the table and its bag -----------------------------------------------------------------
@dataclass
class Series:
    """One logged signal: times (s, on the log's own clock) and values (contract units)."""

    t: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float)
        self.values = np.asarray(self.values, dtype=float)
        keep = increasing(self.t) & np.isfinite(self.values)
        self.t, self.values = self.t[keep], self.values[keep]


class LogDetails(TypedDict, total=False):
    """``FlightLog.details``: what an importer adds to the summary, by format."""

    pole_count: int | None  #: the magnet poles eRPM was divided by (Betaflight); None: none needed
    motor_protocol: str | None  #: Betaflight: how motor values were read (dshot, pwm)
    motor_protocol_from: str  #: Betaflight: why
    skipped_rows: int  #: Betaflight
    header_lines: int  #: Betaflight
    motors_from: str  #: ArduPilot: how the motors were found
    servo_blh_poles: float | None  #: ArduPilot's SERVO_BLH_POLES, if logged
    command_topic: str  #: PX4: actuator_motors or actuator_outputs
    mot_pole_count: float | None  #: PX4's MOT_POLE_COUNT, if logged


@dataclass
class FlightLog:
    """What a reader found in a log, in the contract's units."""

    path: Path
    kind: str  #: e.g. "Betaflight CSV"
    commands: dict[int, Series]  #: motor index -> PWM level
    speeds: dict[int, Series]  #: motor index -> rotor rad/s
    voltage: Series | None
    current: Series | None
    rows: int  #: rows (or messages) of the motor-command table
    command_mapping: str  #: one sentence: which fields became which topics, in which units
    speed_source: str | None  #: e.g. "eRPM (electrical RPM / 100) / 7 pole pairs"; None = no speed
    warnings: list[str] = field(default_factory=list)
    details: LogDetails = field(default_factory=lambda: LogDetails())  #: format-specific summary


def _frames(t: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """50 Hz frames from the first to the last command and the command in force at each."""
    n = int(math.floor((t[-1] - t[0]) * c.PWM_FRAME_HZ + 1e-9)) + 1
    frames = t[0] + np.arange(n) / c.PWM_FRAME_HZ
    return frames, zero_order_hold(t, level, frames + _SAME_INSTANT_S)


class ImportSummary(LogDetails):
    """``write_recording``: what ``import-log --json`` prints (and the format's ``LogDetails``)."""

    path: str
    source: str
    format: str
    rows: int
    motors: list[int]
    duration_s: float
    command_mapping: str
    speed_source: str | None
    motors_with_speed: list[int]
    pwm_frames: int
    pwm_range: dict[str, dict[str, float] | None]  #: motor -> min, max
    speed_max_rad_s: dict[str, float]
    voltage_v: dict[str, float] | None  #: min, max
    current_a: dict[str, float] | None
    topics: dict[str, int]  #: topic -> messages
    messages: int
    warnings: list[str]


def write_recording(log: FlightLog, out_path: str | os.PathLike[str], *, force: bool = False) -> ImportSummary:
    """Write ``log`` as a vehicle recording at ``out_path`` (see the module's table); returns
    the summary that ``import-log --json`` prints."""
    out = Path(out_path)
    for m, s in log.commands.items():
        if len(s.t) < 2:
            raise BadInputError(f"{log.path}: motor {m} has {len(s.t)} usable command sample(s); "
                                "at least 2 are needed")
    series = [*log.commands.values(), *log.speeds.values(),
              *(s for s in (log.voltage, log.current) if s is not None)]
    t0 = min(float(s.t[0]) for s in series if len(s.t))

    streams: list[tuple[str, np.ndarray, np.ndarray]] = []
    frames_written = 0
    for m in sorted(log.commands):
        frames, level = _frames(log.commands[m].t - t0, log.commands[m].values)
        frames_written = max(frames_written, len(frames))
        streams.append((f"motor{m}/{c.TOPIC_PWM}", frames, level))
    for m in sorted(log.speeds):
        streams.append((f"motor{m}/{c.TOPIC_ROTOR_SPEED}", log.speeds[m].t - t0, log.speeds[m].values))
    if log.voltage is not None:
        streams.append((c.TOPIC_BATTERY_VOLTAGE, log.voltage.t - t0, log.voltage.values))
    if log.current is not None:
        streams.append((TOPIC_BATTERY_CURRENT, log.current.t - t0, log.current.values))
    streams = [s for s in streams if len(s[1])]

    with BagWriter(out, force=force, t0_ns=SIM_EPOCH_NS) as bag:
        bag.write_import_source(log.command_mapping, 0.0)
        bag.write_merged(streams)
        written = bag.messages_written

    def span(s: Series | None) -> dict[str, float] | None:
        return None if s is None or not len(s.values) else {"min": float(s.values.min()), "max": float(s.values.max())}

    warnings = list(log.warnings)
    if log.voltage is None:
        warnings.append(f"{log.path}: no battery voltage in the log: /{c.TOPIC_BATTERY_VOLTAGE} not written "
                        "(train, evaluate and discrepancy need it)")
    return {
        "path": str(out),
        "source": str(log.path),
        "format": log.kind,
        "rows": int(log.rows),
        "motors": sorted(log.commands),
        "duration_s": max(float(s[1].max()) for s in streams),
        "command_mapping": log.command_mapping,
        "speed_source": log.speed_source,
        "motors_with_speed": sorted(log.speeds),
        "pwm_frames": int(frames_written),
        "pwm_range": {f"motor{m}": span(s) for m, s in sorted(log.commands.items())},
        "speed_max_rad_s": {f"motor{m}": float(s.values.max()) for m, s in sorted(log.speeds.items()) if len(s.values)},
        "voltage_v": span(log.voltage),
        "current_a": span(log.current),
        "topics": {"/" + topic: int(len(ts)) for topic, ts, _ in streams},
        "messages": int(written),
        **log.details,
        "warnings": warnings,
    }


def summary_text(info: ImportSummary) -> str:
    """Human summary of what ``import-log`` wrote."""
    lines = [
        f"wrote {info['path']}: {info['format']}, {info['rows']} rows over {info['duration_s']:.2f} s, "
        f"{info['messages']} messages",
        f"  {info['command_mapping']}",
        f"  motors: {', '.join(f'motor{m}' for m in info['motors'])}; speed: "
        + (f"{info['speed_source']} ({', '.join(f'motor{m}' for m in info['motors_with_speed'])})"
           if info["speed_source"] else "none"),
    ]
    volts = info.get("voltage_v")
    if volts:
        lines.append(f"  battery voltage {volts['min']:.2f}..{volts['max']:.2f} V")
    lines.append(f"  read one motor with --namespace motor{info['motors'][0]}")
    return "\n".join(lines)
