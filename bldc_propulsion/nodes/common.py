"""Message conversions shared by the nodes (needs rclpy and the message packages).

Anything that can be written without message classes lives in ``params.py`` and is tested
without ROS; this module only puts those values into messages.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any, Callable, Iterable, Sequence

import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, DurabilityPolicy
from rclpy.task import Future
from std_msgs.msg import Float64

from bldc_propulsion.core.status import CoreStatus
from bldc_propulsion.errors import BadInputError, one_line
from bldc_propulsion.nodes.lean_executor import LeanExecutor
from bldc_propulsion.nodes.params import (
    HARDWARE_ID,
    Param,
    diagnostic_name,
    key_values,
    level_byte,
    seconds_to_stamp,
    stamp_to_seconds,
)


def declare_parameters(node: Node, table: Sequence[Param]) -> dict[str, Any]:
    """Declare every parameter of ``table`` on ``node``; return {name: effective value}.

    The value is the override (parameter file, ``-p``) if any, else the table's default. A value
    of the wrong type or out of range makes rclpy raise here, naming the parameter.
    """
    values: dict[str, Any] = {}
    for p in table:
        descriptor = ParameterDescriptor(description=p.description, read_only=p.read_only)
        if isinstance(p.default, float) and p.min is not None:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(p.min), to_value=float(p.max), step=0.0)]
        elif isinstance(p.default, int) and not isinstance(p.default, bool) and p.min is not None:
            descriptor.integer_range = [
                IntegerRange(from_value=int(p.min), to_value=int(p.max), step=1)]
        try:
            values[p.name] = node.declare_parameter(p.name, p.default, descriptor).value
        except ParameterException as e:  # wrong type, out of range: name it, one line
            raise BadInputError(
                f"{node.get_fully_qualified_name()}: parameter {p.name}: {_why(e, p)}") from e
    return values


def _why(e: ParameterException, p: Param) -> str:
    """rclpy's multi-line parameter error as one clause that says what is expected."""
    kind = type(p.default).__name__.replace("str", "string").replace("float", "double")
    text = one_line(e)
    if "type" in type(e).__name__.lower() or "type" in text.lower():
        return f"expected a {kind} (default {p.default!r}; write a double with a decimal point)" \
            if kind == "double" else f"expected a {kind} (default {p.default!r})"
    if p.min is not None:
        return f"must be in [{p.min}, {p.max}] ({text})"
    return text


def input_qos(depth: int) -> QoSProfile:
    """Inputs: best effort (any sensor driver, reliable or not, connects) with a deep history,
    so a node that stalls for less than ``depth`` messages loses none."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def events_executor() -> Any:
    """rclpy's EventsExecutor (about a third of the CPU per message of the single-threaded one).

    It cannot hand message info to callbacks (rclpy 7.1.6 raises SystemError), so it runs only
    nodes that do not need it; where it is missing, the single-threaded executor.
    """
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # pragma: no cover - older rclpy
        return SingleThreadedExecutor()
    return EventsExecutor()


def spin(executor: Any) -> None:
    """Spin until shutdown. The EventsExecutor's own ``spin`` does not return on Ctrl-C
    (rclpy 7.1.6: the context's shutdown does not wake it), so it is spun in slices of 0.1 s
    until a future that never completes: ``spin_once`` would return to Python after every
    event, which cost a fifth of the quadrotor's CPU (benchmarks/bench_nodes_live.py)."""
    if isinstance(executor, SingleThreadedExecutor):
        executor.spin()
        return
    never = Future()
    while rclpy.ok():
        executor.spin_until_future_complete(never, timeout_sec=0.1)


#: Which executor spins which nodes: the first pair on the calling thread, the others each on
#: a thread of its own (propulsion_all's mixed mode).
Plan = Callable[[list[Node]], list[tuple[Any, list[Node]]]]


def single_threaded(nodes: list[Node]) -> list[tuple[Any, list[Node]]]:
    """Every node on one single-threaded executor that hands callbacks the message info
    (``LeanExecutor``: rclpy's, with a cheap path for messages and timers)."""
    return [(LeanExecutor(), nodes)]


def on_events(nodes: list[Node]) -> list[tuple[Any, list[Node]]]:
    """Every node on the EventsExecutor (no message info; cheapest)."""
    return [(events_executor(), nodes)]


def run_node(name: str, build: Callable[[], Node | Sequence[Node]],
             args: list[str] | None = None, plan: Plan = single_threaded) -> int:
    """The one ``main`` of every node executable: init, build, spin, one-line errors.

    Exit status 0 on Ctrl-C or shutdown, 2 on a bad parameter or model (one line on stderr,
    no traceback), as the command line does.
    """
    rclpy.init(args=args)
    nodes: list[Node] = []
    executors: list[Any] = []
    try:
        built = build()
        nodes = list(built) if isinstance(built, (list, tuple)) else [built]
        pairs = plan(nodes)
        for executor, members in pairs:
            executors.append(executor)
            for node in members:
                executor.add_node(node)
        for executor, _ in pairs[1:]:
            threading.Thread(target=spin, args=(executor,), daemon=True).start()
        spin(pairs[0][0])
    except BadInputError as e:
        print(f"{name}: {one_line(e, 400)}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for executor in executors:
            executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


class ScalarOutput:
    """A Float64 topic that is serialized only while someone subscribes to it.

    Publishing to no one still costs a message, its serialization and a DDS write (about a
    sixth of a quadrotor's CPU with every output unread). Matching is looked up by
    :meth:`refresh`, which the node calls from a timer it already has (a lookup per message
    would cost half a publish); a new subscriber therefore gets data within that timer's period,
    sooner than DDS discovery matches it anyway. The message object is reused: ``publish``
    serializes it before returning.
    """

    def __init__(self, node: Node, topic: str, depth: int = 10) -> None:
        self.publisher = node.create_publisher(Float64, topic, depth)
        self.msg = Float64()
        self.listened = True  #: until the first refresh: publish

    def refresh(self) -> None:
        self.listened = self.publisher.get_subscription_count() > 0

    def publish(self, value: float) -> None:
        if self.listened:
            self.msg.data = value
            self.publisher.publish(self.msg)


def now_s(node: Node) -> float:
    """The node clock in seconds: wall time, or /clock under use_sim_time (bag --clock).

    Without sim time the ROS clock IS the system clock, read here without building an rclpy
    Time (a third of the cost; this runs for every message)."""
    clock = node.get_clock()
    if not clock.ros_time_is_active:
        return time.time()
    return clock.now().nanoseconds * 1e-9


def stamp_s(stamp: TimeMsg) -> float:
    """A header stamp in seconds."""
    return stamp_to_seconds(stamp.sec, stamp.nanosec)


def to_stamp(t_s: float) -> TimeMsg:
    """Seconds as a header stamp."""
    sec, nanosec = seconds_to_stamp(t_s)
    return TimeMsg(sec=sec, nanosec=nanosec)


def diagnostic_status(node_fqn: str, status: CoreStatus) -> DiagnosticStatus:
    """One core status as a DiagnosticStatus named after the node."""
    return DiagnosticStatus(
        level=level_byte(status.level),
        name=diagnostic_name(node_fqn, status.name),
        message=status.message,
        hardware_id=HARDWARE_ID,
        values=[KeyValue(key=k, value=v) for k, v in key_values(status.values)],
    )


def diagnostic_array(node: Node, statuses: Iterable[CoreStatus]) -> DiagnosticArray:
    """Every status of a node, stamped with the node clock."""
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    fqn = node.get_fully_qualified_name()
    msg.status = [diagnostic_status(fqn, s) for s in statuses]
    return msg
