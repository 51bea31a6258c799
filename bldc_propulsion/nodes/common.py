"""Message conversions shared by the nodes (needs rclpy and the message packages).

Anything that can be written without message classes lives in ``params.py`` and is tested
without ROS; this module only puts those values into messages.
"""

from __future__ import annotations

from typing import Any, Iterable, Sequence

from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from bldc_propulsion.core.status import CoreStatus
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
        values[p.name] = node.declare_parameter(p.name, p.default, descriptor).value
    return values


def now_s(node: Node) -> float:
    """The node clock in seconds: wall time, or /clock under use_sim_time (bag --clock)."""
    return node.get_clock().now().nanoseconds * 1e-9


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
