"""What a recording holds and what it can be used for (`bldc-propulsion info`, commands/info.py).

In the spirit of ``ros2 bag info``, before any training: topics with types, counts, rates and
gaps; the PWM and battery-voltage ranges; whether the tachometer decodes (the tachometer core,
as every command decodes it); and which commands can use the recording. The reading is
bagio's; "can it be used" is answered by loading it exactly as train/evaluate/discrepancy do,
so the answer and its reason are theirs.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal, TypedDict

import numpy as np

from . import contract as c
from .bagio import TOPIC_IMPORT_SOURCE, open_recording
from .errors import BadInputError, one_line

#: A recorded speed or command sampled slower than this cannot show the rotor's transients (a
#: spin-up time constant is tens of milliseconds): ``info`` says what the recording cannot resolve.
SLOW_RATE_HZ = 20.0


def _interval(t: np.ndarray) -> float | None:
    """The typical sample interval (s): the median step, robust to a gap or a burst."""
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(np.median(dt)) if len(dt) else None


def _resolution(speed_dt: float | None, command_dt: float | None) -> str | None:
    """What a slowly sampled speed or command cannot resolve (None: it is fast enough). Two
    samples per time constant or dead time is about the least that shows one."""
    slow = [(what, dt) for what, dt in (("measured speed", speed_dt), ("command", command_dt))
            if dt is not None and dt > 1.0 / SLOW_RATE_HZ]
    if not slow:
        return None
    worst = max(dt for _, dt in slow)
    sampled = " and ".join(f"the {what} every {dt:.3g} s ({1.0 / dt:.3g} Hz)" for what, dt in slow)
    return (f"{sampled}: time constants and dead times shorter than about {2 * worst:.2g} s are not "
            "resolved (rotor_lag, input_delay, the step response's shape); the static map (speed vs "
            "command and voltage) is fine")


def _range(values: np.ndarray) -> dict[str, float] | None:
    v = values[np.isfinite(values)]
    return {"min": float(v.min()), "max": float(v.max())} if len(v) else None


class TopicInfo(TypedDict):
    """One topic of ``RecordingInfo.topics`` (``bagio.TopicStats``)."""

    topic: str
    type: str
    count: int
    rate_hz: float
    gaps: int
    max_gap_s: float


class TachometerInfo(TypedDict):
    decodes: bool
    speeds: int  #: speeds the tachometer decoded (the rotor moving)
    max_rad_s: float


class _InfoCore(TypedDict):
    path: str
    namespace: str | None
    duration_s: float
    messages: int
    damaged: str | None
    topics: list[TopicInfo]
    namespaces: list[str]
    pwm: dict[str, float] | None  #: min, max
    battery_voltage_v: dict[str, float | str] | None  #: min, max (where valid), source
    tachometer: TachometerInfo | None
    speed_rad_s: dict[str, float | str] | None  #: min, max (where valid), source, gaps (count), gaps_s (s)
    import_source: list[str]
    sample_interval_s: dict[str, float | None]  #: speed, command: where sampled (not sent on change)


class RecordingInfo(_InfoCore, total=False):
    """``recording_info``: what ``info --json`` says of one recording (the keys below are added
    once the recording is read)."""

    motors_elsewhere: list[str]
    usable_for: list[str]
    not_usable: dict[str, str]  #: command -> why not
    problems: dict[str, str]  #: what could not be read -> why
    resolution: str | None


def recording_info(path: str, namespace: str | None = None) -> RecordingInfo:
    """Everything ``info --json`` says of one recording (see the module's docstring)."""
    from .recordings import decode_speed, read_speed, read_speed_gaps, read_voltage

    with open_recording(path, namespace) as rec:
        stats = rec.topic_stats()
        out: RecordingInfo = {
            "path": str(path),
            "namespace": rec.namespace,
            "duration_s": rec.duration_s,
            "messages": rec.message_count,
            "damaged": rec.salvaged or rec.read_error,
            "topics": [{"topic": s.topic, "type": s.msgtype, "count": s.count, "rate_hz": s.rate_hz,
                        "gaps": s.gaps, "max_gap_s": s.max_gap_s} for s in stats],
            "namespaces": rec.namespaces_with(c.TOPIC_PWM),
            "pwm": None, "battery_voltage_v": None, "tachometer": None, "speed_rad_s": None,
            "import_source": [],  # how an imported log's units were mapped (import-csv, import-log)
            "sample_interval_s": {"speed": None, "command": None},  # of recorded signals; see _resolution
        }
        problems: dict[str, str] = {}

        def attempt(key: str, read: Callable[[], None]) -> None:
            try:
                read()
            except BadInputError as exc:
                problems[key] = one_line(exc)

        def pwm() -> None:
            if not rec.has(c.TOPIC_PWM):
                return
            t, v = rec.scalars(c.TOPIC_PWM)
            out["pwm"] = _range(v)
            # a command published on change never repeats a value and is exact however rarely it
            # comes; one sampled by a logger repeats the held value, and its timing is the interval
            if len(v) > 2 and np.any(np.diff(v) == 0):
                out["sample_interval_s"]["command"] = _interval(t)

        def voltage() -> None:
            _, v, source = read_voltage(rec)
            out["battery_voltage_v"] = {**(_range(v) or {}), "source": source}

        def tach() -> None:
            if rec.has(c.TOPIC_TACH_ADC):
                _, v = decode_speed(rec)  # the tachometer's own speeds, even where rotor/speed is recorded
                moving = v[v > 0]
                out["tachometer"] = {"decodes": bool(len(moving)), "speeds": int(len(moving)),
                                     "max_rad_s": float(moving.max()) if len(moving) else 0.0}

        def speed() -> None:
            t, v, source = read_speed(rec)
            gaps = read_speed_gaps(rec, t)
            out["speed_rad_s"] = {**(_range(v) or {}), "source": source, "gaps": len(gaps),
                                  "gaps_s": sum(b - a for a, b in gaps)}
            if rec.has(c.TOPIC_ROTOR_SPEED):  # decoded tachometer speeds come once per revolution
                out["sample_interval_s"]["speed"] = _interval(t)

        def import_notes() -> None:
            out["import_source"] = rec.texts(TOPIC_IMPORT_SOURCE)

        if not rec.salvaged:
            for key, read in (("import_source", import_notes), ("pwm", pwm), ("battery", voltage),
                              ("tachometer", tach), ("speed", speed)):
                attempt(key, read)
        replay_inputs = [t for t in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TACH_ADC) if rec.has(t)]
        out["motors_elsewhere"] = motors = rec.motors_elsewhere()
    usable = _usable(path, namespace, bool(replay_inputs), motors)
    out["usable_for"] = [k for k in ("train", "evaluate", "discrepancy", "replay") if usable[k] is True]
    out["not_usable"] = {k: v for k, v in usable.items() if v is not True}
    out["problems"] = problems
    out["resolution"] = _resolution(**{f"{k}_dt": v for k, v in out["sample_interval_s"].items()})
    return out


