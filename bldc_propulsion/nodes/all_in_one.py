"""propulsion_all: one pack and one or more motors in ONE process.

Saves the memory and the CPU of separate Python interpreters on a small companion computer.
The nodes are the very classes that run alone; only the process is shared.

    ros2 run bldc_propulsion propulsion_all                      # one motor, root names
    ros2 run bldc_propulsion propulsion_all --motors 4 \\
        --ros-args --params-file config/propulsion.yaml          # a quadrotor

``--motors N`` (before ``--ros-args``; default 1). One motor: the three nodes at the process
namespace, so a bench recording plays straight into it. N > 1 (``../shared/interfaces.md``,
"A quadrotor"): ONE battery filter at the process namespace (one pack), and a tachometer and a
thrust estimator under ``motor<i>`` for each motor, every estimator reading the shared
``battery/voltage``. ROS arguments (``--params-file``, ``-p``, ``use_sim_time``) reach every
node of the process, which is why config/propulsion.yaml addresses nodes as ``/**/<node>``.

``--executor``: ``events`` (default) runs every node on rclpy's EventsExecutor, the cheapest
(benchmarks/bench_nodes_live.py): it waits through middleware listeners rather than a wait
set of every node's entities. ``single`` runs every node on ``LeanExecutor`` (a single-threaded
executor, a quarter to a half more CPU than ``events`` with four motors); ``mixed``: the
battery filter on the EventsExecutor in a thread of its own, the motors on ``LeanExecutor``.
Every executor hands the callbacks the message info (sequence numbers, publisher timestamps;
``common.WithInfo``).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from rclpy.node import Node
from rclpy.parameter import Parameter

from bldc_propulsion.nodes.battery_filter_node import BatteryFilterNode
from bldc_propulsion.nodes.common import (
    Plan,
    events_executor,
    on_events,
    run_node,
    single_threaded,
    unknown_parameters_once,
)
from bldc_propulsion.nodes.params import NODE_PARAMS, namespaces, own_arguments, parameters_help, rotor_name
from bldc_propulsion.nodes.tachometer_node import TachometerNode
from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode

#: Every motor's estimator reads the pack's battery/voltage at the process namespace.
SHARED_VOLTAGE = ['--ros-args', '-r', 'battery/voltage:=/battery/voltage']
EXECUTORS = ('events', 'single', 'mixed')
MAX_MOTORS = 16


def build_nodes(motors: int, **kwargs: Any) -> list[Node]:
    """The battery filter, then a tachometer and an estimator per motor (``kwargs``: Node args).
    A parameter no node declares is warned about once for the process, not by every node."""
    with unknown_parameters_once('propulsion_all'):
        return _build_nodes(motors, **kwargs)


def _build_nodes(motors: int, **kwargs: Any) -> list[Node]:
    nodes: list[Node] = [BatteryFilterNode(**kwargs)]
    for namespace in namespaces(motors):
        ns: dict[str, Any] = {'namespace': namespace} if namespace else {}
        if namespace:  # each rotor's own joint and frame (interfaces.md "Stamped outputs")
            name = Parameter('joint_name', value=rotor_name(namespace))
            ns['parameter_overrides'] = [name]
        nodes.append(TachometerNode(**ns, **kwargs))
        if namespace:
            ns['cli_args'] = SHARED_VOLTAGE
            ns['parameter_overrides'] = [name, Parameter('frame_id', value=rotor_name(namespace))]
        nodes.append(ThrustEstimatorNode(**ns, **kwargs))
    return nodes


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog='propulsion_all', description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='Parameters of each node (after --ros-args; -p and params files reach\n'
               'every node of the process):\n' + '\n'.join(
                   f'{node}:\n{parameters_help(table)}' for node, table in NODE_PARAMS.items()))
    parser.add_argument('--motors', type=int, default=1,
                        help=f'motors to run (1-{MAX_MOTORS}): 1 = process namespace, '
                             'N > 1 = motor0..motorN-1 with one battery filter')
    parser.add_argument('--executor', choices=EXECUTORS, default='events',
                        help='events (default), single or mixed; see the module docstring')
    options = parser.parse_args(argv)
    if not 1 <= options.motors <= MAX_MOTORS:
        parser.error(f'--motors must be in 1..{MAX_MOTORS}, got {options.motors}')
    return options


def plan_for(executor: str) -> Plan:
    """Which executor spins which node for ``--executor`` (the battery filter is nodes[0])."""
    if executor == 'events':
        return on_events
    if executor == 'single':
        return single_threaded
    from bldc_propulsion.nodes.lean_executor import LeanExecutor  # its import costs every start

    return lambda nodes: [(LeanExecutor(), nodes[1:]), (events_executor(), nodes[:1])]


def main(args: list[str] | None = None) -> int:
    argv = sys.argv if args is None else args
    options = parse_args(own_arguments(argv[1:]))
    return run_node(
        'propulsion_all',
        lambda: build_nodes(options.motors), argv, plan_for(options.executor))


if __name__ == '__main__':
    sys.exit(main())
