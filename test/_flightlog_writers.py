"""Small flight logs of each format, written from the simulator, for the import-log tests.

A simulated quadrotor (four motors, each simulated on the bench with its own command
staircase) is written as a Betaflight blackbox CSV, a PX4 ULog and an ArduPilot DataFlash
.bin, each in its own units (DShot values, eRPM / 100, mechanical RPM, microseconds), so the
importer's output can be checked against the simulator's truth. The binary formats are written
by hand from their specifications (ULog: header, FLAG_BITS 'B', FORMAT 'F', INFO 'I',
PARAMETER 'P', ADD_LOGGED 'A', DATA 'D'; DataFlash: 0xA3 0x95 + type, FMT messages then data),
not with the readers' libraries, so the readers are checked against the formats themselves.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bldc_propulsion.sim import simulate

RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
#: Step times (s) of every motor's command: multiples of 0.1 s, so that every log's rows and the
#: 50 Hz frames fall on them.
STEP_TIMES = np.array([0.0, 0.5, 1.3, 2.2])


@dataclass
class Vehicle:
    """Four motors on one pack: commands (PWM level, steps) and the simulator's truth at 1 kHz."""

    duration_s: float
    cmd_t: np.ndarray
    cmd_level: list[np.ndarray]  #: per motor, the level from each STEP_TIMES on
    truth_t: np.ndarray
    speed: list[np.ndarray]  #: per motor, rad/s
    voltage: np.ndarray  #: pack terminal voltage (V), motor 0's simulation
    current: np.ndarray  #: the four motors' currents (A)

    @property
    def motors(self) -> int:
        return len(self.cmd_level)

    def command(self, m: int, t: np.ndarray) -> np.ndarray:
        """The level commanded to motor m at times t (the step in force; a step at t counts)."""
        k = np.searchsorted(self.cmd_t, np.asarray(t) + 1e-9, side="right") - 1
        return self.cmd_level[m][np.clip(k, 0, None)]

    def speed_at(self, m: int, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.truth_t, self.speed[m])

    def voltage_at(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.truth_t, self.voltage)

    def current_at(self, t: np.ndarray) -> np.ndarray:
        return np.interp(t, self.truth_t, self.current)


def simulate_vehicle(duration_s: float = 3.0, seed: int = 0, motors: int = 4) -> Vehicle:
    """Each motor: stopped (armed, 0.05) for 0.5 s, then three levels that differ per motor."""
    levels, speeds, currents = [], [], []
    voltage = None
    truth_t = None
    for m in range(motors):
        lv = np.array([0.05, 0.062 + 0.004 * m, 0.080 - 0.003 * m, 0.070 + 0.002 * m])
        res = simulate("vehicle", duration_s, seed + m, pwm=(STEP_TIMES, lv))
        levels.append(lv)
        speeds.append(res.truth_speed)
        currents.append(res.truth_current)
        if voltage is None:
            voltage, truth_t = res.truth_voltage, res.truth_t
    return Vehicle(duration_s=duration_s, cmd_t=STEP_TIMES, cmd_level=levels, truth_t=truth_t,
                   speed=speeds, voltage=voltage, current=np.sum(currents, axis=0))


def _times(duration_s: float, rate_hz: float) -> np.ndarray:
    """Row times k / rate (s) inside the simulation, whole microseconds."""
    n = int(math.floor(duration_s * rate_hz - 1e-9))
    return np.round(np.arange(n) / rate_hz * 1e6) * 1e-6


def dshot_value(level: np.ndarray) -> np.ndarray:
    """PWM level -> Betaflight's logged DShot value: 0 (the stop command) at 0.05, else
    48 + 1999 x throttle, rounded as the firmware's integer output."""
    level = np.asarray(level, dtype=float)
    return np.where(level <= 0.05, 0, np.round(48 + (level - 0.05) / 0.05 * 1999)).astype(int)


