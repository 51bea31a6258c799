"""Where ROS tools look: /diagnostics, --help, and parameters no node declares (issue 32, 2 and 5).

The executables run as processes (their console scripts, or ``python -m`` where the venv has
none) and the node classes in-process on rclpy; conftest.py gives this run a ROS domain of its
own with discovery on this machine only, which the processes inherit.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bldc_propulsion.nodes import params as P

ROOT = Path(__file__).resolve().parents[1]
MODULES = {"battery_filter": "battery_filter_node", "tachometer": "tachometer_node",
           "thrust_estimator": "thrust_estimator_node", "propulsion_all": "all_in_one"}


def command(name: str) -> list[str]:
    script = Path(sys.executable).parent / name
    if script.exists():
        return [str(script)]
    return [sys.executable, "-m", f"bldc_propulsion.nodes.{MODULES[name]}"]


def env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}


# --- without ROS: the rules, on hand-written cases ---

def test_status_names_carry_the_namespace_and_hardware_id_the_motor():
    assert P.diagnostic_name("/motor0/tachometer", "input") == "motor0/tachometer: input"
    assert P.diagnostic_name("/tachometer", "input") == "tachometer: input"
    assert P.hardware_id("/motor0", "tachometer") == "motor0"
    assert P.hardware_id("/vehicle/motor2", "thrust_estimator") == "vehicle/motor2"
    assert P.hardware_id("/", "thrust_estimator") == "motor"
    assert P.hardware_id("/", "battery_filter") == "battery"
    assert P.hardware_id("/motor0", "battery_filter") == "motor0/battery"


def test_unknown_parameters_are_named_with_the_nearest_known():
    warnings = P.unknown_parameters(
        ["tachomter_rate", "blads", "timeout_s", "model_path", "use_sim_time",
         "qos_overrides./rotor/speed.publisher.depth", "zzz"],
        P.TACHOMETER_PARAMS, P.NODE_PARAMS.values())
    assert warnings == [
        "unknown parameter 'blads' ignored: did you mean 'blades'?",
        "unknown parameter 'tachomter_rate' ignored: did you mean 'sample_rate_hz'?",
        "unknown parameter 'zzz' ignored: no parameter of this node is close; it has "
        + ", ".join(p.name for p in P.TACHOMETER_PARAMS),
    ]
    # without siblings, the estimator's model_path is unknown to a tachometer
    assert P.unknown_parameters(["model_path"], P.TACHOMETER_PARAMS) == [
        "unknown parameter 'model_path' ignored: no parameter of this node is close; it has "
        + ", ".join(p.name for p in P.TACHOMETER_PARAMS)]


def test_help_is_asked_only_outside_the_ros_arguments():
    assert P.wants_help(["--help"]) and P.wants_help(["-h", "--ros-args", "-p", "a:=1"])
    assert not P.wants_help(["--ros-args", "-p", "a:=1", "-h"])
    assert P.wants_help(["--ros-args", "-p", "a:=1", "--", "--help"])
    assert not P.wants_help(["--motors", "4", "--ros-args", "--params-file", "f.yaml"])


def test_rcl_errors_become_one_line():
    text = ("failed to initialize rcl: Couldn't parse params file: '--params-file /x.yaml'. "
            "Error: Sequences can only be values and not keys in params. Error at line 1\n"
            ", at /project/src/parse.c:841, at /project/src/rcl/arguments.c:415")
    assert P.rcl_error_line(text) == (
        "Couldn't parse params file: '--params-file /x.yaml'. Error: Sequences can only be "
        "values and not keys in params. Error at line 1")


# --- the executables ---

@pytest.mark.parametrize("name", list(MODULES))
def test_help_lists_every_parameter_and_starts_no_ros(name):
    # an unknown ROS argument makes rclpy.init refuse (exit 2): exit 0 with the help shows
    # that ROS was never started
    flag = "-h" if name == "tachometer" else "--help"
    run = subprocess.run([*command(name), flag, "--ros-args", "--no-such-ros-flag"],
                         env=env(), capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stderr == ""
    tables = P.NODE_PARAMS.values() if name == "propulsion_all" else [P.NODE_PARAMS[name]]
    for table in tables:
        for p in table:
            line = f"  {p.name} ({P.type_name(p.default)}, default {P.as_typed(p.default)}"
            assert line in run.stdout, (line, run.stdout)
            if p.min is not None:
                assert f"range [{p.min}, {p.max}]" in run.stdout
            assert " ".join(p.description.split()[:4]) in run.stdout


@pytest.mark.parametrize("ros_args, why", [
    (["-p", "sample_rate_hz"], "Couldn't parse parameter override rule"),
    (["--params-file", "/no/such/params.yaml"], "Error opening YAML file"),
    (["--no-such-ros-flag"], "unknown ROS arguments ['--no-such-ros-flag']"),
])
def test_bad_ros_arguments_are_one_line_and_exit_2(ros_args, why):
    run = subprocess.run([*command("tachometer"), "--ros-args", *ros_args],
                         env=env(), capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("tachometer: ") and why in last, run.stderr
    assert " at /" not in last  # rcl's C source locations are cut


# --- on rclpy ---

@pytest.fixture
def ros():
    from _ros import require_rclpy
    rclpy = require_rclpy()
    context = rclpy.context.Context()
    rclpy.init(context=context)
    yield rclpy, context
    rclpy.try_shutdown(context=context)


class Observer:
    """A node in a namespace of its own that keeps every status published on /diagnostics."""

    def __init__(self, rclpy, context, *nodes) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        self.node = rclpy.create_node("observer", namespace="/elsewhere", context=context)
        self.statuses: list = []
        self.node.create_subscription(
            DiagnosticArray, "/diagnostics", lambda m: self.statuses.extend(m.status), 100)
        self.executor = SingleThreadedExecutor(context=context)
        for node in (self.node, *nodes):
            self.executor.add_node(node)

    def names(self) -> set[str]:
        return {s.name.split(":")[0] for s in self.statuses}

    def spin_until(self, done, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert time.monotonic() < deadline, f"timed out; statuses from {self.names()}"
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def test_every_node_of_a_vehicle_reports_on_the_absolute_diagnostics(ros):
    rclpy, context = ros
    from bldc_propulsion.nodes.all_in_one import build_nodes
    nodes = build_nodes(2, context=context)
    observer = Observer(rclpy, context, *nodes)
    expected = {"battery_filter": "battery",
                "motor0/tachometer": "motor0", "motor0/thrust_estimator": "motor0",
                "motor1/tachometer": "motor1", "motor1/thrust_estimator": "motor1"}
    try:
        observer.spin_until(lambda: set(expected) <= observer.names())
        assert observer.names() == set(expected)
        for s in observer.statuses:
            assert s.hardware_id == expected[s.name.split(":")[0]], s
        # the per-namespace topic of before is gone: nothing of ours publishes there
        observer.spin_until(lambda: observer.node.get_publisher_names_and_types_by_node(
            "tachometer", "/motor1"))
        topics = {t for t, _ in observer.node.get_publisher_names_and_types_by_node(
            "tachometer", "/motor1")}
        assert "/diagnostics" in topics and "/motor1/diagnostics" not in topics, topics
    finally:
        observer.close()
        for node in nodes:
            node.destroy_node()


def test_the_overrides_rclpy_resolved_are_readable(ros):
    """common.parameter_overrides reads a private rclpy attribute: this fails, rather than the
    check going quiet, if an rclpy update drops it."""
    _, context = ros
    from rclpy.parameter import Parameter

    from bldc_propulsion.nodes.common import parameter_overrides
    from bldc_propulsion.nodes.tachometer_node import TachometerNode
    node = TachometerNode(context=context, cli_args=["--ros-args", "-p", "blads:=3"],
                          parameter_overrides=[Parameter("timeout_s", value=0.5)])
    try:
        assert {"blads", "timeout_s"} <= set(parameter_overrides(node))
        assert node.get_parameter("timeout_s").value == 0.5
        assert not node.has_parameter("blads")  # warned about, not declared
    finally:
        node.destroy_node()


def test_misspelt_parameters_warn_once_each_and_the_node_still_publishes(ros, tmp_path):
    rclpy, context = ros
    yaml = tmp_path / "vehicle.yaml"
    yaml.write_text("/**/tachometer:\n  ros__parameters:\n    blads: 3\n    timeout_s: 0.5\n"
                    "/**:\n  ros__parameters:\n    model_path: ''\n    use_sim_time: false\n")
    proc = subprocess.Popen(
        [*command("tachometer"), "--ros-args", "-r", "__ns:=/motor3", "--params-file",
         str(yaml), "-p", "tachomter_rate:=5.0", "-p", "qos_overrides./x.publisher.depth:=3"],
        env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    observer = Observer(rclpy, context)
    try:
        observer.spin_until(lambda: "motor3/tachometer" in observer.names(), timeout_s=40.0)
        assert all(s.hardware_id == "motor3" for s in observer.statuses
                   if s.name.startswith("motor3/tachometer: "))
    finally:
        observer.close()
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0, stderr
    warnings = [line.split("]: ", 1)[1] for line in stderr.splitlines() if "[WARN]" in line]
    assert warnings == [
        "unknown parameter 'blads' ignored: did you mean 'blades'?",
        "unknown parameter 'tachomter_rate' ignored: did you mean 'sample_rate_hz'?",
    ], stderr
    assert all("[motor3.tachometer]" in line for line in stderr.splitlines() if "[WARN]" in line)
