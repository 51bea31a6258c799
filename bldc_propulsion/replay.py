"""ROS-free replay: the nodes' cores over a recording, in message-time order.

What ``replay`` writes is what the three nodes publish for the same recording (the rules are
shared, and ``test/test_nodes_live.py`` checks live = replay):
- ``battery/voltage`` for accepted ``battery/adc`` samples at the node's publish_rate_hz
  (``core.ticker.Ticker`` on sample time),
- ``rotor/speed`` and ``rotor/rpm`` after each ``tachometer/adc`` batch that has a speed to
  stand behind (``core.tach_output.SpeedOutput``: none across a break, 0 only when stopped),
- ``predicted/speed`` and ``predicted/thrust`` on the estimator's 100 Hz grid from the first
  PWM message, fed with the published filtered voltage as the node is through ``battery/voltage``,
- ``diagnostics`` once a second with every core's status.
A recording that already carries ``battery/voltage`` (e.g. an imported thrust-stand log) feeds
the estimator from it instead of filtering ``battery/adc``.
"""

from __future__ import annotations

import os
from typing import Any

from . import contract as c
from .bagio import BagWriter, open_recording
from .core.battery_filter import BatteryFilter, BatteryFilterConfig
from .core.estimator import ThrustEstimator, fallback_model
from .core.tach_output import SpeedOutput
from .core.tachometer import TachometerConfig, TachometerDecoder
from .core.ticker import Ticker
from .errors import BagError
from .model import load_model

ESTIMATOR_RATE_HZ = 100.0  #: thrust_estimator's output_rate_hz default
VOLTAGE_RATE_HZ = 20.0  #: battery_filter's publish_rate_hz default
DIAGNOSTICS_RATE_HZ = 1.0


def replay_bag(
    in_path: str | os.PathLike[str],
    out_path: str | os.PathLike[str],
    *,
    model_path: str | os.PathLike[str] | None = None,
    force: bool = False,
    battery: BatteryFilterConfig | None = None,
    tachometer: TachometerConfig | None = None,
) -> dict[str, Any]:
    """Replay ``in_path`` into a new bag at ``out_path``; returns the summary (``--json``)."""
    model = load_model(model_path) if model_path else fallback_model()
    with open_recording(in_path) as rec:
        inputs = [t for t in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TACH_ADC) if rec.has(t)]
        has_voltage = rec.has(c.TOPIC_BATTERY_VOLTAGE, c.BATTERY_STATE)
        if has_voltage:
            inputs.append(c.TOPIC_BATTERY_VOLTAGE)
        for topic, msgtype in ((c.TOPIC_PWM, c.FLOAT64), (c.TOPIC_BATTERY_ADC, c.FLOAT64),
                               (c.TOPIC_TACH_ADC, c.FLOAT32_ARRAY)):
            if rec.has(topic):
                rec.require(topic, msgtype)
        if not inputs:
            raise BagError(
                f"{in_path}: none of the input topics (/pwm, /battery/adc, /tachometer/adc) is recorded"
            )
        filt = BatteryFilter(battery or BatteryFilterConfig())
        tach = TachometerDecoder(tachometer or TachometerConfig())
        speed_out = SpeedOutput(tach)
        est = ThrustEstimator(model)
        counts = {"messages_in": 0, "messages_out": 0}
        per_topic_in: dict[str, int] = {}
        predictions = Ticker(ESTIMATOR_RATE_HZ)
        voltage_out = Ticker(VOLTAGE_RATE_HZ)
        next_diag: float | None = None

        with BagWriter(out_path, force=force, t0_ns=rec.t0_ns) as bag:

            def timers_until(t: float) -> None:
                nonlocal next_diag
                for tick in predictions.due(t):
                    p = est.predict(tick)
                    if p.ready:
                        bag.write_float64(c.TOPIC_PREDICTED_SPEED, tick, p.speed_rad_s)
                        bag.write_float64(c.TOPIC_PREDICTED_THRUST, tick, p.thrust_n)
                while next_diag is not None and next_diag <= t:
                    tach.check_timeout(next_diag)
                    statuses = [*filt.status(), *tach.status(), *est.status()]
                    bag.write_diagnostics(c.TOPIC_DIAGNOSTICS, next_diag, statuses)
                    next_diag += 1.0 / DIAGNOSTICS_RATE_HZ

            for topic, t, msg in rec.messages(inputs, tolerant=True):
                timers_until(t)
                counts["messages_in"] += 1
                per_topic_in[topic] = per_topic_in.get(topic, 0) + 1
                if next_diag is None:
                    next_diag = t + 1.0 / DIAGNOSTICS_RATE_HZ
                if topic == c.TOPIC_PWM:
                    if est.update_pwm(t, float(msg.data)):
                        predictions.start(t)
                elif topic == c.TOPIC_BATTERY_ADC:
                    v = filt.update(t, float(msg.data))
                    if v is not None and voltage_out.take(t):
                        bag.write_battery_state(c.TOPIC_BATTERY_VOLTAGE, t, v)
                        if not has_voltage:
                            est.update_voltage(t, v)
                elif topic == c.TOPIC_BATTERY_VOLTAGE:
                    est.update_voltage(t, float(msg.voltage))
                elif topic == c.TOPIC_TACH_ADC:
                    tach.process_batch(t, msg.data)
                    speed = speed_out.after_batch()
                    if speed is not None:
                        bag.write_float64(c.TOPIC_ROTOR_SPEED, t, speed)
                        bag.write_float64(c.TOPIC_ROTOR_RPM, t, speed * c.RAD_S_TO_RPM)
                timers_until(t)
            end = (rec.end_ns - rec.t0_ns) * 1e-9
            timers_until(end)
            counts["messages_out"] = bag.messages_written
        tach.check_timeout(end)  # a tachometer silent until the end is lost, as the node's timer says
        statuses = [*filt.status(), *tach.status(), *est.status()]
        return {
            "path": str(out_path),
            "input": str(in_path),
            "model": str(model_path) if model_path else None,
            **counts,
            "messages_in_per_topic": per_topic_in,
            "duration_s": end,
            "read_error": rec.read_error,
            "status": [
                {"name": s.name, "level": s.level, "message": s.message, "values": dict(s.values)}
                for s in statuses
            ],
        }


def summary_text(info: dict[str, Any]) -> str:
    """A few lines a person reads after a replay."""
    lines = [
        f"replayed {info['input']} ({info['duration_s']:.1f} s) -> {info['path']}",
        f"  messages in {info['messages_in']}, out {info['messages_out']}; "
        f"model: {info['model'] or 'first-principles fallback'}",
    ]
    for s in info["status"]:
        level = ("OK", "WARN", "ERROR")[min(int(s["level"]), 2)]
        vals = ", ".join(f"{k}={v}" for k, v in s["values"].items() if _worth_saying(k, v))
        lines.append(f"  [{level}] {s['name']}: {s['message']}" + (f" ({vals})" if vals else ""))
    if info.get("read_error"):
        lines.append(f"  recording damaged: kept the readable part; {info['read_error']}")
    return "\n".join(lines)


#: Counters a replay summary shows when they are not zero: what went wrong, not what went well.
_PROBLEM_WORDS = ("reject", "loss", "glitch", "gap", "clipped", "mismatch", "reset", "missing",
                  "nonfinite", "suppressed", "unverified", "not_ready", "resync")


def _worth_saying(key: str, value: str) -> bool:
    if key in ("accepted", "edges", "speeds", "predictions", "batches", "samples"):
        return True
    return any(w in key for w in _PROBLEM_WORDS) and value not in ("0", "False", "nan", "")
