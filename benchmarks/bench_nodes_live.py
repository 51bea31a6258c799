"""Live nodes on ROS 2 Jazzy: CPU, messages lost, a 5x playback, and the ROS-free replay speed.

A simulated recording (default 40 s of random steps) is played at 1x on wall time by
``bldc_propulsion.nodes.player`` into a quadrotor's nodes: the battery filter at the root and the
same motor streams into /motor0 .. /motor3, as quadrotor.launch.py starts them. CPU = the node
processes' CPU time (from /proc) over the wall time of the playback, in % of one core. Lost =
input messages published minus those the nodes counted (from their diagnostics). A consumer
subscribes to each motor's predicted/thrust and rotor/speed, as a flight controller would, and
counts what it gets; outputs nobody reads are not serialized by the nodes. Prints figures; not
a test.

The floor: before the first run of each quadrotor mode and after each run, the same recording
is played into ``benchmarks/floor_relay.py`` (a minimal rclpy relay with the same
subscriptions, QoS, timers and EventsExecutor, publishing the nodes' consumed outputs at their
counts to the same consumer, with none of their work) as one
process or as nine, and each run's CPU per input message is printed as a ratio to the mean of
the floors played just before and just after it (absolute figures differ by up to 3x between
machines of this class, and the load of a shared one moves both by up to a fifth between runs;
the ratio does not). ``--consume all`` / ``none``
subscribes to every output of every motor / to none, so that two runs give what publishing
costs.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_nodes_live.py [--duration 40] [--modes ...] [--runs 5] \
        [--pin-nodes 0] [--consume flight|all|none]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("ROS_DOMAIN_ID", str(101 - os.getpid() % 50))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

import rclpy  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from bldc_propulsion import contract as c  # noqa: E402
from bldc_propulsion.bagio import open_recording  # noqa: E402
from bldc_propulsion.replay import replay_bag  # noqa: E402
from bldc_propulsion.sim import simulate  # noqa: E402
from bldc_propulsion.sim.record import write_sim_bag  # noqa: E402

MOTORS = [f"motor{i}" for i in range(4)]
#: Issue 32's goals: CPU per input message at most this many times the floor's.
GOAL_RATIO = {"floor, one process": 1.5, "floor, 9 processes": 2.0}
#: The battery filter's battery/voltage: one per this many battery/adc samples (1 kHz / 20 Hz).
PUBLISH_EVERY = 50
NODE = [sys.executable, "-m"]
CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU time of a process (s)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


#: ``--pin-nodes CPU``: the node processes run on this CPU alone (the bench, the player and the
#: consumer on the others), so that their CPU time is not lowered by sharing a core with the
#: player (a node that waits for the CPU finds several messages queued and wakes up less).
NODE_CPUS: set[int] | None = None


def _node_preexec() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    if NODE_CPUS is not None:
        os.sched_setaffinity(0, NODE_CPUS)


def start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen(NODE + args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, preexec_fn=_node_preexec)


FLOOR = [sys.executable, str(ROOT / "benchmarks" / "floor_relay.py")]


def start_floor(roles: list[str]) -> subprocess.Popen:
    """A floor_relay process with these roles; it prints "received N" when stopped."""
    return subprocess.Popen(FLOOR + roles, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT, preexec_fn=_node_preexec)


def floor_roles() -> list[list[str]]:
    """The quadrotor's nine nodes as floor roles, one list per process."""
    roles = [["battery_filter"]]
    for ns in MOTORS:
        roles += [[f"{ns}/tachometer"], [f"{ns}/thrust_estimator"]]
    return roles


def floor_of(mode: str) -> str:
    """The floor a quadrotor mode is compared with: as many processes, the same executor."""
    return "floor, one process" if mode.startswith("one process") else "floor, 9 processes"


