"""LeanExecutor: message info, bursts drained in order, timers, entities added while spinning,
parameter services (woken by their requests, served by the base class) and Ctrl-C-style shutdown."""

from __future__ import annotations

import time

import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from bldc_propulsion.nodes import lean_executor  # noqa: E402
from bldc_propulsion.nodes.lean_executor import LeanExecutor  # noqa: E402

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def ros():
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("lean_under_test", context=ctx)
    helper = rclpy.create_node("lean_helper", context=ctx)
    executor = LeanExecutor(context=ctx)
    executor.add_node(node)
    executor.add_node(helper)
    yield ctx, node, helper, executor
    executor.shutdown()
    node.destroy_node()
    helper.destroy_node()
    rclpy.try_shutdown(context=ctx)


def spin_until(executor, condition, timeout_s=5.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        executor.spin_once(timeout_sec=0.01)


def test_a_burst_arrives_whole_in_order_with_message_info(ros):
    _, node, helper, executor = ros
    got = []
    node.create_subscription(Float64, "burst", lambda m, info: got.append((m.data, info)),
                             RELIABLE)
    pub = helper.create_publisher(Float64, "burst", RELIABLE)
    spin_until(executor, lambda: pub.get_subscription_count() > 0)
    for i in range(50):  # queued before the executor looks again: drained in one wake-up
        pub.publish(Float64(data=float(i)))
    spin_until(executor, lambda: len(got) == 50)
    assert [d for d, _ in got] == [float(i) for i in range(50)]
    seqs = [info["publication_sequence_number"] for _, info in got]
    assert seqs == list(range(seqs[0], seqs[0] + 50))
    assert all(info["source_timestamp"] > 0 for _, info in got)


def test_message_only_callbacks_and_timers(ros):
    _, node, helper, executor = ros
    got, ticks = [], []
    node.create_subscription(Float64, "plain", lambda m: got.append(m.data), RELIABLE)
    node.create_timer(0.02, lambda: ticks.append(time.monotonic()))
    pub = helper.create_publisher(Float64, "plain", RELIABLE)
    spin_until(executor, lambda: pub.get_subscription_count() > 0)
    pub.publish(Float64(data=2.5))
    spin_until(executor, lambda: got == [2.5] and len(ticks) >= 10)
    period = (ticks[-1] - ticks[0]) / (len(ticks) - 1)
    assert 0.015 < period < 0.05


@pytest.mark.parametrize("poll_s", [lean_executor.POLL_S, 3600.0])
def test_parameter_services_answer(ros, monkeypatch, poll_s):
    """Services and clients are in the lean wait set and wake the base class, which serves them:
    with the base class's poll an hour apart the request is still answered."""
    monkeypatch.setattr(lean_executor, "POLL_S", poll_s)
    _, node, helper, executor = ros
    node.declare_parameter("gain", 1.0)
    client = helper.create_client(SetParameters, "/lean_under_test/set_parameters")
    spin_until(executor, client.service_is_ready)
    future = client.call_async(SetParameters.Request(
        parameters=[Parameter("gain", value=3.0).to_parameter_msg()]))
    spin_until(executor, future.done)
    assert future.result().results[0].successful
    assert node.get_parameter("gain").value == 3.0


def test_shutdown_of_the_context_ends_spin(ros):
    ctx, node, _, executor = ros
    node.create_timer(0.01, lambda: rclpy.try_shutdown(context=ctx))
    t = time.monotonic()
    executor.spin()  # returns once the context is shut down
    assert time.monotonic() - t < 2.0
