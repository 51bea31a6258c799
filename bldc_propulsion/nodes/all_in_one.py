"""propulsion_all: the three nodes of one or more motors in ONE process, one executor.

Saves the memory of separate Python interpreters on a small companion computer. The nodes are
the very classes that run alone; only the process is shared.

    ros2 run bldc_propulsion propulsion_all                      # one motor, root names
    ros2 run bldc_propulsion propulsion_all --ros-args -r __ns:=/motor2   # one motor, /motor2/...
    ros2 run bldc_propulsion propulsion_all --motors 4 \\
        --ros-args --params-file config/propulsion.yaml          # /motor0 ... /motor3

``--motors N`` (before ``--ros-args``; default 1): one motor keeps the process namespace so a
bench recording plays straight into it; N > 1 puts motor i under ``motor<i>``. ROS arguments
(``--params-file``, ``-p``, ``use_sim_time``) reach every node of the process, which is why
config/propulsion.yaml addresses nodes as ``/**/battery_filter`` and so on. Do not combine
``-r __ns:=...`` with N > 1 (it would move every motor into the same namespace).
"""

import argparse
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.utilities import remove_ros_args

from bldc_propulsion.errors import BadInputError
from bldc_propulsion.nodes.battery_filter_node import BatteryFilterNode
from bldc_propulsion.nodes.params import namespaces
from bldc_propulsion.nodes.tachometer_node import TachometerNode
from bldc_propulsion.nodes.thrust_estimator_node import ThrustEstimatorNode


def build_nodes(motors, **kwargs):
    """The three nodes of each motor; ``kwargs`` go to every Node (context, overrides)."""
    nodes = []
    for namespace in namespaces(motors):
        ns = {'namespace': namespace} if namespace else {}
        for node_class in (BatteryFilterNode, TachometerNode, ThrustEstimatorNode):
            nodes.append(node_class(**ns, **kwargs))
    return nodes


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='propulsion_all', description=__doc__.split('\n')[0])
    parser.add_argument('--motors', type=int, default=1,
                        help='motors to run: 1 = process namespace, N > 1 = motor0..motorN-1')
    options = parser.parse_args(argv)
    if options.motors < 1:
        parser.error('--motors must be >= 1')
    return options


def main(args=None):
    argv = sys.argv if args is None else args
    options = parse_args(remove_ros_args(args=argv)[1:])
    rclpy.init(args=argv)
    executor = SingleThreadedExecutor()
    nodes = []
    try:
        nodes = build_nodes(options.motors)
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except BadInputError as e:
        print(f'propulsion_all: {e}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
