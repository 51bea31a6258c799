"""Suite-wide setup: ROS 2 discovery kept on this machine, in a domain of this run's own.

Set before any test imports rclpy, and inherited by the node processes the tests start, so
parallel runs (or another ROS program on the machine) never see each other's topics. Also the
fixtures of the in-process node tests: ``context`` and ``start_node``.
"""

from __future__ import annotations

import os

import pytest


def _domain_id() -> int:
    """This run's ROS domain: from the pid, and under pytest-xdist (scripts/test.sh) from the
    controller's pid plus the worker's index, so the workers of one run never share a domain."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", ...
    if worker.startswith("gw") and worker[2:].isdigit():
        return 1 + (os.getppid() % 50) * MAX_WORKERS + int(worker[2:]) % MAX_WORKERS
    return 1 + os.getpid() % 100


#: Most pytest-xdist workers scripts/test.sh starts (domain ids stay within 1..200).
MAX_WORKERS = 4
#: Test files run after the parallel part, one test at a time: they start node processes and
#: judge wall time (start-up, stop within 2 s of SIGINT, live CPU, messages lost, Ctrl-C at a given
#: instant), which a second worker's load would falsify. scripts/test.sh runs ``-m serial`` alone.
SERIAL_FILES = frozenset({
    "test_nodes_live.py", "test_nodes_stop.py", "test_node_start.py", "test_nodes_cli.py", "test_nodes_ros.py",
    "test_reliability_sigint.py", "test_quiet_start.py", "test_cli_small.py", "test_bagio.py",
    "test_launch_files.py",
})

if os.environ.get("PYTEST_XDIST_WORKER"):
    # set, not defaulted: a worker inherits the controller's ROS_DOMAIN_ID (its conftest ran
    # first), and two workers in one domain see each other's nodes' topics
    os.environ["ROS_DOMAIN_ID"] = str(_domain_id())
else:
    os.environ.setdefault("ROS_DOMAIN_ID", str(_domain_id()))
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


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "serial: runs alone after the parallel part (conftest.SERIAL_FILES)")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.name in SERIAL_FILES:
            item.add_marker(pytest.mark.serial)
