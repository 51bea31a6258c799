"""rclpy adapters of the cores: battery_filter, tachometer, thrust_estimator, propulsion_all.

Importing this package does not import rclpy: only the node modules do (``params`` does not),
so the rest of bldc_propulsion and its tests run without ROS.

Run as a node executable (``tachometer``, ``python -m bldc_propulsion.nodes.tachometer_node``,
...), this package is the first of ours Python imports, before rclpy, numpy and the node's
module (about a second on a loaded 2-core computer): Ctrl-C (SIGINT) or SIGTERM in that window
ends the process at once with status 0 and no KeyboardInterrupt traceback, as they do later
(``common.run_node`` takes both signals over before ``rclpy.init``). When the node has
stopped, :func:`leave` ends such a process without the interpreter's finalization. Imported as
a library (tests, ``python -c``), nothing changes.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import sys

from bldc_propulsion import quiet_start

#: The node executables (setup.py's entry points) and the modules ``python -m`` runs.
_EXECUTABLES = {"battery_filter", "tachometer", "thrust_estimator", "propulsion_all"}
_MODULES = {f"{__name__}.{m}" for m in (
    "battery_filter_node", "tachometer_node", "thrust_estimator_node", "all_in_one")}

#: Whether this process is a node executable (then the two behaviours above apply).
EXECUTABLE = quiet_start.started_as(_EXECUTABLES, _MODULES)
if EXECUTABLE:  # nothing is running yet to stop in order: leave at once, status 0
    quiet_start.install(0, (signal.SIGINT, signal.SIGTERM))


#: Longest a node executable's teardown (executors, nodes, the ROS context) may take once the
#: stop began, s: a stop takes 0.2-0.4 s even on a loaded machine, and the quadrotor must be down
#: within 2 s of Ctrl-C, well before ``ros2 launch`` escalates to SIGTERM (5 s) and SIGKILL.
TEARDOWN_LIMIT_S = 1.5
#: Whether :func:`guard_teardown` armed the watchdog (once: a second Ctrl-C does not re-arm it).
_GUARDED = False


def guard_teardown() -> None:
    """In a node executable: unless the process has ended :data:`TEARDOWN_LIMIT_S` from now,
    print every thread's Python stack on stderr and exit 1; as a library, nothing.

    Why: a stop normally takes 0.2-0.4 s, but now and then (about 1 in 50 stops of the
    quadrotor's nine processes at once on a loaded machine) a node never ends in rclpy's
    ``destroy_node``. gdb on such a node: the last node's destroy deletes the DDS participant,
    and rmw_fastrtps first removes its listener (``DomainParticipant::set_listener(nullptr)``),
    which waits, with no deadline, for a discovery callback in flight (a peer's participant
    being removed, as peers stop at the same moment) to finish. Fast DDS 2.14.5 from PyPI is
    built without ``pthread_cond_clockwait``, so libstdc++'s wait for an infinite deadline on
    the steady clock overflows to a deadline in the past and spins, re-taking the mutex the
    callback needs to leave: the callback starves and the wait never ends (a build with
    ``pthread_cond_clockwait``, as Ubuntu 24.04's should be, would sleep there; not checked).
    Leaving without the teardown is no cure for the usual stop: the participant's goodbye is
    what lets peers drop the node at once (measured: within 0.1 s of its exit, against 19 s,
    the DDS lease, without). Without this guard such a node spins until ``ros2 launch`` kills
    it, saying nothing of where.
    faulthandler's watchdog is a C thread: it fires although the hung call holds the GIL.
    """
    global _GUARDED
    if not EXECUTABLE or _GUARDED or sys.__stderr__ is None:
        return
    with contextlib.suppress(ValueError, OSError):  # no file descriptor (a captured stderr)
        faulthandler.dump_traceback_later(TEARDOWN_LIMIT_S, exit=True, file=sys.__stderr__)
        _GUARDED = True


def leave(status: int) -> int:
    """After ``run_node`` stopped everything: in a node executable, exit now with ``status``;
    as a library, return it.

    Why: the interpreter's finalization (tearing down numpy, rclpy and the message modules)
    took 0.3-0.45 s of a core per process on a loaded 2-core computer, so the quadrotor's nine
    processes needed ~4 s to stop and ``ros2 launch`` escalated to SIGTERM. The ROS context
    is destroyed first (its DDS participant says goodbye: peers unmatch at once, not after a
    lease), and stdout and stderr are flushed.
    """
    if not EXECUTABLE:
        return status
    try:
        import rclpy.utilities

        rclpy.utilities.get_default_context().destroy()
    except Exception:  # noqa: BLE001 - already destroyed, or never initialised: leave anyway
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(status)