def processes(mode: str) -> list[subprocess.Popen]:
    """The quadrotor's nodes: one process (propulsion_all) or nine; or their floor."""
    if mode == "floor, one process":
        return [start_floor([r for roles in floor_roles() for r in roles])]
    if mode == "floor, 9 processes":
        return [start_floor(roles) for roles in floor_roles()]
    if mode.startswith("one process"):
        executor = mode.split("(")[1].rstrip(")")
        return [start(["bldc_propulsion.nodes.all_in_one", "--motors", "4",
                       "--executor", executor])]
    procs = [start(["bldc_propulsion.nodes.battery_filter_node"])]
    for ns in MOTORS:
        procs.append(start(["bldc_propulsion.nodes.tachometer_node", "--ros-args",
                            "-r", f"__ns:=/{ns}"]))
        procs.append(start(["bldc_propulsion.nodes.thrust_estimator_node", "--ros-args",
                            "-r", f"__ns:=/{ns}", "-r", "battery/voltage:=/battery/voltage"]))
    return procs


def one_motor() -> list[subprocess.Popen]:
    return [start([f"bldc_propulsion.nodes.{m}"]) for m in
            ("battery_filter_node", "tachometer_node", "thrust_estimator_node")]


#: What a flight controller reads of each motor (the bench subscribes to these, so that the
#: nodes publish them; outputs nobody reads are not serialized, see nodes.common.ScalarOutput).
CONSUMED = (c.TOPIC_PREDICTED_THRUST, c.TOPIC_ROTOR_SPEED)
#: Every output of a motor and its type (``--consume all``).
MOTOR_OUTPUTS = {
    c.TOPIC_ROTOR_SPEED: Float64, c.TOPIC_ROTOR_RPM: Float64, c.TOPIC_PREDICTED_SPEED: Float64,
    c.TOPIC_PREDICTED_THRUST: Float64, c.TOPIC_ROTOR_STATE: JointState,
    c.TOPIC_PREDICTED_STATE: JointState, c.TOPIC_PREDICTED_WRENCH: WrenchStamped}
CONSUME = {"flight": CONSUMED, "all": tuple(MOTOR_OUTPUTS), "none": ()}


