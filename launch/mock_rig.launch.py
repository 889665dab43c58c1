"""The whole rig on mock hardware (lab PC with ROS 2):  ros2 launch dea_ros mock_rig.launch.py

mock_hardware_node serves the amplifier (UDP) and the ILD1320 emulator (pty); amplifier_node
(autostarted lifecycle), laser_sensor_node and model_node run as on the real rig.
Arguments: membrane (preset or params YAML for the mock and the model), namespace.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory("dea_ros"), "config")
    membrane = LaunchConfiguration("membrane")
    ns = LaunchConfiguration("namespace")
    return LaunchDescription([
        DeclareLaunchArgument("membrane", default_value="A2", description="preset or parameters YAML"),
        DeclareLaunchArgument("namespace", default_value="dea", description="namespace of the rig topics"),
        Node(package="dea_ros", executable="mock_hardware_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "mock_hardware.yaml"), {"params_file": membrane}]),
        Node(package="dea_ros", executable="amplifier_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "amplifier.yaml"), {"params_file": membrane, "autostart": True}]),
        Node(package="dea_ros", executable="laser_sensor_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "laser_sensor.yaml"),
                         {"port": "/tmp/dea_ros_mock_laser", "zero_offset_m": 0.002}]),
        Node(package="dea_ros", executable="model_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "model.yaml"), {"params_file": membrane}]),
    ])
