"""Message conversions shared by the nodes (needs rclpy and the message packages).

Anything that can be written without message classes lives in ``params.py`` and is tested
without ROS; this module only puts those values into messages.
"""

from __future__ import annotations

import contextlib
import contextvars
import faulthandler
import inspect
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, cast

import rclpy
import rclpy.logging
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import JumpThreshold, ROSClock, TimeJump
from rclpy.context import Context
from rclpy.event_handler import PublisherEventCallbacks, QoSPublisherMatchedInfo
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from std_msgs.msg import Float64

from bldc_propulsion.core.status import CoreStatus
from bldc_propulsion.core.wrench import check_rotor_name
from bldc_propulsion.errors import BadInputError, one_line
from bldc_propulsion.nodes import guard_teardown, leave
from bldc_propulsion.nodes.params import (
    NODE_PARAMS,
    Param,
    diagnostic_name,
    hardware_id,
    key_values,
    level_byte,
    node_help,
    rcl_error_line,
    seconds_to_stamp,
    stamp_to_seconds,
    unknown_parameters,
    wants_help,
)


def declare_parameters(node: Node, table: Sequence[Param]) -> dict[str, Any]:
    """Declare every parameter of ``table`` on ``node``; return {name: effective value} (rclpy's
    parameter value: of the type of the table's default, which the caller reads it as).

    The value is the override (parameter file, ``-p``) if any, else the table's default. A value
    of the wrong type or out of range makes rclpy raise here, naming the parameter. An override
    that no node of this package declares gets one WARN line (``params.unknown_parameters``)
    and is otherwise ignored, as rclpy ignores it; inside ``unknown_parameters_once`` the
    process warns once instead, after all its nodes are declared.
    """
    values: dict[str, Any] = {}
    for p in table:
        descriptor = ParameterDescriptor(description=p.description, read_only=p.read_only)
        if isinstance(p.default, float) and p.min is not None and p.max is not None:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(p.min), to_value=float(p.max), step=0.0)]
        elif (isinstance(p.default, int) and not isinstance(p.default, bool)
              and p.min is not None and p.max is not None):
            descriptor.integer_range = [
                IntegerRange(from_value=int(p.min), to_value=int(p.max), step=1)]
        try:
            values[p.name] = node.declare_parameter(p.name, p.default, descriptor).value
        except ParameterException as e:  # wrong type, out of range: name it, one line
            raise BadInputError(
                f"{node.get_fully_qualified_name()}: parameter {p.name}: {_why(e, p)}") from e
    given = _GIVEN_PARAMETERS.get()
    if given is not None:
        given.update(parameter_overrides(node))
    else:
        for warning in unknown_parameters(parameter_overrides(node), table, NODE_PARAMS.values()):
            node.get_logger().warning(warning)
    return values


#: While a process builds several nodes (``unknown_parameters_once``): the override names they
#: were given, collected so that a typo is warned about once, not once per node.
_GIVEN_PARAMETERS: contextvars.ContextVar[set[str] | None] = contextvars.ContextVar(
    "bldc_propulsion_given_parameters", default=None)


@contextlib.contextmanager
def unknown_parameters_once(logger_name: str) -> Iterator[None]:
    """Nodes declared in this block warn about no unknown parameter; at its end, one WARN line
    (logger ``logger_name``) per name that no node of the package declares, with the nearest
    name of any of them: ``-p`` and a launch's parameters reach every node of a propulsion_all
    process, so a typo would otherwise be reported by each of its nodes (9 on a quadrotor)."""
    given: set[str] = set()
    token = _GIVEN_PARAMETERS.set(given)
    try:
        yield
    finally:
        _GIVEN_PARAMETERS.reset(token)
    every = list({p.name: p for table in NODE_PARAMS.values() for p in table}.values())
    logger = rclpy.logging.get_logger(logger_name)
    for warning in unknown_parameters(given, every):
        logger.warning(warning)


def parameter_overrides(node: Node) -> list[str]:
    """Names of the parameter overrides rcl resolved for ``node`` (``-p``, params files with
    their ``/**`` and node-name matching, ``parameter_overrides=``), declared or not.

    rclpy 7 has no public accessor for them (Node, rclpy.parameter and Context expose none;
    ``automatically_declare_parameters_from_overrides`` would declare typos as parameters), so
    this reads ``Node._parameter_overrides``, the dict rclpy's own ``declare_parameter`` takes
    values from; re-parsing the arguments would have to copy rcl's node matching.
    test_nodes_cli.py fails if an rclpy update drops it; here the check is then skipped rather
    than the node stopped.
    """
    return [str(name) for name in getattr(node, "_parameter_overrides", {})]


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