class Diagnostics:
    """The latest status values of every node, by status name; counts the consumed outputs."""

    def __init__(self, namespaces: list[str], consumed: tuple[str, ...] = CONSUMED) -> None:
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("bench_diagnostics", context=self.context)
        self.latest: dict[str, dict[str, str]] = {}
        self.consumed = {out: 0 for out in consumed}
        # every node publishes on the absolute /diagnostics (status names carry the namespace);
        # /<ns>/diagnostics too, for nodes from before that (the names differ: no double count)
        for topic in {"/diagnostics", *(f"/{ns}/diagnostics" for ns in namespaces if ns)}:
            self.node.create_subscription(DiagnosticArray, topic, self.on_diag, 100)
        for ns in namespaces:
            for out in consumed:
                self.node.create_subscription(
                    MOTOR_OUTPUTS[out], f"/{ns}/{out}" if ns else f"/{out}",
                    lambda _msg, out=out: self.consumed.__setitem__(out, self.consumed[out] + 1),
                    100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.running = True
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.thread.start()

    def spin(self) -> None:
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def on_diag(self, msg: DiagnosticArray) -> None:
        for s in msg.status:
            self.latest[s.name] = {kv.key: kv.value for kv in s.values}

    def total(self, suffix: str, key: str) -> int:
        return sum(int(float(v[key])) for name, v in self.latest.items()
                   if name.endswith(suffix) and key in v)

    def close(self) -> None:
        self.running = False
        self.thread.join(5)
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def run(bag: Path, procs: list[subprocess.Popen], motors: list[str], rate: float,
        counts: dict[str, int], tmp: Path, consumed: tuple[str, ...] = CONSUMED,
        floor: bool = False) -> dict[str, float]:
    """Play ``bag`` into ``procs`` (the nodes, or their ``floor``); CPU and messages lost."""
    diag = Diagnostics(["", *[m for m in motors if m]], consumed)
    spec = tmp / "spec.json"
    spec.write_text(json.dumps({"bag": str(bag), "motors": motors, "rate": rate, "delay": 2.0}))
    player = subprocess.Popen(NODE + ["bldc_propulsion.nodes.player", str(spec)], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = float(player.stdout.readline().split()[1])
    time.sleep(max(0.0, t0 - time.time()))
    cpu0 = [cpu_s(p.pid) for p in procs]
    done = player.stdout.readline()  # "published N t_end T", then the player lingers
    cpu1 = [cpu_s(p.pid) for p in procs]
    if "t_end" not in done:
        raise SystemExit(f"player: {done!r} {player.communicate()[1][-500:]}")
    t_end = float(done.split("t_end")[1])
    player.communicate()
    wall = t_end - t0
    time.sleep(2.5)  # diagnostics after the last input
    diag.close()
    for p in procs:
        p.send_signal(signal.SIGINT)
    floor_received = 0
    for p in procs:
        try:
            out, _ = p.communicate(timeout=10)
            if floor:
                floor_received += int(out.split()[-1])
        except subprocess.TimeoutExpired:
            p.kill()
            p.communicate()
    n = len(motors)
    received = {
        "battery/adc": diag.total("battery_filter: battery filter", "accepted")
        + diag.total("battery_filter: battery filter", "rejected_nonfinite"),
        "tachometer/adc": diag.total("tachometer: tachometer", "batches"),
        "pwm": diag.total("thrust_estimator: thrust estimator", "pwm_accepted"),
    }
    lost = {k: counts[k] * (1 if k == "battery/adc" else n) - received[k] for k in received}
    # Where a loss happened: sequence-number jumps are losses in DDS (queue overflow, SHM).
    in_transport = {k: diag.total(name, key) for k, name, key in (
        ("battery/adc", "battery_filter: battery filter", "lost_in_transport"),
        ("tachometer/adc", "tachometer: input", "lost_in_transport"),
        ("pwm", "thrust_estimator: input", "pwm_lost"))}
    handled = sum(received.values()) + n * counts["battery/voltage"]
    if floor:  # its inputs: the player's, battery/voltage and rotor/speed (one per batch) for
        # each estimator; lost = what it should have taken minus what it took
        expected = (counts["battery/adc"] + n * (counts["pwm"] + 2 * counts["tachometer/adc"])
                    + n * counts["battery/adc"] // PUBLISH_EVERY)
        lost = {"any": expected - floor_received}
        in_transport = {}
        handled = sum(counts[k] * (1 if k == "battery/adc" else n)
                      for k in ("battery/adc", "pwm", "tachometer/adc")) + n * counts[
                          "battery/voltage"]
    cpu = sum(b - a for a, b in zip(cpu0, cpu1, strict=True))
    by_node: dict[str, float] = {}  # % of one core by node kind, summed over the motors
    for p, a, b in zip(procs, cpu0, cpu1, strict=True):
        kind = p.args[2].rsplit(".", 1)[-1].rsplit("/", 1)[-1]
        by_node[kind] = by_node.get(kind, 0.0) + 100.0 * (b - a) / wall
    return {"wall_s": wall, "cpu_core_pct": 100.0 * cpu / wall, "processes": len(procs),
            "cpu_by_node_pct": by_node,
            "consumed": dict(diag.consumed),
            "us_per_input_message": 1e6 * cpu / max(handled, 1),
            "lost": lost, "lost_in_transport": in_transport, "received": received}


def play_floor(bag: Path, mode: str, counts: dict[str, int], tmp: Path,
               consumed: tuple[str, ...]) -> float:
    """Play the recording into ``mode``'s floor once; print it; its CPU per input message (us)."""
    f = run(bag, processes(floor_of(mode)), MOTORS, 1.0, counts, tmp, consumed, floor=True)
    print(f"  {floor_of(mode):<29} {f['processes']} process(es): CPU "
          f"{f['cpu_core_pct']:5.1f} % of one core, {f['us_per_input_message']:5.0f} us "
          f"per input message, lost {f['lost']}, consumed {f['consumed']}", flush=True)
    return float(f["us_per_input_message"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=40.0)
    parser.add_argument("--modes", nargs="*", default=[
        "one process (events)", "one process (single)", "separate processes"])
    parser.add_argument("--runs", "--repeat", type=int, default=1, metavar="N", dest="repeat",
                        help="play each quadrotor mode N times, its floor before the first run "
                             "and after each; prints the median [min, max] and every run's ratio "
                             "to the mean of the floors before and after it")
    parser.add_argument("--consume", choices=sorted(CONSUME), default="flight",
                        help="outputs the bench subscribes to on each motor: flight (default: "
                             "predicted/thrust, rotor/speed), all, none")
    parser.add_argument("--no-floor", action="store_true", help="skip the floor")
    parser.add_argument("--no-extras", action="store_true",
                        help="skip the one-motor 5x run and the replay timing")
    parser.add_argument("--pin-nodes", type=int, metavar="CPU",
                        help="run the node processes on this CPU, everything else on the others")
    args = parser.parse_args()
    if args.pin_nodes is not None:
        global NODE_CPUS
        NODE_CPUS = {args.pin_nodes}
        others = os.sched_getaffinity(0) - NODE_CPUS
        if not others or args.pin_nodes not in os.sched_getaffinity(0):
            parser.error(f"--pin-nodes {args.pin_nodes}: needs that CPU and at least one other")
        os.sched_setaffinity(0, others)
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        bag = tmp / "rec"
        write_sim_bag(simulate("random_steps", args.duration, seed=3), bag)
        with open_recording(bag) as rec:
            counts = {t: rec.count(t) for t in ("pwm", "battery/adc", "tachometer/adc")}
            duration = (rec.end_ns - rec.t0_ns) * 1e-9
        counts["battery/voltage"] = int(duration * 20)  # publish_rate_hz
        print(f"recording: {duration:.1f} s, per motor {counts['tachometer/adc']} tachometer "
              f"batches, {counts['pwm']} pwm; {counts['battery/adc']} battery samples; "
              f"{os.cpu_count()} cores")
        consumed = CONSUME[args.consume]
        print(f"consumer subscribed to {list(consumed) or 'nothing'} of each motor")
        for mode in args.modes:
            cpus, ratios, lost_any = [], [], 0
            floor_before = None if args.no_floor else play_floor(bag, mode, counts, tmp, consumed)
            for _ in range(args.repeat):
                r = run(bag, processes(mode), MOTORS, 1.0, counts, tmp, consumed)
                cpus.append(r["cpu_core_pct"])
                lost_any += sum(r["lost"].values())
                print(f"quadrotor, {mode:<22} {r['processes']} process(es): CPU "
                      f"{r['cpu_core_pct']:5.1f} % of one core, {r['us_per_input_message']:5.0f} us "
                      f"per input message, lost {r['lost']} (sequence jumps "
                      f"{r['lost_in_transport']}), consumed {r['consumed']}", flush=True)
                if len(r["cpu_by_node_pct"]) > 1:
                    print("    by node: " + ", ".join(
                        f"{k} {v:.1f} %" for k, v in r["cpu_by_node_pct"].items()), flush=True)
                if floor_before is None:
                    continue
                floor_after = play_floor(bag, mode, counts, tmp, consumed)
                # the floors played just before and just after this run, averaged: the load of
                # this shared machine drifts between runs, and moves both by up to a fifth
                floor_us = (floor_before + floor_after) / 2.0
                ratios.append(r["us_per_input_message"] / floor_us)
                print(f"  quadrotor / floor (mean of the floors before and after, {floor_us:.0f} us "
                      f"per input message) = {ratios[-1]:.2f}", flush=True)
                floor_before = floor_after
            if len(cpus) > 1:
                print(f"quadrotor, {mode:<22} CPU over {len(cpus)} runs: median "
                      f"{statistics.median(cpus):.1f} % [{min(cpus):.1f}, {max(cpus):.1f}]")
            if ratios:
                goal = GOAL_RATIO[floor_of(mode)]
                met = max(ratios) <= goal and lost_any == 0
                print(f"quadrotor, {mode:<22} CPU per input message / floor over {len(ratios)} "
                      f"runs: median {statistics.median(ratios):.2f} [{min(ratios):.2f}, "
                      f"{max(ratios):.2f}], inputs lost {lost_any} (goal <= {goal}x and 0 lost "
                      f"in every run: {'met' if met else 'NOT met'})", flush=True)
        if args.no_extras:
            return 0
        r = run(bag, one_motor(), [""], 5.0, counts, tmp)
        print(f"one motor at 5x: CPU {r['cpu_core_pct']:.1f} % of one core, lost {r['lost']}")
        t = time.perf_counter()
        replay_bag(bag, tmp / "replayed")
        dt = time.perf_counter() - t
        print(f"ROS-free replay: {duration / dt:.0f}x real time ({dt:.2f} s for {duration:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
