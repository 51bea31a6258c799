"""LeanExecutor: message info, bursts drained in order, timers, entities added while spinning,
parameter services (woken by their requests, served by the base class) and Ctrl-C-style shutdown;
the private rclpy names it uses (a test that names the one an rclpy update drops) and its fallback."""

from __future__ import annotations

import time

import pytest

from _ros import require_rclpy

rclpy = require_rclpy()

from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rclpy.subscription import Subscription  # noqa: E402
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


# --- the private rclpy names it leans on ------------------------------------------------------

def test_the_private_rclpy_names_it_uses_are_there(ros):
    """Fails, naming each one, when an rclpy update drops or renames a private name the lean
    path uses (lean_executor.PRIVATE_API); the executor would then fall back at run time."""
    _, node, _, executor = ros
    sub = node.create_subscription(Float64, "names", lambda m: None, RELIABLE)
    missing = lean_executor.missing_private_api(executor, sub)
    assert not missing, (
        f"rclpy {lean_executor.rclpy_version()} no longer has {', '.join(missing)}: update "
        f"bldc_propulsion/nodes/lean_executor.py (supports rclpy {lean_executor.SUPPORTED_RCLPY})")
    assert not executor.missing
    # and they are what the lean path takes them for
    assert isinstance(executor._guard.handle.pointer, int) and isinstance(executor._sigint_gc.handle.pointer, int)
    assert executor._context is node.context and executor._is_shutdown is False
    assert sub._callback_type in list(Subscription.CallbackType)
    assert lean_executor._WITH_INFO is Subscription.CallbackType.WithMessageInfo


def test_the_check_names_what_is_missing():
    """On objects without them: every instance name of PRIVATE_API, by owner."""
    expected = [f"{owner}.{name}" for owner in ("Executor", "Subscription")
                for name in lean_executor.PRIVATE_API[owner]]
    assert lean_executor.missing_private_api(object(), object()) == expected
    assert lean_executor.missing_private_api() == []  # the C extension's names: all there


def test_without_them_it_is_rclpys_executor_with_one_warning(monkeypatch, capfd):
    """An rclpy without a name it uses: rclpy's SingleThreadedExecutor's way, the same callbacks
    (message info included), and one WARN line naming the name."""
    monkeypatch.setitem(lean_executor.PRIVATE_API, "Executor",
                        (*lean_executor.PRIVATE_API["Executor"], "_gone_in_a_later_rclpy"))
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("lean_fallback", context=ctx)
    executor = LeanExecutor(context=ctx)
    try:
        executor.add_node(node)
        assert executor.missing == ["Executor._gone_in_a_later_rclpy"]
        got, ticks = [], []
        node.create_subscription(Float64, "fallback", lambda m, info: got.append((m.data, info)), RELIABLE)
        node.create_timer(0.02, lambda: ticks.append(1))
        pub = node.create_publisher(Float64, "fallback", RELIABLE)
        for i in range(5):
            pub.publish(Float64(data=float(i)))
        spin_until(executor, lambda: len(got) == 5 and len(ticks) >= 3)
        assert [d for d, _ in got] == [0.0, 1.0, 2.0, 3.0, 4.0]
        assert all(info["source_timestamp"] > 0 for _, info in got)
        assert executor._lean is None  # the lean path never ran
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    warnings = [line for line in capfd.readouterr().err.splitlines() if "lean_executor" in line]
    assert len(warnings) == 1 and "[WARN]" in warnings[0], warnings
    assert "_gone_in_a_later_rclpy" in warnings[0] and "SingleThreadedExecutor" in warnings[0]
