"""One motor: battery_filter, tachometer and thrust_estimator under an optional namespace.

    ros2 launch bldc_propulsion propulsion.launch.py use_sim_time:=true
    ros2 bag play BENCH_BAG --clock          # the bench names are the root names

Arguments: namespace ('' = root names), use_sim_time (false), params_file (the installed
config/propulsion.yaml), model (a model .npz; '' = model_path of params_file, whose default
'' is the first-principles fallback), single_process (true = one propulsion_all process).

A node that exits (a crash, a refused model or parameter) shuts the launch down, and `ros2
launch` then exits 1 and logs which node and why (``bldc_propulsion.nodes.launch_watch``);
Ctrl-C stops every node and exits 0.
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessIO
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from bldc_propulsion.nodes.launch_watch import LaunchWatch
from launch import LaunchDescription

PACKAGE = 'bldc_propulsion'
NODES = ('battery_filter', 'tachometer', 'thrust_estimator')  # executable = node name


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument(
            'namespace', default_value='',
            description="namespace of the motor's topics, e.g. motor0; empty = root names"),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='follow /clock (true with `ros2 bag play --clock`)'),
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), 'config', 'propulsion.yaml']),
            description='parameter file of the three nodes'),
        DeclareLaunchArgument(
            'model', default_value='',
            description="model .npz for thrust_estimator; empty = params_file's model_path"),
        DeclareLaunchArgument(
            'single_process', default_value='false',
            description='true = the three nodes in one propulsion_all process'),
        OpaqueFunction(function=launch_nodes),
    ])


def launch_nodes(context):
    """The nodes, with the model override only when a model is given; each node's exit goes
    to a LaunchWatch, which ends the launch with status 1 unless it is shutting down."""
    watch = LaunchWatch()
    stderr = RegisterEventHandler(OnProcessIO(on_stderr=watch.on_stderr))
    namespace = LaunchConfiguration('namespace')
    use_sim_time = ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)
    overrides = {'use_sim_time': use_sim_time}
    if LaunchConfiguration('model').perform(context):
        overrides['model_path'] = ParameterValue(LaunchConfiguration('model'), value_type=str)
    parameters = [LaunchConfiguration('params_file'), overrides]

    if LaunchConfiguration('single_process').perform(context).lower() in ('true', '1'):
        return [stderr, Node(package=PACKAGE, executable='propulsion_all', namespace=namespace,
                             parameters=parameters, output='screen', on_exit=watch.on_exit)]
    return [stderr, *[Node(package=PACKAGE, executable=name, name=name, namespace=namespace,
                           parameters=parameters, output='screen', on_exit=watch.on_exit)
                      for name in NODES]]
