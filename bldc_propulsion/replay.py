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
from .atomic import RECORDING, check_output
from .bagio import MOTOR_TOPICS, BagWriter, open_recording, vehicle_topic
from .core.battery_filter import BatteryFilter, BatteryFilterConfig
from .core.estimator import ThrustEstimator, fallback_model
from .core.tach_output import SpeedOutput
from .core.tachometer import TachometerConfig, TachometerDecoder
from .core.ticker import Ticker
from .model import RangeReport, load_model

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
    namespace: str | None = None,
) -> dict[str, Any]:
    """Replay ``in_path`` into a new bag at ``out_path``; returns the summary (``--json``).

    With ``namespace`` (one motor of a vehicle's recording) the outputs are written as the
    quadrotor launch publishes them: under the namespace, ``battery/voltage`` at the root."""
    check_output(out_path, RECORDING, force=force, inputs=[in_path, model_path])
    model = load_model(model_path) if model_path else fallback_model()
    with open_recording(in_path, namespace) as rec:
        ns = rec.namespace
        inputs = [t for t in (c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TACH_ADC) if rec.has(t)]
        has_voltage = rec.has(c.TOPIC_BATTERY_VOLTAGE, c.BATTERY_STATE)
        if has_voltage:
            inputs.append(c.TOPIC_BATTERY_VOLTAGE)
        for topic, msgtype in ((c.TOPIC_PWM, c.FLOAT64), (c.TOPIC_BATTERY_ADC, c.FLOAT64),
                               (c.TOPIC_TACH_ADC, c.FLOAT32_ARRAY)):
            if rec.has(topic):
                rec.require(topic, msgtype)
        if not inputs:
            raise rec.missing_error([c.TOPIC_PWM, c.TOPIC_BATTERY_ADC, c.TOPIC_TACH_ADC])
        if rec.motors_elsewhere():
            raise rec.missing_error(MOTOR_TOPICS)  # a vehicle's recording: only its battery is at the root
        filt = BatteryFilter(battery or BatteryFilterConfig())
        tach = TachometerDecoder(tachometer or TachometerConfig())
        speed_out = SpeedOutput(tach)
        est = ThrustEstimator(model)
        counts = {"messages_in": 0, "messages_out": 0}
        per_topic_in: dict[str, int] = {}
        predictions = Ticker(ESTIMATOR_RATE_HZ)
        voltage_out = Ticker(VOLTAGE_RATE_HZ)
        next_diag: float | None = None

        speed_topic, thrust_topic, voltage_topic, rotor_topic, rpm_topic, diag_topic = (
            vehicle_topic(t, ns) for t in (c.TOPIC_PREDICTED_SPEED, c.TOPIC_PREDICTED_THRUST, c.TOPIC_BATTERY_VOLTAGE,
                                           c.TOPIC_ROTOR_SPEED, c.TOPIC_ROTOR_RPM, c.TOPIC_DIAGNOSTICS))

        with BagWriter(out_path, force=force, t0_ns=rec.t0_ns) as bag:

            def timers_until(t: float) -> None:
                """Outputs due up to t, emitted before an input at t is applied (as the nodes
                do: a grid time equal to an input's time sees the state before it)."""
                nonlocal next_diag
                if t < predictions.next_s and (next_diag is None or t < next_diag):
                    return
                for tick in predictions.due(t):
                    p = est.predict(tick)
                    if p.ready:
                        bag.write_float64(speed_topic, tick, p.speed_rad_s)
                        bag.write_float64(thrust_topic, tick, p.thrust_n)
                while next_diag is not None and next_diag <= t:
                    tach.check_timeout(next_diag)
                    statuses = [*filt.status(), *tach.status(), *est.status()]
                    bag.write_diagnostics(diag_topic, next_diag, statuses)
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
                        bag.write_battery_state(voltage_topic, t, v)
                        if not has_voltage:
                            est.update_voltage(t, v)
                elif topic == c.TOPIC_BATTERY_VOLTAGE:
                    est.update_voltage(t, float(msg.voltage))
                elif topic == c.TOPIC_TACH_ADC:
                    tach.process_batch(t, msg.data)
                    speed = speed_out.after_batch()
                    if speed is not None:
                        bag.write_float64(rotor_topic, t, speed)
                        bag.write_float64(rpm_topic, t, speed * c.RAD_S_TO_RPM)
            end = (rec.end_ns - rec.t0_ns) * 1e-9
            timers_until(end)
            counts["messages_out"] = bag.messages_written
        tach.check_timeout(end)  # a tachometer silent until the end: its status says so
        statuses = [*filt.status(), *tach.status(), *est.status()]
        n = max(est.predictions, 1)
        ranged = None if est.is_fallback else RangeReport(
            str(in_path), est.clipped / n, {k: v / n for k, v in est.clipped_by_input.items() if v})
        warning = ranged.warning() if ranged else None
        return {
            "path": str(out_path),
            "input": str(in_path),
            "model": str(model_path) if model_path else None,
            "namespace": ns,
            **counts,
            "messages_in_per_topic": per_topic_in,
            "duration_s": end,
            "read_error": rec.read_error,
            "out_of_training_range": ranged.as_dict() if ranged else None,
            "warnings": [warning] if warning else [],
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
