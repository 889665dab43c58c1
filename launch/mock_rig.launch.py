"""The whole rig on mock hardware, in real time: ``ros2 launch dea_ros mock_rig.launch.py``.

mock_hardware_node simulates the membrane and serves the amplifier (UDP) and an emulated ILD1320
on a pseudo-terminal; amplifier_node (a lifecycle node, configured and activated at start: safe,
the output only drives the simulation), laser_sensor_node (reading the emulated serial port, the
only publisher of ``displacement``) and model_node run as on the real rig.

Arguments: ``membrane`` (preset or parameters YAML: the amplifier's limits and the model),
``true_params`` (the simulated membrane, default: ``membrane``), ``namespace`` (default ``dea``),
``laser_port`` (symlink of the emulated sensor), ``amplifier_port`` (UDP).
Every node reads its ``config/<node>.yaml`` first; the values below override it.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    """Mock hardware, amplifier (autostarted lifecycle node), laser sensor and model in /dea."""
    config = os.path.join(get_package_share_directory("dea_ros"), "config")
    ns = LaunchConfiguration("namespace")
    membrane = ParameterValue(LaunchConfiguration("membrane"), value_type=str)
    port = ParameterValue(LaunchConfiguration("amplifier_port"), value_type=int)
    laser_port = ParameterValue(LaunchConfiguration("laser_port"), value_type=str)
    standoff_m = 0.002  # the emulated sensor reads this at the flat membrane; the laser node tares on it
    return LaunchDescription([
        DeclareLaunchArgument("membrane", default_value="A2", description="preset (LP1, A1, A2) or parameters YAML"),
        DeclareLaunchArgument("true_params", default_value=LaunchConfiguration("membrane"),
                              description="the simulated membrane (preset or YAML)"),
        DeclareLaunchArgument("namespace", default_value="dea", description="namespace of the rig"),
        DeclareLaunchArgument("laser_port", default_value="/tmp/dea_ros_mock_laser",
                              description="symlink of the emulated ILD1320's serial port"),
        DeclareLaunchArgument("amplifier_port", default_value="5765", description="UDP port of the mock amplifier"),
        Node(package="dea_ros", executable="mock_hardware_node", name="mock_hardware_node", namespace=ns,
             output="screen",
             parameters=[os.path.join(config, "mock_hardware.yaml"),
                         {"params_file": ParameterValue(LaunchConfiguration("true_params"), value_type=str),
                          "amplifier_port": port, "laser_output": "emulator", "laser_port": laser_port,
                          "laser_standoff_m": standoff_m, "publish_clock": False}]),
        LifecycleNode(package="dea_ros", executable="amplifier_node", name="amplifier_node", namespace=ns,
                      output="screen",
                      parameters=[os.path.join(config, "amplifier.yaml"),
                                  {"backend": "mock", "mock_port": port, "params_file": membrane,
                                   "autostart": True}]),
        Node(package="dea_ros", executable="laser_sensor_node", name="laser_sensor_node", namespace=ns,
             output="screen",
             parameters=[os.path.join(config, "laser_sensor.yaml"),
                         {"backend": "ild1320", "port": laser_port, "zero_offset_m": standoff_m,
                          "params_file": membrane}]),
        Node(package="dea_ros", executable="model_node", name="model_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "model.yaml"), {"params_file": membrane}]),
    ])
