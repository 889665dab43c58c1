"""The real rig:  ros2 launch dea_ros rig.launch.py membrane:=A2 laser_port:=/dev/ttyUSB0

amplifier_node drives a Measurement Computing DAQ (uldaq) into the high-voltage amplifier
(it starts inactive: activate with `ros2 lifecycle set /dea/amplifier_node configure` then
`activate`, or pass autostart:=true), laser_sensor_node reads the ILD1320, model_node predicts.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node


def generate_launch_description():
    config = os.path.join(get_package_share_directory("dea_ros"), "config")
    membrane = LaunchConfiguration("membrane")
    ns = LaunchConfiguration("namespace")
    return LaunchDescription([
        DeclareLaunchArgument("membrane", default_value="A2"),
        DeclareLaunchArgument("namespace", default_value="dea"),
        DeclareLaunchArgument("laser_port", default_value="/dev/ttyUSB0"),
        DeclareLaunchArgument("autostart", default_value="false"),
        LifecycleNode(package="dea_ros", executable="amplifier_node", name="amplifier_node", namespace=ns,
                      output="screen",
                      parameters=[os.path.join(config, "amplifier.yaml"),
                                  {"backend": "uldaq", "params_file": membrane,
                                   "autostart": LaunchConfiguration("autostart")}]),
        Node(package="dea_ros", executable="laser_sensor_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "laser_sensor.yaml"), {"port": LaunchConfiguration("laser_port")}]),
        Node(package="dea_ros", executable="model_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "model.yaml"), {"params_file": membrane}]),
    ])
