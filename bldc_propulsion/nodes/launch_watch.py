"""What the launch files do when a node exits: end ``ros2 launch`` with a non-zero status.

Why: launch's ``Shutdown`` action stops the other nodes, but ``ros2 launch`` then returns 0
(``LaunchService.run`` returns 1 only when an exception escapes an action or event handler),
so systemd or a script sees success after a node crashed or refused its model. Here each node's
``on_exit`` raises :class:`NodeLost` instead; launch logs it on one line ("Caught exception in
launch (see debug for traceback): ..."), shuts the launch down and ``ros2 launch`` exits 1.

A node that exits 0 while the launch is shutting down (Ctrl-C, another node lost) stopped as
asked; any other exit (a crash, a refused model or parameter, status 0 while the launch was
running) is a lost node. The message names the node, its status, and why: the last line the
node wrote on stderr (its one-line error, or the last line of a traceback).

Plain Python (no launch import): the launch files pass :meth:`LaunchWatch.on_exit` as each
Node's ``on_exit`` and :meth:`LaunchWatch.on_stderr` to an ``OnProcessIO`` handler; the tests
run it with stand-in events.
"""

from __future__ import annotations

import signal
from typing import Protocol


class _RosNode(Protocol):
    """launch_ros's Node action, as ``node_label`` reads it (a plain process's action lacks
    these: AttributeError, caught there)."""

    @property
    def node_name(self) -> str: ...

    def is_node_name_fully_specified(self) -> bool: ...


class _ProcessEvent(Protocol):
    """What launch's process events (ProcessIO, ProcessExited) carry that is read here."""

    @property
    def process_name(self) -> str: ...

    @property
    def action(self) -> _RosNode: ...


class _ProcessIO(_ProcessEvent, Protocol):
    @property
    def text(self) -> bytes: ...


class _ProcessExited(_ProcessEvent, Protocol):
    @property
    def pid(self) -> int: ...

    @property
    def returncode(self) -> int: ...


class _LaunchContext(Protocol):
    @property
    def is_shutdown(self) -> bool: ...


class NodeLost(RuntimeError):
    """A launched node exited on its own: the launch ends with a non-zero status."""


def describe_status(returncode: int) -> str:
    """'status 2' or 'killed by SIGSEGV' (a negative return code is the signal)."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"status {returncode}"


def node_label(event: _ProcessEvent) -> str:
    """The process name, with the ROS node's full name when launch_ros knows it
    ('tachometer-2 /motor0/tachometer'): the process name alone does not say which motor."""
    try:
        action = event.action
        if action.is_node_name_fully_specified():
            return f"{event.process_name} {action.node_name}"
    except (AttributeError, RuntimeError):  # not a launch_ros Node, or not executed
        pass
    return event.process_name


class LaunchWatch:
    """Remembers each process's last stderr line; turns an unexpected exit into NodeLost."""

    def __init__(self) -> None:
        self.last_line: dict[str, str] = {}

    def on_stderr(self, event: _ProcessIO) -> None:
        """OnProcessIO's on_stderr: keep the last non-empty line of ``event.text`` (bytes)."""
        lines = [ln.strip() for ln in event.text.decode(errors="replace").splitlines()]
        lines = [ln for ln in lines if ln]
        if lines:
            self.last_line[event.process_name] = lines[-1]

    def on_exit(self, event: _ProcessExited, context: _LaunchContext) -> None:
        """A Node's on_exit (``ProcessExited``, ``LaunchContext``): nothing when the node
        stopped because the launch is shutting down, else raise :class:`NodeLost`."""
        if event.returncode == 0 and context.is_shutdown:
            return None
        why = self.last_line.get(event.process_name, "")
        running = "" if context.is_shutdown else " while the launch was running"
        raise NodeLost(
            f"node {node_label(event)} (pid {event.pid}) exited with "
            f"{describe_status(event.returncode)}{running}"
            + (f": {why}" if why else " (nothing on stderr)")
            + "; shutting the launch down, exit status 1")