def _usable(path: str, namespace: str | None, replay_inputs: bool, motors: list[str]
            ) -> dict[str, Literal[True] | str]:
    """Each command: True when it can use the recording, else why not (loaded exactly as the
    commands load it, so the reason is theirs)."""
    from .recordings import load_signals

    usable: dict[str, Literal[True] | str] = {}
    usable["replay"] = True if replay_inputs else "none of /pwm, /battery/adc, /tachometer/adc is recorded"
    if motors:  # a vehicle's recording read at the root: every command needs --namespace
        reason = f"the motor topics are under {', '.join('/' + n for n in motors)}: give --namespace {motors[0]}"
        usable.update(train=reason, evaluate=reason, discrepancy=reason, replay=reason)
        return usable
    try:
        sig = load_signals(path, namespace=namespace)
    except BadInputError as exc:
        reason = one_line(exc).removeprefix(f"{path}: ")
        usable.update(train=reason, evaluate=reason, discrepancy=reason)
    else:
        usable.update(evaluate=True, discrepancy=True)
        speed_ok = np.isfinite(sig.speed)
        usable["train"] = (True if np.ptp(sig.pwm) > 0 and speed_ok.any() and np.ptp(sig.speed[speed_ok]) > 0
                           else "the PWM or the measured speed does not vary")
    return usable


def _num(x: float | None, fmt: str) -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, fmt)


def summary_text(info: RecordingInfo) -> str:
    """``ros2 bag info``-like lines for people."""
    lines = [f"Recording:        {info['path']}" + (f" (namespace /{info['namespace']})" if info["namespace"] else ""),
             f"Duration:         {info['duration_s']:.3f} s",
             f"Messages:         {info['messages']}"]
    if info["damaged"]:
        lines.append(f"Damaged:          {info['damaged']}")
    for text in info.get("import_source") or []:
        lines.append(f"Source:           {text}")
    lines.append("Topics:")
    width = max([len(t["topic"]) for t in info["topics"]] + [10])
    for t in info["topics"]:
        gaps = "no gaps" if not t["gaps"] else f"{t['gaps']} gap(s), longest {t['max_gap_s']:.3f} s"
        lines.append(f"  {t['topic']:<{width}}  {t['type']:<34} {t['count']:>8} msgs  "
                     f"{_num(t['rate_hz'], '8.1f')} Hz  {gaps}")
    if info["namespaces"] and not info["namespace"]:
        lines.append(f"Motors:           {', '.join('/' + n for n in info['namespaces'])} "
                     f"(read one with --namespace {info['namespaces'][0]})")
    p, v, tach, sp = info["pwm"], info["battery_voltage_v"], info["tachometer"], info["speed_rad_s"]
    if p:
        lines.append(f"PWM:              {p['min']:.4f} .. {p['max']:.4f}")
    if v and "min" in v:
        lines.append(f"Battery voltage:  {v['min']:.2f} .. {v['max']:.2f} V ({v['source']})")
    if tach:
        lines.append("Tachometer:       " + (f"decodes: {tach['speeds']} speeds, up to {tach['max_rad_s']:.0f} rad/s"
                                              if tach["decodes"] else "does NOT decode (no speed from the edges)"))
    if sp and "min" in sp:
        gaps = f"; {sp['gaps']} gap(s), {sp['gaps_s']:.2f} s not measured" if sp.get("gaps") else ""
        lines.append(f"Measured speed:   {sp['min']:.0f} .. {sp['max']:.0f} rad/s ({sp['source']}){gaps}")
    if info.get("resolution"):
        lines.append(f"Sampling:         {info['resolution']}")
    lines.append(f"Usable for:       {', '.join(info['usable_for']) or 'nothing'}")
    by_reason: dict[str, list[str]] = {}
    for cmd, why in info["not_usable"].items():
        by_reason.setdefault(why, []).append(cmd)
    for why, cmds in by_reason.items():
        lines.append(f"  not for {', '.join(cmds)}: {why}")
    return "\n".join(lines)
