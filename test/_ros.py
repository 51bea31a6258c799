"""rclpy for the node tests: a skip on a developer machine without ROS, a failure in CI.

CI (``CI`` set, as .ci/run runs) installs the ROS 2 Jazzy wheels, so a missing rclpy there is a
broken install, and a node test silently skipped would hide exactly what it exists to find.
"""

from __future__ import annotations

import importlib
import os
import time

import pytest


def require_rclpy():
    """Import rclpy, or skip (developer machine) / fail (CI) saying why."""
    try:
        return importlib.import_module("rclpy")
    except ImportError as e:
        if os.environ.get("CI"):
            pytest.fail(f"rclpy is required in CI (scripts/venv.sh installs it): {e}",
                        pytrace=False)
        pytest.skip(f"rclpy not installed: {e}", allow_module_level=True)


class NodeHarness:
    """A node under test on sim time, a helper node that publishes its inputs and /clock and
    records its outputs, and one executor spinning both (the set-up of every in-process node
    test: test_nodes_ros.py, test_stamped_outputs.py; start one with the ``start_node`` fixture).

    The node runs with use_sim_time and use_source_timestamps false (stamp-less inputs timed on
    receipt), and each input is published once the node's clock shows its time, then the helper
    spins until the node has taken it: the node sees exactly the synthetic times, whatever the
    machine's speed."""

    def __init__(self, context, node_class, **params) -> None:
        rclpy = require_rclpy()
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from rosgraph_msgs.msg import Clock

        overrides = [Parameter("use_sim_time", value=True), Parameter("use_source_timestamps", value=False),
                     *[Parameter(k, value=v) for k, v in params.items()]]
        self._clock_msg = Clock
        self.node = node_class(context=context, parameter_overrides=overrides)
        self.helper = rclpy.create_node("test_helper", context=context)
        self.executor = SingleThreadedExecutor(context=context)
        for n in (self.node, self.helper):
            self.executor.add_node(n)
        self.clock_pub = self.helper.create_publisher(Clock, "/clock", 10)
        self.received: dict[str, list] = {}
        self.pubs: dict[str, object] = {}

    def record(self, msg_type, topic: str) -> list:
        """Keep every message the node publishes on ``topic`` (in ``received[topic]``)."""
        self.received[topic] = []
        self.helper.create_subscription(msg_type, topic, self.received[topic].append, 10000)
        return self.received[topic]

    def publisher(self, msg_type, topic: str):
        """A publisher of the node's input ``topic``, returned once the node subscribes to it."""
        self.pubs[topic] = self.helper.create_publisher(msg_type, topic, 100)
        self.spin_until(lambda: self.pubs[topic].get_subscription_count() > 0)
        return self.pubs[topic]

    def spin_until(self, done, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert time.monotonic() < deadline, "timed out waiting for the node"
            self.executor.spin_once(timeout_sec=0.01)

    def spin(self, times: int, timeout_s: float = 0.005) -> None:
        """A few turns of the executor (callbacks that are due, nothing awaited)."""
        for _ in range(times):
            self.executor.spin_once(timeout_sec=timeout_s)

    def set_time(self, t_s: float) -> None:
        """Publish /clock = ``t_s`` and spin until the node's clock shows it (exact to 1 ns)."""
        from builtin_interfaces.msg import Time as TimeMsg

        target = int(round(t_s * 1e9))
        sec, nanosec = divmod(target, 1_000_000_000)
        self.clock_pub.publish(self._clock_msg(clock=TimeMsg(sec=sec, nanosec=nanosec)))
        self.spin_until(lambda: self.node.get_clock().now().nanoseconds >= target)

    def send(self, topic: str, msg, t_s: float, expect=(), taken=None) -> None:
        """Publish ``msg`` at node time ``t_s``; then spin until each ``expect`` topic grew by
        one message and ``taken()`` (if given) says the node has it; with neither, a few turns."""
        self.set_time(t_s)
        expect = (expect,) if isinstance(expect, str) else tuple(expect)
        before = [len(self.received[e]) for e in expect]
        self.pubs[topic].publish(msg)
        if expect or taken is not None:
            self.spin_until(lambda: all(len(self.received[e]) > b for e, b in zip(expect, before, strict=True))
                            and (taken is None or taken()))
        else:
            self.spin(5)

    def feed_estimator(self, events, t0_s: float) -> None:
        """Feed a thrust estimator node ``events`` (s after ``t0_s``, kind 0 pwm / 1 battery voltage /
        2 rotor speed, value), each sent once the node has taken the previous one (its counters),
        then one diagnostics period after the last; the publishers are made here."""
        from builtin_interfaces.msg import Time as TimeMsg
        from sensor_msgs.msg import BatteryState
        from std_msgs.msg import Float64

        from bldc_propulsion import contract as c

        topics = (c.TOPIC_PWM, c.TOPIC_BATTERY_VOLTAGE, c.TOPIC_ROTOR_SPEED)
        for msg_type, topic in zip((Float64, BatteryState, Float64), topics, strict=True):
            if topic not in self.pubs:
                self.publisher(msg_type, topic)
        node = self.node
        voltages = lambda: node.core.voltage_accepted + node.core.voltage_rejected_time  # noqa: E731
        speeds = lambda: node.core.speed_accepted + node.core.speed_rejected  # noqa: E731
        for rel_s, kind, value in events:
            t = t0_s + rel_s
            if kind == 0:
                n = node.pwm_stream.messages
                self.send(topics[0], Float64(data=value), t, taken=lambda n=n: node.pwm_stream.messages > n)
            elif kind == 1:
                n = voltages()
                msg = BatteryState(voltage=value)
                ns = int(round(t * 1e9))
                msg.header.stamp = TimeMsg(sec=ns // 10**9, nanosec=ns % 10**9)
                self.send(topics[1], msg, t, taken=lambda n=n: voltages() > n)
            else:
                n = speeds()
                self.send(topics[2], Float64(data=value), t, taken=lambda n=n: speeds() > n)
        self.set_time(t0_s + events[-1][0] + 1.1)  # a diagnostics message after the last input

    def drain(self, quiet_s: float = 0.3) -> None:
        """Spin until no output has arrived for ``quiet_s`` (the last ones are in flight)."""
        count = lambda: sum(map(len, self.received.values()))  # noqa: E731
        seen, since = count(), time.monotonic()
        while time.monotonic() - since < quiet_s:
            self.executor.spin_once(timeout_sec=0.01)
            if count() != seen:
                seen, since = count(), time.monotonic()

    def close(self) -> None:
        """Stop the executor and destroy both nodes (again: nothing)."""
        if self.executor is None:
            return
        self.executor.shutdown()
        self.node.destroy_node()
        self.helper.destroy_node()
        self.executor = None
