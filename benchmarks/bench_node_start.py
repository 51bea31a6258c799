"""How fast a node executable is up, and how fast the quadrotor's nine processes stop.

Start: each executable is started as a subprocess (the venv's entry point, as ``ros2 run``
starts it) and timed from ``Popen`` until every input topic has its subscription matched and
every output topic its publisher matched, seen from a probe process (discovery both ways: a
message published from then on reaches it). Then it is stopped with SIGINT (status and stderr
checked: 0 and quiet, as ``nodes.common.run_node`` documents). Median and max over ``--starts``.
Stop: the nine processes of quadrotor.launch.py, SIGINT to each at once, time until the last
exits; with ``--hog N`` busy-loop processes running meanwhile (``ros2 launch`` escalates to
SIGTERM after 5 s: the goal is < 2 s). Imports: ``python -X importtime`` of each node module,
self time summed by top-level package (the offenders). Prints figures; not a test.

The probe announces its participant every 0.1 s (a Fast DDS profile for this process only:
``PROBE_PROFILE``; the nodes run with the defaults), so the time measured is the node's. Why:
Fast DDS 2.14 sends a new participant's first announcement before it registers its receivers
(``RTPSParticipantImpl::enable``), and a peer answers a participant it has not seen with its
own announcement at once, over loopback within ~2 ms: an answer that lands in that window is
dropped, and the new node then learns of the peer only at the peer's next periodic
announcement (every 3 s by default). Seen with strace on the node: its announcement, the
peer's answer received 2.3 ms later and ignored, nothing sent to the peer until its next
announcement 3.0 s later; meanwhile the node's subscriptions and publishers had existed since
0.3-0.5 s. Starts then took the node's 0.3-0.6 s plus a uniform 0-3 s (max 3.2 s over 3),
whatever the node (a bare rclpy node the same), the discovery range (LOCALHOST or SUBNET) or
the transport (UDPv4 or SHM). ``--default-peer`` measures with such a peer.

    .venv/bin/python benchmarks/bench_node_start.py [--starts 5] [--hog 2] [--default-peer]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("ROS_DOMAIN_ID", str(151 - os.getpid() % 50))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

import rclpy  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402
from std_msgs.msg import Float32MultiArray, Float64  # noqa: E402

from bldc_propulsion import contract as c  # noqa: E402

#: executable: (module, input topics, output topics) with their message types.
EXECUTABLES = {
    "battery_filter": ("battery_filter_node", {c.TOPIC_BATTERY_ADC: Float64},
                       {c.TOPIC_BATTERY_VOLTAGE: BatteryState}),
    "tachometer": ("tachometer_node", {c.TOPIC_TACH_ADC: Float32MultiArray},
                   {c.TOPIC_ROTOR_SPEED: Float64, c.TOPIC_ROTOR_RPM: Float64}),
    "thrust_estimator": ("thrust_estimator_node",
                         {c.TOPIC_PWM: Float64, c.TOPIC_BATTERY_VOLTAGE: BatteryState,
                          c.TOPIC_ROTOR_SPEED: Float64},
                         {c.TOPIC_PREDICTED_SPEED: Float64, c.TOPIC_PREDICTED_THRUST: Float64}),
}
EXECUTABLES["propulsion_all"] = (
    "all_in_one", {c.TOPIC_BATTERY_ADC: Float64, c.TOPIC_TACH_ADC: Float32MultiArray,
                   c.TOPIC_PWM: Float64},
    {c.TOPIC_BATTERY_VOLTAGE: BatteryState, c.TOPIC_ROTOR_SPEED: Float64,
     c.TOPIC_PREDICTED_SPEED: Float64})
GOAL_START_S = 1.5
#: The probe's Fast DDS participant profile: a participant announcement every 0.1 s (default
#: 3 s), so that a node whose first discovery exchange was lost (module docstring) hears from
#: the probe within 0.1 s.
PROBE_PROFILE = """<?xml version="1.0" encoding="UTF-8" ?>
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <participant profile_name="bench_probe" is_default_profile="true">
    <rtps><builtin><discovery_config>
      <leaseAnnouncement><sec>0</sec><nanosec>100000000</nanosec></leaseAnnouncement>
    </discovery_config></builtin></rtps>
  </participant>
