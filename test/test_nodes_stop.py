"""Stopping a node: Ctrl-C (SIGINT) or SIGTERM ends it with status 0 and nothing on stderr,
whenever the signal lands, including in the middle of a stream of messages.

Before ``common.stop_on_signals`` rclpy's signal handlers shut the context down from another
thread while a callback ran, and Python raised KeyboardInterrupt inside rclpy's C++: in ~1 of 20
stops under traffic a node exited 1 ("publisher's context is invalid", a pybind11 RuntimeError),
hung in ``executor.shutdown`` or crashed with SIGSEGV (CI, test_nodes_live).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from _ros import require_rclpy

require_rclpy()

from bldc_propulsion.nodes import common  # noqa: E402
from bldc_propulsion.sim import simulate  # noqa: E402
from bldc_propulsion.sim.record import write_sim_bag  # noqa: E402
from test_nodes_live import NODES, ROOT, env, play, player_t0, start_node  # noqa: E402

PROBE = """
import os, signal, threading, time
import rclpy
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64
from bldc_propulsion.nodes import common
from bldc_propulsion.nodes.lean_executor import LeanExecutor
guard = common.stop_on_signals()  # held: the handlers go back when it is closed
stop = guard.__enter__()
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node('stop_probe')
pub = node.create_publisher(Float64, 'stop_probe', 10)
published = []
def tick():  # a callback that publishes is running when the signal lands (1 kHz)
    pub.publish(Float64(data=1.0))
    published.append(time.monotonic())
node.create_timer(0.001, tick)
executor = {executor}
executor.add_node(node)
sent = []
def send():
    sent.append(time.monotonic())
    os.kill(os.getpid(), signal.{sig})
