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

