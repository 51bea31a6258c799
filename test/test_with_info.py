"""Every executor the nodes run on hands a ``WithInfo`` callback the message and its info.

rclpy 7.1.6's EventsExecutor calls a message-info callback with one (msg, info) tuple where
the other executors pass two arguments; the timing rules (``stream_time.py``) need the
publication sequence numbers and source timestamps from all of them.
"""

from __future__ import annotations

import time

import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.subscription import Subscription  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from bldc_propulsion.nodes.common import WithInfo, events_executor  # noqa: E402
from bldc_propulsion.nodes.lean_executor import LeanExecutor  # noqa: E402

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
EXECUTORS = {"events": events_executor, "lean": LeanExecutor, "single": SingleThreadedExecutor}


@pytest.mark.parametrize("kind", list(EXECUTORS))
def test_with_info_gets_message_and_info_from_every_executor(kind):
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("with_info_under_test", context=ctx)
    got: list = []
    sub = node.create_subscription(Float64, "numbers", WithInfo(lambda m, i: got.append((m, i))),
                                   RELIABLE)
    pub = node.create_publisher(Float64, "numbers", RELIABLE)
    executor = EXECUTORS[kind](context=ctx)
    assert sub._callback_type is Subscription.CallbackType.WithMessageInfo
    try:
        executor.add_node(node)
        for i in range(20):
            pub.publish(Float64(data=float(i)))
        deadline = time.monotonic() + 10.0
        while len(got) < 20 and time.monotonic() < deadline:
            if kind == "events":
                executor.spin_until_future_complete(rclpy.task.Future(), timeout_sec=0.05)
            else:
                executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert [m.data for m, _ in got] == [float(i) for i in range(20)]
    seqs = [info["publication_sequence_number"] for _, info in got]
    assert seqs == list(range(seqs[0], seqs[0] + 20))
    assert all(info["source_timestamp"] > 0 for _, info in got)


def test_with_info_takes_both_call_forms():
    calls: list = []
    cb = WithInfo(lambda m, i: calls.append((m, i)))
    cb("m", {"k": 1})
    cb(("m2", {"k": 2}))
    assert calls == [("m", {"k": 1}), ("m2", {"k": 2})]


def test_node_clock_follows_use_sim_time_set_at_run_time():
    """NodeClock asks rcl whether sim time is on only when it changes (a jump callback): wall
    time, then the /clock time (0 before any /clock message) once use_sim_time is set at run
    time, then wall time again."""
    from rclpy.parameter import Parameter

    from bldc_propulsion.nodes.common import NodeClock

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("node_clock_under_test", context=ctx)
    try:
        now_s = NodeClock(node)
        assert abs(now_s() - time.time()) < 0.5
        node.set_parameters([Parameter("use_sim_time", value=True)])
        assert now_s() == 0.0
        node.set_parameters([Parameter("use_sim_time", value=False)])
        assert abs(now_s() - time.time()) < 0.5
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