# --- Betaflight blackbox CSV -------------------------------------------------------------
def write_betaflight_csv(path: Path, v: Vehicle, *, pole_count: int = 14, rate_hz: float = 500.0,
                         protocol: str = "dshot", erpm: bool = True, explorer_header: bool = True,
                         boot_us: int = 3_000_000, empty_motors: bool = False) -> Path:
    """The CSV blackbox_decode writes (", " between cells, unit suffixes), after the
    ``"key","value"`` header lines Blackbox Explorer's export starts with."""
    t = _times(v.duration_s, rate_hz)
    cols = ["loopIteration", "time (us)", "axisP[0]"]
    cols += [f"motor[{m}]" for m in range(v.motors)]
    if erpm:
        cols += [f"eRPM[{m}]" for m in range(v.motors)]
    cols += ["vbatLatest (V)", "amperageLatest (A)"]
    lines = []
    if explorer_header:
        lines += ['"Product","Blackbox flight data recorder by Nicholas Sherlock"',
                  '"Firmware revision","Betaflight 4.4.2 (025a6b3d6) STM32F7X2"',
                  f'"motor_poles","{pole_count}"', '"looptime","125"']
    lines.append(", ".join(cols))
    motor = []
    for m in range(v.motors):
        lv = v.command(m, t)
        motor.append(dshot_value(lv) if protocol == "dshot" else np.round(lv * 20000).astype(int))
    erpm_values = [np.round(v.speed_at(m, t) * RPM_PER_RAD_S * (pole_count // 2) / 100).astype(int)
                   for m in range(v.motors)]
    volts, amps = v.voltage_at(t), v.current_at(t)
    for k, tk in enumerate(t):
        row = [str(k * 4), str(boot_us + int(round(tk * 1e6))), "3"]
        row += ["" if empty_motors else str(motor[m][k]) for m in range(v.motors)]
        if erpm:
            row += [str(erpm_values[m][k]) for m in range(v.motors)]
        row += [f"{volts[k]:.2f}", f"{amps[k]:.2f}"]
        lines.append(", ".join(row))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# --- PX4 ULog ------------------------------------------------------------------------------
_ULOG_MAGIC = b"ULog\x01\x12\x35"


def _ulog_msg(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _ulog_key(type_name: str, key: str, value: bytes) -> bytes:
    k = f"{type_name} {key}".encode()
    return struct.pack("<B", len(k)) + k + value


def write_ulog(path: Path, v: Vehicle, *, command_topic: str = "actuator_motors", boot_us: int = 20_000_000,
               command_hz: float = 100.0, esc_hz: float = 50.0, battery_hz: float = 10.0) -> Path:
    """actuator_motors (control[i] 0..1, NaN while disarmed: before the first step) or
    actuator_outputs (output[i] in us), esc_status (esc[i].esc_rpm, mechanical RPM) and
    battery_status (voltage_v, current_a); every timestamp is boot_us + the simulation time.
    The formats end in padding fields, whose bytes PX4's logger leaves out of the data."""
    formats = [
        ("actuator_motors", "uint64_t timestamp;uint64_t timestamp_sample;float[12] control;"
                            "uint16_t reversible_flags;uint8_t[6] _padding0;"),
        ("actuator_outputs", "uint64_t timestamp;uint32_t noutputs;float[16] output;uint8_t[4] _padding0;"),
        ("esc_report", "uint64_t timestamp;uint32_t esc_errorcount;int32_t esc_rpm;float esc_voltage;"
                       "float esc_current;"),
        ("esc_status", "uint64_t timestamp;uint16_t counter;uint8_t esc_count;uint8_t esc_connectiontype;"
                       "uint8_t esc_online_flags;uint8_t esc_armed_flags;esc_report[8] esc;"),
        ("battery_status", "uint64_t timestamp;float voltage_v;float current_a;float remaining;"
                           "uint8_t connected;uint8_t[3] _padding0;"),
    ]
    out = bytearray(_ULOG_MAGIC + b"\x01" + struct.pack("<Q", boot_us))
    out += _ulog_msg("B", bytes(40))  # FLAG_BITS: no compat/incompat flags, no appended data
    out += _ulog_msg("I", _ulog_key("char[3]", "sys_name", b"PX4"))
    for name, fields in formats:
        out += _ulog_msg("F", f"{name}:{fields}".encode())
    out += _ulog_msg("P", _ulog_key("int32_t", "MOT_POLE_COUNT", struct.pack("<i", 14)))
    topics = [command_topic, "esc_status", "battery_status"]
    for msg_id, name in enumerate(topics):
        out += _ulog_msg("A", struct.pack("<BH", 0, msg_id) + name.encode())

    records: list[tuple[int, int, bytes]] = []  # (timestamp, msg_id, payload)
    t = _times(v.duration_s, command_hz)
    for tk in t:
        ts = boot_us + int(round(tk * 1e6))
        levels = [float(v.command(m, np.array([tk]))[0]) for m in range(v.motors)]
        if command_topic == "actuator_motors":
            armed = tk >= STEP_TIMES[1] - 1e-9
            control = [(lv - 0.05) / 0.05 if armed else math.nan for lv in levels]
            control += [math.nan] * (12 - len(control))
            payload = struct.pack("<QQ12fH", ts, ts, *control, 0)
        else:
            output = [round(lv * 20000) for lv in levels] + [0.0] * (16 - len(levels))
            payload = struct.pack("<QI16f", ts, v.motors, *output)
        records.append((ts, 0, payload))
    t = _times(v.duration_s, esc_hz)
    for k, tk in enumerate(t):
        ts = boot_us + int(round(tk * 1e6))
        payload = struct.pack("<QHBBBB", ts, k % 65536, v.motors, 1, 0x0F, 0x0F)
        for m in range(8):
            rpm = int(round(float(v.speed_at(m, np.array([tk]))[0]) * RPM_PER_RAD_S)) if m < v.motors else 0
            payload += struct.pack("<QIiff", ts, 0, rpm, 0.0, 0.0)
        records.append((ts, 1, payload))
    t = _times(v.duration_s, battery_hz)
    for tk in t:
        ts = boot_us + int(round(tk * 1e6))
        payload = struct.pack("<QfffB", ts, float(v.voltage_at(tk)), float(v.current_at(tk)), 0.9, 1)
        records.append((ts, 2, payload))
    for _ts, msg_id, payload in sorted(records, key=lambda r: (r[0], r[1])):
        out += _ulog_msg("D", struct.pack("<H", msg_id) + payload)
    path.write_bytes(bytes(out))
    return path


# --- ArduPilot DataFlash -------------------------------------------------------------------
_DF_HEAD = b"\xa3\x95"
_DF_STRUCT = {"Q": "Q", "B": "B", "H": "H", "f": "f", "N": "16s", "c": "h", "Z": "64s", "n": "4s"}


def _df_struct(fmt: str) -> struct.Struct:
    return struct.Struct("<" + "".join(_DF_STRUCT[ch] for ch in fmt))


def write_dataflash(path: Path, v: Vehicle, *, boot_us: int = 7_000_000, rcou_hz: float = 50.0,
                    esc_hz: float = 50.0, battery_hz: float = 10.0, servo_functions: bool = True) -> Path:
    """FMT messages, PARM (SERVOn_FUNCTION: 33-36 = Motor1-4 on channels 1-4, channel 5 a
    pass-through servo at 1500 us; SERVO_BLH_POLES), then RCOU (C1..C14 us), ESC (one message
    per instance, mechanical RPM) and BAT in time order."""
    defs = {  # name: (type id, format, columns) as ArduPilot 4.5 logs them
        "PARM": (64, "QNff", "TimeUS,Name,Value,Default"),
        "RCOU": (34, "Q" + "H" * 14, "TimeUS," + ",".join(f"C{k}" for k in range(1, 15))),
        "ESC": (99, "QBffffcfcf", "TimeUS,Instance,RPM,RawRPM,Volt,Curr,Temp,CTot,MotTemp,Err"),
        "BAT": (70, "QBfffffcfBBB", "TimeUS,Inst,Volt,VoltR,Curr,CurrTot,EnrgTot,Temp,Res,RemPct,H,SH"),
    }
    fmt_struct = _df_struct("BBnNZ")
    out = bytearray(_DF_HEAD + bytes([128]) + fmt_struct.pack(128, 89, b"FMT", b"BBnNZ",
                                                              b"Type,Length,Name,Format,Columns"))
    packers = {}
    for name, (tid, fmt, columns) in defs.items():
        packers[name] = (tid, _df_struct(fmt))
        length = 3 + packers[name][1].size
        out += _DF_HEAD + bytes([128]) + fmt_struct.pack(tid, length, name.encode(), fmt.encode(), columns.encode())

    def msg(name: str, *values: object) -> bytes:
        tid, st = packers[name]
        return _DF_HEAD + bytes([tid]) + st.pack(*values)

    params = {"SERVO_BLH_POLES": 14.0}
    if servo_functions:
        params.update({f"SERVO{n}_FUNCTION": float(32 + n) for n in range(1, v.motors + 1)})
        params[f"SERVO{v.motors + 1}_FUNCTION"] = 1.0  # RCPassThru: a servo, not a motor
    for name, value in params.items():
        out += msg("PARM", boot_us, name.encode(), value, value)

    records: list[tuple[int, int, bytes]] = []
    for tk in _times(v.duration_s, rcou_hz):
        ts = boot_us + int(round(tk * 1e6))
        channels = [int(round(float(v.command(m, np.array([tk]))[0]) * 20000)) for m in range(v.motors)]
        channels += [1500] + [0] * (14 - v.motors - 1)
        records.append((ts, 0, msg("RCOU", ts, *channels)))
    for tk in _times(v.duration_s, esc_hz):
        ts = boot_us + int(round(tk * 1e6))
        for m in range(v.motors):
            rpm = float(v.speed_at(m, np.array([tk]))[0]) * RPM_PER_RAD_S
            records.append((ts, 1 + m, msg("ESC", ts, m, rpm, rpm * 7, float(v.voltage_at(tk)) - 0.1, 1.0,
                                           3000, 0.1, 2500, 0.0)))
    for tk in _times(v.duration_s, battery_hz):
        ts = boot_us + int(round(tk * 1e6))
        records.append((ts, 10, msg("BAT", ts, 0, float(v.voltage_at(tk)), float(v.voltage_at(tk)) + 0.2,
                                    float(v.current_at(tk)), 0.0, 0.0, 2500, 0.02, 90, 0, 0)))
    for _, _, data in sorted(records, key=lambda r: (r[0], r[1])):
        out += data
    path.write_bytes(bytes(out))
    return path
