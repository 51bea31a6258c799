"""A quadrotor: one pack, four motors (../shared/interfaces.md, "A quadrotor").

    ros2 launch bldc_propulsion quadrotor.launch.py                       # 9 processes
    ros2 launch bldc_propulsion quadrotor.launch.py single_process:=true  # 1 process

One battery filter at the root (/battery/adc -> /battery/voltage), and under /motor<i> a
tachometer and a thrust estimator for each motor; every estimator reads the shared
/battery/voltage. single_process:=true runs the same nodes in one propulsion_all process (the
cheapest: see benchmarks/bench_nodes_live.py). Arguments: motors (4; 1-16), use_sim_time,
params_file, model (passed to every estimator), single_process. A node that exits (a crash, a
refused model or parameter) shuts the launch down, and `ros2 launch` then exits 1 and logs which
node and why (``bldc_propulsion.nodes.launch_watch``); Ctrl-C stops every node and exits 0. A
bad motor count is refused in one line.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessIO
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from bldc_propulsion.nodes.launch_watch import LaunchWatch
from bldc_propulsion.nodes.params import rotor_name
from launch import LaunchDescription

PACKAGE = 'bldc_propulsion'
MAX_MOTORS = 16
SHARED_VOLTAGE = [('battery/voltage', '/battery/voltage')]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('motors', default_value='4', description='number of motors, 1-16'),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='follow /clock (true with `ros2 bag play --clock`)'),
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), 'config', 'propulsion.yaml']),
            description='parameter file of every node'),
        DeclareLaunchArgument(
            'model', default_value='',
            description="model .npz for every estimator; empty = params_file's model_path"),
        DeclareLaunchArgument(
            'single_process', default_value='false',
            description='true = every node in one propulsion_all process'),
        OpaqueFunction(function=launch_vehicle),
    ])


def motor_count(text):
    """The motors argument as an int in 1..MAX_MOTORS, or a one-line error."""
    try:
        motors = int(text)
    except ValueError:
        motors = 0
    if not 1 <= motors <= MAX_MOTORS:
        raise ValueError(f"quadrotor.launch.py: motors must be an integer in 1..{MAX_MOTORS}, "
                         f"got '{text}'")
    return motors


def launch_vehicle(context):
    """The battery filter and each motor's nodes, or one propulsion_all process; each node's
    exit goes to a LaunchWatch (status 1 unless the launch is shutting down)."""
    motors = motor_count(LaunchConfiguration('motors').perform(context))
    watch = LaunchWatch()
    stderr = RegisterEventHandler(OnProcessIO(on_stderr=watch.on_stderr))
    overrides = {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                                value_type=bool)}
    model = LaunchConfiguration('model')
    if model.perform(context):
        overrides['model_path'] = ParameterValue(model, value_type=str)
    parameters = [LaunchConfiguration('params_file'), overrides]

    if LaunchConfiguration('single_process').perform(context).lower() in ('true', '1'):
        return [stderr, Node(package=PACKAGE, executable='propulsion_all',
                             arguments=['--motors', str(motors)] if motors > 1 else [],
                             parameters=parameters, output='screen', on_exit=watch.on_exit)]
    nodes = [stderr, Node(package=PACKAGE, executable='battery_filter', name='battery_filter',
                          parameters=parameters, output='screen', on_exit=watch.on_exit)]
    for i in range(motors):
        namespace = f'motor{i}' if motors > 1 else ''
        # each rotor's own joint and frame on a vehicle (interfaces.md "Stamped outputs")
        joint = [{'joint_name': rotor_name(namespace)}] if namespace else []
        frame = [{'frame_id': rotor_name(namespace)}] if namespace else []
        nodes.append(Node(package=PACKAGE, executable='tachometer', name='tachometer',
                          namespace=namespace, parameters=[*parameters, *joint], output='screen',
                          on_exit=watch.on_exit))
        nodes.append(Node(package=PACKAGE, executable='thrust_estimator',
                          name='thrust_estimator', namespace=namespace,
                          parameters=[*parameters, *joint, *frame], remappings=SHARED_VOLTAGE,
                          output='screen', on_exit=watch.on_exit))
    return nodes
