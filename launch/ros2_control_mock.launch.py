r"""The mock rig driven by ros2_control:  ros2 launch dea_ros ros2_control_mock.launch.py

mock_rig_control.launch.py (the simulated membrane, amplifier_node, laser_sensor_node,
position_controller_node in ``namespace``) plus a controller manager whose hardware is the
topic-based interface of urdf/dea_rig.ros2_control.xacro (``topic_based_ros2_control/TopicBasedSystem``
on Humble, ``joint_state_topic_hardware_interface/JointStateTopicSystem`` on Jazzy and later), the
controllers of config/ros2_controllers.yaml (joint_state_broadcaster, dea_trajectory_controller: a
joint_trajectory_controller on ``dea_joint``) and robot_state_publisher. The controllers are spawned
``controller_delay_s`` after the start, once position_controller_node is tracking (the trajectory
controller holds the position it reads on activation).

Needs ros-$ROS_DISTRO-ros2-control, -ros2-controllers, -xacro, -robot-state-publisher and the hardware
interface (humble: ros-humble-topic-based-ros2-control; jazzy: ros-jazzy-joint-state-topic-hardware-interface).
Move the mass with a trajectory (positions = displacement d in m, + downwards)::

    ros2 action send_goal /dea_trajectory_controller/follow_joint_trajectory \
      control_msgs/action/FollowJointTrajectory \
      "{trajectory: {joint_names: [dea_joint], points: [{positions: [0.0008], time_from_start: {sec: 1}}]}}"

Arguments: those of mock_rig_control.launch.py and ``controller_delay_s``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription, TimerAction
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import Command, EnvironmentVariable, FindExecutable, LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

NAMESPACE = "dea"


def generate_launch_description():
    share = get_package_share_directory("dea_ros")
    # the description expanded by the xacro executable at launch (its distro argument picks the plugin)
    description = ParameterValue(
        Command([FindExecutable(name="xacro"), " ", os.path.join(share, "urdf", "dea_rig.ros2_control.xacro"),
                 " distro:=", EnvironmentVariable("ROS_DISTRO", default_value="jazzy"),
                 " namespace:=/" + NAMESPACE]),
        value_type=str)
    controllers = os.path.join(share, "config", "ros2_controllers.yaml")
    delay = LaunchConfiguration("controller_delay_s")
    return LaunchDescription([
        DeclareLaunchArgument("controller_delay_s", default_value="5.0",
                              description="spawn the controllers this long after the start, s"),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(os.path.join(share, "launch", "mock_rig_control.launch.py")),
            launch_arguments={"namespace": NAMESPACE}.items()),
        Node(package="robot_state_publisher", executable="robot_state_publisher", output="screen",
             parameters=[{"robot_description": description}]),
        Node(package="controller_manager", executable="ros2_control_node", output="screen",
             parameters=[{"robot_description": description}, controllers]),
        TimerAction(period=delay, actions=[
            Node(package="controller_manager", executable="spawner", output="screen",
                 arguments=["joint_state_broadcaster", "dea_trajectory_controller",
                            "--controller-manager", "/controller_manager"]),
        ]),
    ])
