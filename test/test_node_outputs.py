"""An output is serialized exactly while someone subscribes to it (``common.ListenedOutput``): the
publisher's matched event switches it on when a subscription matches and off when the last one
leaves, with rclpy's EventsExecutor (the nodes' default) and with its single-threaded one; while
it is off, ``publish`` hands nothing to the middleware."""

from __future__ import annotations

import time

import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from bldc_propulsion.nodes.common import ScalarOutput, events_executor  # noqa: E402


@pytest.mark.parametrize("kind", ["events", "single"])
def test_an_output_is_published_exactly_while_someone_listens(context, kind):
    node = rclpy.create_node("output_under_test", context=context)
    helper = rclpy.create_node("output_reader", context=context)
    executor = events_executor(context) if kind == "events" else SingleThreadedExecutor(context=context)
    for n in (node, helper):
        executor.add_node(n)

    def spin_until(done, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert time.monotonic() < deadline, "timed out"
            executor.spin_once(timeout_sec=0.01)

    try:
        out = ScalarOutput(node, "listened_output")
        sent: list[float] = []
        real = out.publisher.publish
        out.publisher.publish = lambda msg: (sent.append(msg.data), real(msg))  # what reaches DDS
        for _ in range(20):
            executor.spin_once(timeout_sec=0.01)
        assert not out.listened
        out.publish(1.0)
        assert sent == []  # nobody listens: not even serialized

        got: list[float] = []
        sub = helper.create_subscription(Float64, "listened_output", lambda m: got.append(m.data), 10)
        spin_until(lambda: out.listened)
        out.publish(2.0)
        spin_until(lambda: got == [2.0])
        assert sent == [2.0]

        helper.destroy_subscription(sub)
        spin_until(lambda: not out.listened)
        out.publish(3.0)
        assert sent == [2.0]
    finally:
        executor.shutdown()
        node.destroy_node()
        helper.destroy_node()