threading.Timer(0.5, send).start()
common.spin(executor, stop)  # a KeyboardInterrupt or a failed publish would end the probe here
print(f"{{time.monotonic() - sent[0]:.3f}} {{int(stop.is_set())}} {{int(rclpy.ok())}} {{len(published)}}")
executor.shutdown()
node.destroy_node()
rclpy.try_shutdown()
"""


@pytest.mark.parametrize("executor", ["LeanExecutor()", "common.events_executor()"])
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_ends_the_spin_between_callbacks_with_the_context_intact(sig, executor):
    done = subprocess.run([sys.executable, "-c", PROBE.format(sig=sig, executor=executor)],
                          env=env(), cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and not done.stderr, done.stderr
    lag_s, stopped, ok, published = done.stdout.split()
    assert 0.0 <= float(lag_s) < common.SPIN_SLICE_S + 0.5, lag_s  # the signal to the end of spin
    assert stopped == "1"
    assert ok == "1"  # nothing shut rclpy down under the callbacks: the node shuts down in order
    assert int(published) > 100


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp("stop")
    write_sim_bag(simulate("random_steps", 4.0, seed=7), d / "steps")
    return d / "steps"


@pytest.mark.parametrize("sig,after_s,nodes", [
    ("SIGINT", 0.4, "separate"), ("SIGTERM", 1.1, "separate"), ("SIGINT", 2.3, "separate"),
    ("SIGINT", 0.8, "events"), ("SIGTERM", 1.5, "single"), ("SIGINT", 1.9, "mixed")])
def test_nodes_stopped_in_a_stream_exit_0_and_quietly(recording, tmp_path, sig, after_s, nodes):
    """``separate``: the three node executables; else propulsion_all with that ``--executor``.
    Every node exits 0 with nothing on stderr; one that the teardown guard ended in
    ``destroy_node`` (Fast DDS's livelock, about 1 stop in 50, ``nodes.guard_teardown``) makes it
    an expected failure, as in the nine processes' test below."""
    if nodes == "separate":
        names = NODES
        nodes = [start_node(n) for n in names]
    else:
        names = (f"propulsion_all --executor {nodes}",)
        nodes = [start_node("propulsion_all", options=("--executor", nodes))]
    time.sleep(2.0)
    player = play(tmp_path, "p", bag=str(recording))
    try:
        player_t0(player)
        time.sleep(after_s)  # messages are flowing into every node
        for p in nodes:
            p.send_signal(getattr(signal, sig))
        livelocked = []
        for name, p in zip(names, nodes, strict=True):
            try:
                _, err = p.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.communicate()
                pytest.fail(f"{name} did not stop within 10 s of {sig}")
            if upstream_teardown_livelock(p.returncode, err.strip()):
                livelocked.append(name)  # ended by the guard within its limit: judged below
            elif p.returncode != 0 or err.strip():  # the whole stderr: a hung teardown's stacks say where
                pytest.fail(f"{name} exited {p.returncode} after {sig}; its stderr:\n{err[-8000:]}", pytrace=False)
        if livelocked:  # as the nine processes' test: the known upstream hang, the node down all the same
            pytest.xfail(f"Fast DDS's set_listener livelock in destroy_node (nodes.guard_teardown): {livelocked}")
    finally:
        for p in (*nodes, player):
            if p.poll() is None:
                p.kill()
                p.wait()


def test_the_quadrotors_nine_processes_stop_within_2_s_of_sigint_under_a_cpu_hog():
    """quadrotor.launch.py's nine processes, two busy loops on this 2-core machine meanwhile:
    every process exits 0, quietly, within 2 s of SIGINT (``ros2 launch`` escalates to SIGTERM
    after 5 s). Was ~4 s (interpreter finalization: ``bldc_propulsion.nodes.leave``). A node the
    teardown guard ended in ``destroy_node`` (Fast DDS's livelock, about 1 stop in 50) makes it
    an expected failure, as long as every process was down within the 2 s."""
    ros = {**env(), "ROS_DOMAIN_ID": str(200 + os.getpid() % 30),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

    def node(module: str, *ros_args: str) -> subprocess.Popen:
        return subprocess.Popen(
            [sys.executable, "-m", f"bldc_propulsion.nodes.{module}",
             *(["--ros-args", *ros_args] if ros_args else [])],
            env=ros, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    procs, names = [node("battery_filter_node")], ["battery_filter"]
    for i in range(4):
        procs.append(node("tachometer_node", "-r", f"__ns:=/motor{i}"))
        procs.append(node("thrust_estimator_node", "-r", f"__ns:=/motor{i}",
                          "-r", "battery/voltage:=/battery/voltage"))
        names += [f"motor{i}/tachometer", f"motor{i}/thrust_estimator"]
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        time.sleep(8.0)  # every node spinning (a start takes ~1 s alone; nine share 2 cores)
        assert all(p.poll() is None for p in procs), [p.communicate()[1] for p in procs
                                                      if p.poll() is not None]
        sent = time.monotonic()
        for p in procs:
            p.send_signal(signal.SIGINT)
        results = []
        for p in procs:
            try:
                _, err = p.communicate(timeout=max(0.1, 10.0 - (time.monotonic() - sent)))
            except subprocess.TimeoutExpired:  # where it hangs: faulthandler prints the stacks
                p.send_signal(signal.SIGABRT)
                _, err = p.communicate(timeout=10)
                err = "did not stop within 10 s; on SIGABRT:\n" + err
            results.append((p.returncode, err.strip()))
        stopped_s = time.monotonic() - sent
    finally:
        for p in (*procs, *hogs):
            if p.poll() is None:
                p.kill()
                p.wait()
    bad = [(name, rc, err) for name, (rc, err) in zip(names, results, strict=True) if rc != 0 or err]
    failed = [(name, rc, err[-3000:]) for name, rc, err in bad]
    assert stopped_s < 2.0, (stopped_s, failed)
    # judged on the whole stderr: faulthandler's "Timeout (" opens a dump longer than the shown tail
    if bad and all(upstream_teardown_livelock(rc, err) for _, rc, err in bad):
        pytest.xfail(f"Fast DDS's set_listener livelock in destroy_node (nodes.guard_teardown): "
                     f"{[name for name, _, _ in bad]} ended by the guard, all down in {stopped_s:.2f} s")
    assert not failed, failed


def upstream_teardown_livelock(status: int, stderr: str) -> bool:
    """Whether a node's exit is the guard ending the known Fast DDS livelock (PyPI build): status
    1 and faulthandler's timeout stack with the main thread in rclpy's ``destroy_node``."""
    return status == 1 and stderr.startswith("Timeout (") and "in destroy_node" in stderr
