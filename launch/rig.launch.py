"""The real rig: ``ros2 launch dea_ros rig.launch.py membrane:=A2 laser_port:=/dev/ttyUSB0``.

amplifier_node drives a Measurement Computing DAQ (uldaq) into the high-voltage amplifier. It is a
lifecycle node that starts UNCONFIGURED (0 V) and is never autostarted here: a person enables the
high voltage with

    ros2 lifecycle set /dea/amplifier_node configure
    ros2 lifecycle set /dea/amplifier_node activate

(``deactivate`` ramps to 0 V). laser_sensor_node reads the ILD1320 on ``laser_port``, model_node
predicts the displacement from the applied voltage. Every node reads its ``config/<node>.yaml``
first; the values below override it.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    """Amplifier (lifecycle, manual activation), laser sensor and model in /dea."""
    config = os.path.join(get_package_share_directory("dea_ros"), "config")
    ns = LaunchConfiguration("namespace")
    membrane = ParameterValue(LaunchConfiguration("membrane"), value_type=str)
    return LaunchDescription([
        DeclareLaunchArgument("membrane", default_value="A2",
                              description="preset (LP1, A1, A2) or parameters YAML: bounds the voltage"),
        DeclareLaunchArgument("namespace", default_value="dea", description="namespace of the rig"),
        DeclareLaunchArgument("laser_port", default_value="/dev/ttyUSB0",
                              description="serial device of the ILD1320 (RS422/USB adapter)"),
        LifecycleNode(package="dea_ros", executable="amplifier_node", name="amplifier_node", namespace=ns,
                      output="screen",
                      parameters=[os.path.join(config, "amplifier.yaml"),
                                  {"backend": "uldaq", "params_file": membrane, "autostart": False}]),
        Node(package="dea_ros", executable="laser_sensor_node", name="laser_sensor_node", namespace=ns,
             output="screen",
             parameters=[os.path.join(config, "laser_sensor.yaml"),
                         {"backend": "ild1320", "params_file": membrane,
                          "port": ParameterValue(LaunchConfiguration("laser_port"), value_type=str)}]),
        Node(package="dea_ros", executable="model_node", name="model_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "model.yaml"), {"params_file": membrane}]),
    ])
