"""Suite-wide setup: ROS 2 discovery kept on this machine, in a domain of this run's own.

Set before any test imports rclpy, and inherited by the node processes the tests start, so
parallel runs (or another ROS program on the machine) never see each other's topics. Also the
fixtures of the in-process node tests: ``context`` and ``start_node``.
"""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")


@pytest.fixture
def context():
    """A fresh rclpy context for an in-process node test (skipped without rclpy, failed in CI)."""
    from _ros import require_rclpy

    rclpy = require_rclpy()
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture
def start_node(context):
    """``start_node(NodeClass, **parameters)``: that node on sim time with the helper that feeds
    and records it (``_ros.NodeHarness``); every harness started is closed after the test."""
    from _ros import NodeHarness

    started = []

    def start(node_class, **params):
        started.append(NodeHarness(context, node_class, **params))
        return started[-1]

    yield start
    for harness in started:
        harness.close()
