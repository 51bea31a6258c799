"""Four motors, /motor0 ... /motor3, from one parameter file.

    ros2 launch bldc_propulsion quadrotor.launch.py                       # 12 processes
    ros2 launch bldc_propulsion quadrotor.launch.py single_process:=true  # 1 process

Separate processes: propulsion.launch.py included once per motor with namespace motor<i>.
single_process:=true: one propulsion_all process running the 12 nodes (--motors 4).
Arguments use_sim_time, params_file and model are passed to every motor.
"""

from launch import LaunchDescription
from launch.actions import (
    DeclareLaunchArgument, GroupAction, IncludeLaunchDescription, OpaqueFunction)
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

PACKAGE = 'bldc_propulsion'
MOTORS = 4


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument(
            'use_sim_time', default_value='false',
            description='follow /clock (true with `ros2 bag play --clock`)'),
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), 'config', 'propulsion.yaml']),
            description='parameter file of every node of every motor'),
        DeclareLaunchArgument(
            'model', default_value='',
            description="model .npz for all four estimators; empty = params_file's model_path"),
        DeclareLaunchArgument(
            'single_process', default_value='false',
            description='true = all 12 nodes in one propulsion_all process'),
        OpaqueFunction(function=launch_motors),
    ])


def launch_motors(context):
    """Four includes of propulsion.launch.py, or one propulsion_all process."""
    use_sim_time = LaunchConfiguration('use_sim_time')
    params_file = LaunchConfiguration('params_file')
    model = LaunchConfiguration('model')

    if LaunchConfiguration('single_process').perform(context).lower() in ('true', '1'):
        overrides = {'use_sim_time': ParameterValue(use_sim_time, value_type=bool)}
        if model.perform(context):
            overrides['model_path'] = ParameterValue(model, value_type=str)
        return [Node(package=PACKAGE, executable='propulsion_all',
                     arguments=['--motors', str(MOTORS)],
                     parameters=[params_file, overrides], output='screen')]

    one_motor = PathJoinSubstitution([FindPackageShare(PACKAGE), 'launch', 'propulsion.launch.py'])
    return [
        GroupAction([  # scoped: each include keeps its own launch arguments
            IncludeLaunchDescription(
                PythonLaunchDescriptionSource(one_motor),
                launch_arguments={
                    'namespace': f'motor{i}',
                    'use_sim_time': use_sim_time,
                    'params_file': params_file,
                    'model': model,
                    'single_process': 'false',
                }.items()),
        ])
        for i in range(MOTORS)
    ]