def events_executor(context: Context | None = None) -> Executor:
    """rclpy's EventsExecutor (about a third of the CPU per message of the single-threaded one;
    callbacks get the message info through :class:`WithInfo`); where it is missing, the
    single-threaded executor."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:  # pragma: no cover - older rclpy
        return SingleThreadedExecutor(context=context)
    return EventsExecutor(context=context)


class WithInfo:
    """A subscription callback ``fn(msg, info)`` that gets the message info (publication
    sequence number, source timestamp) from every executor.

    rclpy's executors call a two-argument callback as ``callback(msg, info)``, but rclpy
    7.1.6's EventsExecutor calls it as ``callback((msg, info))``: one tuple (a plain two-argument
    function then fails inside the executor with SystemError "null argument to internal
    routine"). This callable takes both forms; its declared signature has two parameters, so
    rclpy registers it as wanting the message info (``Subscription.CallbackType``).
    """

    __signature__ = inspect.Signature([
        inspect.Parameter("msg", inspect.Parameter.POSITIONAL_ONLY),
        inspect.Parameter("info", inspect.Parameter.POSITIONAL_ONLY)])

    def __init__(self, fn: Callable[[Any, dict], None]) -> None:  # fn(an rclpy message, its info)
        self.fn = fn

    def __call__(self, *args: Any) -> None:  # what rclpy's executors pass a callback
        if len(args) == 1:  # the EventsExecutor's (msg, info)
            args = args[0]
        self.fn(args[0], args[1])


@contextlib.contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """While in the block, SIGINT and SIGTERM set the yielded event and do nothing else; the
    previous handlers come back after it. ``rclpy.init`` is then called without its own signal
    handlers (``SignalHandlerOptions.NO``).

    Why: rclpy's handlers shut the context down from another thread the moment the signal lands,
    so a callback running then fails ("publisher's context is invalid", exit 1) or rcl is torn
    down under it (SIGSEGV); and Python's KeyboardInterrupt lands at whatever bytecode runs,
    often inside rclpy's C++ (a pybind11 RuntimeError, a hang in ``shutdown``). Here the spin
    loop sees the event between two callbacks, and the context is shut down after the
    executors stopped and the nodes are destroyed (test/test_nodes_stop.py).
    """
    stop = threading.Event()
    signums = (signal.SIGINT, signal.SIGTERM)

    def stopped(*_: object) -> None:
        stop.set()
        guard_teardown()  # a node executable that has not ended within the limit says where

    previous = [signal.signal(signum, stopped) for signum in signums]
    try:
        yield stop
    finally:
        for signum, handler in zip(signums, previous, strict=True):
            signal.signal(signum, handler)


def spin(executor: Executor, stop: threading.Event) -> None:
    """Spin until ``stop`` is set or the context shuts down, in slices of at most
    ``SPIN_SLICE_S`` (a signal does not end a wait: without rclpy's handlers nothing wakes it).

    The EventsExecutor is spun until a future that never completes (a new one each slice: a
    future keeps every done callback added to it): ``spin_once`` would return to Python after
    every event, which cost a fifth of the quadrotor's CPU (benchmarks/bench_nodes_live.py).
    """
    events = not isinstance(executor, SingleThreadedExecutor)
    try:
        while rclpy.ok() and not stop.is_set():
            if events:
                executor.spin_until_future_complete(Future(), timeout_sec=SPIN_SLICE_S)
            else:
                executor.spin_once(timeout_sec=SPIN_SLICE_S)
    except ExternalShutdownException:  # someone else shut rclpy down
        pass


#: Longest a spin waits before it looks at the stop event, s: the most Ctrl-C waits on an idle
#: node (a wake-up costs ~30 us: 4 a second are 0.01 % of a core).
SPIN_SLICE_S = 0.25
#: How long stopping waits for an executor's callbacks and spinning threads, s.
SHUTDOWN_TIMEOUT_S = 2.0

#: Which executor spins which nodes: the first pair on the calling thread, the others each on
#: a thread of its own (propulsion_all's mixed mode).
Plan = Callable[[list[Node]], list[tuple[Executor, list[Node]]]]


def single_threaded(nodes: list[Node]) -> list[tuple[Executor, list[Node]]]:
    """Every node on one single-threaded executor (``LeanExecutor``: rclpy's, with a cheap
    path for messages and timers; for an rclpy whose EventsExecutor misbehaves)."""
    from bldc_propulsion.nodes.lean_executor import LeanExecutor  # imported by the modes that use it

    return [(LeanExecutor(), nodes)]


def on_events(nodes: list[Node]) -> list[tuple[Executor, list[Node]]]:
    """Every node on the EventsExecutor (the default: cheapest; message info through
    :class:`WithInfo`)."""
    return [(events_executor(), nodes)]


def run_node(name: str, build: Callable[[], Node | Sequence[Node]],
             args: list[str] | None = None, plan: Plan = on_events) -> int:
    """The one ``main`` of every node executable: init, build, spin, one-line errors.

    Exit status 0 on Ctrl-C or shutdown, 2 on a bad parameter or model (one line on stderr,
    no traceback), as the command line does. ``-h``/``--help`` (before ``--ros-args``) prints
    the node's parameters from its table (``params.NODE_PARAMS[name]``) and returns 0 without
    starting ROS; executables with options of their own (propulsion_all) parse them first.
    """
    table = NODE_PARAMS.get(name)
    if table is not None and wants_help((sys.argv if args is None else args)[1:]):
        module = sys.modules.get(getattr(build, "__module__", ""))
        summary = ((module.__doc__ if module else None) or name).strip().split("\n")[0]
        print(node_help(name, summary, table), end="")
        return 0
    if sys.__stderr__ is not None:  # None: started without a stderr (pythonw, some daemons)
        with contextlib.suppress(ValueError, OSError):  # no file descriptor (a captured stderr)
            faulthandler.enable(sys.__stderr__)  # a crash in rclpy's C++ prints the Python stack
    with stop_on_signals() as stop:
        status = _run(name, build, args, plan, stop)
    return leave(status)  # a node executable ends here, without the interpreter's finalization


def _run(name: str, build: Callable[[], Node | Sequence[Node]], args: list[str] | None,
         plan: Plan, stop: threading.Event) -> int:
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)  # stop_on_signals
    except _rclpy.UnknownROSArgsError as e:  # a misspelt flag after --ros-args
        print(f"{name}: unknown ROS arguments {e} (see --help)", file=sys.stderr)
        return 2
    except _rclpy.RCLError as e:  # -p without :=, a params file that is missing or not YAML
        print(f"{name}: {rcl_error_line(str(e))}", file=sys.stderr)
        return 2
    nodes: list[Node] = []
    executors: list[Executor] = []
    threads: list[threading.Thread] = []
    try:
        built = build()
        nodes = [built] if isinstance(built, Node) else list(built)
        pairs = plan(nodes)
        for executor, members in pairs:
            executors.append(executor)
            for node in members:
                executor.add_node(node)
        for executor, _ in pairs[1:]:
            threads.append(threading.Thread(target=spin, args=(executor, stop), daemon=True))
            threads[-1].start()
        spin(pairs[0][0], stop)
    except BadInputError as e:
        print(f"{name}: {one_line(e, 400)}", file=sys.stderr)
        return 2
    finally:
        stop.set()
        guard_teardown()
        for executor in executors:
            executor.shutdown(timeout_sec=SHUTDOWN_TIMEOUT_S)
        for thread in threads:  # no entity is destroyed under a spinning executor
            thread.join(SHUTDOWN_TIMEOUT_S)
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


class ListenedOutput:
    """A topic that is serialized only while someone subscribes to it.

    Publishing to no one still costs a message, its serialization and a DDS write (3-17 us a
    Float64 here, about a sixth of a quadrotor's CPU with every output unread). Whether someone
    listens is kept by the publisher's matched event, which rclpy delivers like a message when
    a subscription matches or leaves (with the current count): nothing is polled, and a message
    costs one attribute test (a ``get_subscription_count`` per message would cost half a
    publish; polling it from the nodes' timers, 820 lookups a second on a quadrotor, cost 0.2 % of
    a core). A new subscriber gets data from the moment DDS matches it (``LeanExecutor`` looks at
    events every ``lean_executor.POLL_S``). The message object is reused (its constant fields set
    once): publishing serializes it before returning.
    """

    def __init__(self, node: Node, msg_type: type, topic: str, msg: Any, depth: int = 10) -> None:
        # msg: a message of a generated package (no type information), whose fields subclasses set
        self.publisher = node.create_publisher(
            msg_type, topic, depth, event_callbacks=PublisherEventCallbacks(matched=self._matched))
        self.msg = msg
        self.listened = self.publisher.get_subscription_count() > 0

    def _matched(self, info: QoSPublisherMatchedInfo) -> None:
        self.listened = info.current_count > 0


class ScalarOutput(ListenedOutput):
    """A Float64 topic (``ListenedOutput``)."""

    def __init__(self, node: Node, topic: str, depth: int = 10) -> None:
        super().__init__(node, Float64, topic, Float64(), depth)

    def publish(self, value: float) -> None:
        if self.listened:
            self.msg.data = value
            self.publisher.publish(self.msg)


class NamedValuesOutput(ListenedOutput):
    """A Float64MultiArray of a fixed count of values (``ListenedOutput``): one layout dimension
    whose label names them (e.g. comma-joined names), set once, so a consumer knows what each is."""

    def __init__(self, node: Node, topic: str, label: str, count: int, depth: int = 10) -> None:
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension  # only the estimator's adaptation

        msg = Float64MultiArray()
        msg.layout.dim = [MultiArrayDimension(label=label, size=count, stride=count)]
        super().__init__(node, Float64MultiArray, topic, msg, depth)

    def publish(self, values: Sequence[float]) -> None:
        if self.listened:
            self.msg.data = [float(v) for v in values]
            self.publisher.publish(self.msg)


class StampedOutput(ListenedOutput):
    """A stamped output (the contract's "Stamped outputs"), a ``ListenedOutput``.

    header.stamp is the instant the value describes, given by the caller on the node clock
    (s), not the time of publishing: a consumer fuses and compares by it.
    """

    def _send(self, t_s: float) -> None:
        stamp = self.msg.header.stamp
        stamp.sec, stamp.nanosec = seconds_to_stamp(t_s)
        self.publisher.publish(self.msg)


class JointStateOutput(StampedOutput):
    """sensor_msgs/JointState with one joint: ``name[0]`` = joint_name, ``velocity[0]`` (rad/s);
    position and effort empty (unknown, as the message allows)."""

    def __init__(self, node: Node, topic: str, joint_name: str, depth: int = 10) -> None:
        from sensor_msgs.msg import JointState  # only the nodes that publish one pay the import

        super().__init__(node, JointState, topic, JointState(name=[joint_name]), depth)

    def publish(self, t_s: float, velocity_rad_s: float) -> None:
        if self.listened:
            self.msg.velocity = [velocity_rad_s]
            self._send(t_s)


class WrenchOutput(StampedOutput):
    """geometry_msgs/WrenchStamped in the rotor's frame: force.z (N), torque.z (N m); the
    other components 0 (an axial rotor's model gives none)."""

    def __init__(self, node: Node, topic: str, frame_id: str, depth: int = 10) -> None:
        from geometry_msgs.msg import WrenchStamped  # only the estimator pays the import

        msg = WrenchStamped()
        msg.header.frame_id = frame_id
        super().__init__(node, WrenchStamped, topic, msg, depth)

    def publish(self, t_s: float, force_z_n: float, torque_z_nm: float) -> None:
        if self.listened:
            wrench = self.msg.wrench
            wrench.force.z = force_z_n
            wrench.torque.z = torque_z_nm
            self._send(t_s)


def stamped_name(node: Node, param: str, value: str) -> str:
    """A joint name or frame id parameter, refused when blank (``core.wrench.check_rotor_name``)."""
    return check_rotor_name(value, f"{node.get_fully_qualified_name()}: parameter {param}")


class NodeClock:
    """The node clock in seconds (call it): wall time, or /clock under use_sim_time (bag --clock).

    Runs for every message. Without sim time the ROS clock IS the system clock, read here without
    building an rclpy Time; whether sim time is on is asked of rcl only when it changes (a jump
    callback on clock change, which use_sim_time set at start or at run time triggers), not per
    message (``Clock.ros_time_is_active`` takes a lock and a C call, 1.5 us warm)."""

    def __init__(self, node: Node) -> None:
        # a node's clock is a ROSClock (rclpy's Node.get_clock is annotated with the base class)
        self._clock = cast(ROSClock, node.get_clock())
        self._sim = self._clock.ros_time_is_active
        self._on_change = self._clock.create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=None, on_clock_change=True),
            post_callback=self._changed)

    def _changed(self, _jump: TimeJump) -> None:
        self._sim = self._clock.ros_time_is_active

    def __call__(self) -> float:
        if not self._sim:
            return time.time()
        return self._clock.now().nanoseconds * 1e-9


def stamp_s(stamp: TimeMsg) -> float:
    """A header stamp in seconds."""
    return stamp_to_seconds(stamp.sec, stamp.nanosec)


def to_stamp(t_s: float) -> TimeMsg:
    """Seconds as a header stamp."""
    sec, nanosec = seconds_to_stamp(t_s)
    return TimeMsg(sec=sec, nanosec=nanosec)


def diagnostic_status(node_fqn: str, status: CoreStatus, hardware: str) -> DiagnosticStatus:
    """One core status as a DiagnosticStatus named after the node (with its namespace) and
    the hardware it watches (``params.hardware_id``)."""
    return DiagnosticStatus(
        level=level_byte(status.level),
        name=diagnostic_name(node_fqn, status.name),
        message=status.message,
        hardware_id=hardware,
        values=[KeyValue(key=k, value=v) for k, v in key_values(status.values)],
    )


def diagnostic_array(node: Node, statuses: Iterable[CoreStatus]) -> DiagnosticArray:
    """Every status of a node, stamped with the node clock, for the absolute /diagnostics
    (``contract.TOPIC_DIAGNOSTICS_ABSOLUTE``) that every node shares."""
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    fqn = node.get_fully_qualified_name()
    hardware = hardware_id(node.get_namespace(), node.get_name())
    msg.status = [diagnostic_status(fqn, s, hardware) for s in statuses]
    return msg