</profiles>
"""
PROFILE_VARIABLE = "FASTRTPS_DEFAULT_PROFILES_FILE"
GOAL_STOP_S = 2.0
MOTORS = [f"motor{i}" for i in range(4)]


def command(name: str) -> list[str]:
    """The entry point the venv installs (what ``ros2 run`` runs), else ``python -m``."""
    script = Path(sys.executable).parent / name
    if script.exists():
        return [sys.executable, str(script)]
    return [sys.executable, "-m", f"bldc_propulsion.nodes.{EXECUTABLES[name][0]}"]


def node_env() -> dict[str, str]:
    """The environment of the processes measured: this one's without the probe's DDS profile."""
    return {k: v for k, v in os.environ.items() if k != PROFILE_VARIABLE}


def default_sigint() -> None:
    """SIGINT back to its default in the child (a background shell may have ignored it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Probe:
    """Publishers on a node's inputs and subscriptions to its outputs, to see it matched."""

    def __init__(self, node, inputs: dict, outputs: dict, namespace: str = "") -> None:
        prefix = f"/{namespace}/" if namespace else ""
        self.pubs = [node.create_publisher(t, prefix + n, 10) for n, t in inputs.items()]
        self.subs = [node.create_subscription(t, prefix + n, lambda _m: None, 10)
                     for n, t in outputs.items()]
        self.node = node

    def matched(self) -> bool:
        return (all(p.get_subscription_count() > 0 for p in self.pubs)
                and all(s.get_publisher_count() > 0 for s in self.subs))

    def gone(self) -> bool:
        return (all(p.get_subscription_count() == 0 for p in self.pubs)
                and all(s.get_publisher_count() == 0 for s in self.subs))

    def close(self) -> None:
        for p in self.pubs:
            self.node.destroy_publisher(p)
        for s in self.subs:
            self.node.destroy_subscription(s)


CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU time of a process (s): what the start cost, whatever the load."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def wait_for(predicate, timeout_s: float, poll_s: float = 0.002) -> float | None:
    """Seconds until ``predicate()`` holds, or None after ``timeout_s``."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if predicate():
            return time.monotonic() - t0
        time.sleep(poll_s)
    return None


def stop(procs: list[subprocess.Popen], timeout_s: float = 10.0) -> tuple[float, list]:
    """SIGINT to every process at once; (seconds until the last exited, [(status, stderr)])."""
    t0 = time.monotonic()
    for p in procs:
        p.send_signal(signal.SIGINT)
    out = []
    for p in procs:
        try:
            _, err = p.communicate(timeout=max(0.1, timeout_s - (time.monotonic() - t0)))
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
            err = f"(killed: no exit within {timeout_s} s) {err}"
        out.append((p.returncode, err))
    return time.monotonic() - t0, out


def quiet(results: list) -> str:
    """'' when every process exited 0 with nothing on stderr, else what went wrong."""
    bad = [f"status {rc}: {err.strip()[-300:]}" for rc, err in results if rc != 0 or err.strip()]
    return "; ".join(bad)


def start_times(node, name: str, starts: int) -> None:
    _module, inputs, outputs = EXECUTABLES[name]
    probe = Probe(node, inputs, outputs)
    up, down, cpu, problems = [], [], [], []
    for _ in range(starts):
        if wait_for(probe.gone, 10.0) is None:
            problems.append("a previous start still matched after 10 s")
        t0 = time.monotonic()
        proc = subprocess.Popen(command(name), cwd=ROOT, stdout=subprocess.DEVNULL, env=node_env(),
                                stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
        ready = wait_for(probe.matched, 30.0)
        startup = time.monotonic() - t0
        cpu.append(cpu_s(proc.pid))
        if ready is None:
            problems.append(f"not matched within 30 s (status {proc.poll()})")
        up.append(startup)
        stop_s, results = stop([proc])
        down.append(stop_s)
        if quiet(results):
            problems.append(quiet(results))
    probe.close()
    verdict = "met" if max(up) <= GOAL_START_S else "NOT met"
    print(f"{name:<17} start to subscribed and publishing: median {statistics.median(up):.2f} s, "
          f"max {max(up):.2f} s over {starts} starts (goal <= {GOAL_START_S} s: {verdict}), "
          f"CPU time to get there median {statistics.median(cpu):.2f} s; "
          f"stop on SIGINT: max {max(down):.2f} s"
          + (f"; PROBLEMS: {problems}" if problems else "; exit 0, stderr empty"), flush=True)


def quadrotor() -> list[subprocess.Popen]:
    """The nine processes quadrotor.launch.py starts."""
    def node(name: str, *ros_args: str) -> subprocess.Popen:
        args = [*command(name), *(["--ros-args", *ros_args] if ros_args else [])]
        return subprocess.Popen(args, cwd=ROOT, stdout=subprocess.DEVNULL, env=node_env(),
                                stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    procs = [node("battery_filter")]
    for ns in MOTORS:
        procs.append(node("tachometer", "-r", f"__ns:=/{ns}"))
        procs.append(node("thrust_estimator", "-r", f"__ns:=/{ns}",
                          "-r", "battery/voltage:=/battery/voltage"))
    return procs


def quadrotor_stops(node, runs: int, hogs: int) -> None:
    probes = [Probe(node, {c.TOPIC_BATTERY_ADC: Float64}, {c.TOPIC_BATTERY_VOLTAGE: BatteryState})]
    probes += [Probe(node, {c.TOPIC_PWM: Float64, c.TOPIC_TACH_ADC: Float32MultiArray},
                     {c.TOPIC_PREDICTED_SPEED: Float64, c.TOPIC_ROTOR_SPEED: Float64}, ns)
               for ns in MOTORS]
    for n_hogs in sorted({0, hogs}):
        hog = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
               for _ in range(n_hogs)]
        try:
            times, ups, problems = [], [], []
            for _ in range(runs):
                wait_for(lambda: all(p.gone() for p in probes), 10.0)
                t0 = time.monotonic()
                procs = quadrotor()
                if wait_for(lambda: all(p.matched() for p in probes), 60.0) is None:
                    problems.append("not all matched within 60 s")
                ups.append(time.monotonic() - t0)
                stop_s, results = stop(procs)
                times.append(stop_s)
                if quiet(results):
                    problems.append(quiet(results))
        finally:
            for h in hog:
                h.kill()
                h.wait()
        verdict = "met" if max(times) <= GOAL_STOP_S else "NOT met"
        print(f"quadrotor, 9 processes, {n_hogs} busy-loop hog(s): all up in median "
              f"{statistics.median(ups):.2f} s [max {max(ups):.2f}]; SIGINT to all stopped "
              f"in median {statistics.median(times):.2f} s, max {max(times):.2f} s over {runs} "
              f"runs (goal <= {GOAL_STOP_S} s: {verdict})"
              + (f"; PROBLEMS: {problems}" if problems else "; every exit 0, stderr empty"),
              flush=True)
    for p in probes:
        p.close()


def import_offenders(module: str, top: int = 6) -> str:
    """``-X importtime`` of a node module: total, and self time summed by top-level package."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                          cwd=ROOT, capture_output=True, text=True, check=True)
    by_package: dict[str, int] = {}
    for line in done.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_us, _cumulative, name = line[len("import time:"):].split("|")
        package = name.strip().split(".")[0]
        by_package[package] = by_package.get(package, 0) + int(self_us)
    total = sum(by_package.values())
    worst = sorted(by_package.items(), key=lambda kv: -kv[1])[:top]
    return (f"{module}: {total / 1e6:.2f} s of imports; by package: "
            + ", ".join(f"{k} {v / 1e6:.2f} s" for k, v in worst))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--starts", type=int, default=5, help="starts per executable")
    parser.add_argument("--stops", type=int, default=3, help="quadrotor stops per hog count")
    parser.add_argument("--hog", type=int, default=2, metavar="N",
                        help="busy-loop processes during the second series of stops")
    parser.add_argument("--only", choices=("start", "stop", "imports"), nargs="*",
                        default=["imports", "start", "stop"])
    parser.add_argument("--default-peer", action="store_true",
                        help="the probe with Fast DDS's default announcement period (3 s): "
                             "starts then include the discovery race (module docstring)")
    args = parser.parse_args()
    if args.starts < 1 or args.stops < 1 or args.hog < 0:
        parser.error("--starts and --stops must be >= 1, --hog >= 0")
    with tempfile.TemporaryDirectory() as tmp:
        if args.default_peer:
            os.environ.pop(PROFILE_VARIABLE, None)
        else:  # read when rclpy.init creates the probe's participant
            profile = Path(tmp) / "probe_profile.xml"
            profile.write_text(PROBE_PROFILE)
            os.environ[PROFILE_VARIABLE] = str(profile)
        return measure(args)


def measure(args: argparse.Namespace) -> int:
    peer = "3 s (Fast DDS default)" if args.default_peer else "0.1 s"
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; executables: "
          f"{' '.join(command('tachometer')[1:2])} ...; probe announces every {peer}", flush=True)
    if "imports" in args.only:
        for module, _, _ in EXECUTABLES.values():
            print("  " + import_offenders(f"bldc_propulsion.nodes.{module}"), flush=True)
    rclpy.init()
    node = rclpy.create_node("bench_node_start")
    try:
        if "start" in args.only:
            for name in EXECUTABLES:
                start_times(node, name, args.starts)
        if "stop" in args.only:
            quadrotor_stops(node, args.stops, args.hog)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
