"""The CPU floor of bench_nodes_live.py: a minimal rclpy relay with a node's traffic.

One process per ROLE given, each role the subscriptions of one of the package's nodes (same
topics, types, QoS, message-info callbacks, timers and rclpy EventsExecutor), publishing what
that node publishes to whoever reads it, at the node's counts, and nothing else (no decoding,
no filtering, no timing rules): the battery role a BatteryState on battery/voltage every
sample_rate_hz / publish_rate_hz samples; the tachometer role a Float64 on rotor/speed per
batch; the estimator role a Float64 on predicted/thrust per output_rate_hz grid time of the
wall clock, emitted from its inputs and its fallback timer as the node does. What a node costs
above this is the package's own work.

    python benchmarks/floor_relay.py battery_filter motor0/tachometer motor0/thrust_estimator ...

A role is ``[namespace/]node``; several roles in one process = one process's floor. On SIGINT
it prints "received N" (input messages taken) on stdout and exits 0.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import rclpy  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402
from std_msgs.msg import Float32MultiArray, Float64  # noqa: E402

from bldc_propulsion import contract as c  # noqa: E402
from bldc_propulsion.nodes.common import WithInfo, events_executor, input_qos, spin  # noqa: E402
from bldc_propulsion.nodes.params import (  # noqa: E402
    DIAGNOSTICS_PERIOD_S,
    NODE_PARAMS,
    TACH_TIMEOUT_CHECK_PERIOD_S,
)
from bldc_propulsion.nodes.thrust_estimator_node import FALLBACK_TIMER_HZ  # noqa: E402

#: Each node's parameter defaults (queue depths, the battery filter's rates).
DEFAULTS = {node: {p.name: p.default for p in table} for node, table in NODE_PARAMS.items()}
PUBLISH_EVERY = int(round(DEFAULTS["battery_filter"]["sample_rate_hz"]
                          / DEFAULTS["battery_filter"]["publish_rate_hz"]))
OUTPUT_PERIOD_S = 1.0 / DEFAULTS["thrust_estimator"]["output_rate_hz"]


class Relay:
    """One role's subscriptions, timers and outputs."""

    def __init__(self, role: str) -> None:
        namespace, _, kind = role.rpartition("/")
        self.node = rclpy.create_node(f"floor_{kind}", namespace=namespace or "/")
        self.received = 0
        self.out = Float64()
        if kind not in DEFAULTS:
            raise SystemExit(f"floor_relay: unknown role {role!r}")
        qos = input_qos(DEFAULTS[kind]["queue_depth"])
        sub = self.node.create_subscription
        timer = self.node.create_timer
        timer(DIAGNOSTICS_PERIOD_S, self.idle)
        if kind == "battery_filter":
            self.voltage = self.node.create_publisher(BatteryState, c.TOPIC_BATTERY_VOLTAGE, 10)
            self.state = BatteryState()
            sub(Float64, c.TOPIC_BATTERY_ADC, WithInfo(self.on_adc), qos)
        elif kind == "tachometer":
            self.pub = self.node.create_publisher(Float64, c.TOPIC_ROTOR_SPEED, 10)
            sub(Float32MultiArray, c.TOPIC_TACH_ADC, WithInfo(self.relay), qos)
            timer(TACH_TIMEOUT_CHECK_PERIOD_S, self.idle)
        elif kind == "thrust_estimator":
            self.pub = self.node.create_publisher(Float64, c.TOPIC_PREDICTED_THRUST, 10)
            self.next_s = time.time()
            sub(Float64, c.TOPIC_PWM, WithInfo(self.on_input), qos)
            sub(BatteryState, "/" + c.TOPIC_BATTERY_VOLTAGE, lambda _m: self.on_input(None, None),
                qos)
            sub(Float64, c.TOPIC_ROTOR_SPEED, WithInfo(self.on_input), qos)
            timer(1.0 / FALLBACK_TIMER_HZ, self.publish_until_now)

    def idle(self) -> None:
        """A timer of the node's, without its work."""

    def relay(self, _msg: object, _info: dict | None) -> None:
        self.received += 1
        self.out.data = float(self.received)
        self.pub.publish(self.out)

    def on_adc(self, msg: Float64, _info: dict | None) -> None:
        self.received += 1
        if self.received % PUBLISH_EVERY == 0:
            self.state.voltage = msg.data
            self.voltage.publish(self.state)

    def on_input(self, _msg: object, _info: dict | None) -> None:
        self.received += 1
        self.publish_until_now()

    def publish_until_now(self) -> None:
        """One predicted/thrust per output grid time passed, as the estimator's publish_until."""
        now = time.time()
        while self.next_s <= now:
            self.out.data = self.next_s
            self.pub.publish(self.out)
            self.next_s += OUTPUT_PERIOD_S


def main(roles: list[str]) -> int:
    stop = threading.Event()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    relays = [Relay(role) for role in roles]
    executor = events_executor()
    for r in relays:
        executor.add_node(r.node)
    spin(executor, stop)
    executor.shutdown(timeout_sec=2.0)
    print(f"received {sum(r.received for r in relays)}", flush=True)
    for r in relays:
        r.node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
