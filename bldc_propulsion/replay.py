"""ROS-free replay: the nodes' cores over a recording, in message-time order.

What ``replay`` writes is what the three nodes publish during ``ros2 bag play --clock``:
- ``battery/voltage`` for every accepted ``battery/adc`` sample (the node's decimation 1),
- ``rotor/speed`` and ``rotor/rpm`` once per ``tachometer/adc`` batch (the core's latest
  estimate, 0 after signal loss),
- ``predicted/speed`` and ``predicted/thrust`` on the estimator's timer (100 Hz from the first
  PWM message), fed with the filtered voltage as the node is through ``battery/voltage``,
- ``diagnostics`` once a second with every core's status.
A recording that already carries ``battery/voltage`` (e.g. an imported thrust-stand log) feeds
the estimator from it instead of filtering ``battery/adc``.
"""

from __future__ import annotations

import os
from typing import Any

from . import contract as c
from .atomic import RECORDING, check_output
from .bagio import BagWriter, open_recording
from .core.battery_filter import BatteryFilter, BatteryFilterConfig
from .core.estimator import ThrustEstimator, fallback_model
from .core.tachometer import TachometerConfig, TachometerDecoder
from .model import RangeReport, load_model

ESTIMATOR_RATE_HZ = 100.0
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

        def topic_out(topic: str) -> str:
            return topic if ns is None or topic == c.TOPIC_BATTERY_VOLTAGE else f"{ns}/{topic}"

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
        motor = [c.TOPIC_PWM, c.TOPIC_TACH_ADC]
        if not any(rec.has(t) for t in motor) and any(rec.namespaces_with(t) for t in motor):
            raise rec.missing_error(motor)  # a vehicle's recording: only its battery is at the root
        filt = BatteryFilter(battery or BatteryFilterConfig())
        tach = TachometerDecoder(tachometer or TachometerConfig())
        est = ThrustEstimator(model)
        counts = {"messages_in": 0, "messages_out": 0}
        per_topic_in: dict[str, int] = {}
        next_pred: float | None = None
        next_diag: float | None = None

        with BagWriter(out_path, force=force, t0_ns=rec.t0_ns) as bag:

            def timers_until(t: float) -> None:
                nonlocal next_pred, next_diag
                while next_pred is not None and next_pred <= t:
                    p = est.predict(next_pred)
                    if p.ready:
                        bag.write_float64(topic_out(c.TOPIC_PREDICTED_SPEED), next_pred, p.speed_rad_s)
                        bag.write_float64(topic_out(c.TOPIC_PREDICTED_THRUST), next_pred, p.thrust_n)
                    next_pred += 1.0 / ESTIMATOR_RATE_HZ
                while next_diag is not None and next_diag <= t:
                    tach.check_timeout(next_diag)
                    statuses = [*filt.status(), *tach.status(), *est.status()]
                    bag.write_diagnostics(topic_out(c.TOPIC_DIAGNOSTICS), next_diag, statuses)
                    next_diag += 1.0 / DIAGNOSTICS_RATE_HZ

            for topic, t, msg in rec.messages(inputs, tolerant=True):
                timers_until(t)
                counts["messages_in"] += 1
                per_topic_in[topic] = per_topic_in.get(topic, 0) + 1
                if next_diag is None:
                    next_diag = t + 1.0 / DIAGNOSTICS_RATE_HZ
                if topic == c.TOPIC_PWM:
                    est.update_pwm(t, float(msg.data))
                    if next_pred is None:
                        next_pred = t
                elif topic == c.TOPIC_BATTERY_ADC:
                    v = filt.update(t, float(msg.data))
                    if v is not None:
                        bag.write_battery_state(topic_out(c.TOPIC_BATTERY_VOLTAGE), t, v)
                        if not has_voltage:
                            est.update_voltage(t, v)
                elif topic == c.TOPIC_BATTERY_VOLTAGE:
                    est.update_voltage(t, float(msg.voltage))
                elif topic == c.TOPIC_TACH_ADC:
                    out = tach.process_batch(t, msg.data)
                    bag.write_float64(topic_out(c.TOPIC_ROTOR_SPEED), t, out.speed_now)
                    bag.write_float64(topic_out(c.TOPIC_ROTOR_RPM), t, out.speed_now * c.RAD_S_TO_RPM)
                timers_until(t)
            end = (rec.end_ns - rec.t0_ns) * 1e-9
            timers_until(end)
            counts["messages_out"] = bag.messages_written
        tach.check_timeout(end)  # a tachometer silent until the end is lost, as the node's timer says
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
