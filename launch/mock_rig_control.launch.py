"""Mock rig + position control:  ros2 launch dea_ros mock_rig_control.launch.py params_file:=runs/<run>/params.yaml

mock_hardware_node simulates the membrane (``membrane``, by default the demo's "true" membrane
config/rig/mock_membrane.yaml) and serves the amplifier (UDP) and the ILD1320 emulator (pty);
laser_sensor_node reads it at 1 kHz; amplifier_node (lifecycle, autostarted) applies the voltage
within its safety limits; position_controller_node (lifecycle, autostarted) controls the
displacement with the model in ``params_file`` (the identifier's params.yaml; default the nominal A2).
Drive it with ``ros2 topic pub --once /dea/displacement_setpoint std_msgs/msg/Float64 "{data: 0.0008}"``
or a trajectory_msgs/JointTrajectory on /dea/joint_trajectory (joint ``dea_joint``, positions in m).
Arguments: membrane, params_file, namespace, autostart, publish_tf (robot_state_publisher with
urdf/dea_rig.urdf: TF of the mass from joint_states; needs ros-$ROS_DISTRO-robot-state-publisher).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    share = get_package_share_directory("dea_ros")
    config = os.path.join(share, "config")
    membrane = ParameterValue(LaunchConfiguration("membrane"), value_type=str)
    params_file = ParameterValue(LaunchConfiguration("params_file"), value_type=str)
    ns = LaunchConfiguration("namespace")
    autostart = ParameterValue(LaunchConfiguration("autostart"), value_type=bool)
    with open(os.path.join(share, "urdf", "dea_rig.urdf")) as f:
        robot_description = f.read()
    return LaunchDescription([
        DeclareLaunchArgument("membrane", default_value=os.path.join(config, "rig", "mock_membrane.yaml"),
                              description="the simulated (true) membrane: preset or parameters YAML"),
        DeclareLaunchArgument("params_file", default_value="A2",
                              description="the controller's model: identified params.yaml or preset"),
        DeclareLaunchArgument("namespace", default_value="dea", description="namespace of the rig topics"),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="configure + activate the lifecycle nodes at start"),
        DeclareLaunchArgument("publish_tf", default_value="false",
                              description="robot_state_publisher with urdf/dea_rig.urdf"),
        Node(package="dea_ros", executable="mock_hardware_node", name="mock_hardware_node", namespace=ns,
             output="screen",
             parameters=[os.path.join(config, "mock_hardware.yaml"), {"params_file": membrane}]),
        LifecycleNode(package="dea_ros", executable="amplifier_node", name="amplifier_node", namespace=ns,
                      output="screen",
                      parameters=[os.path.join(config, "amplifier.yaml"),
                                  {"params_file": params_file, "autostart": autostart}]),
        Node(package="dea_ros", executable="laser_sensor_node", name="laser_sensor_node", namespace=ns,
             output="screen",
             parameters=[os.path.join(config, "laser_sensor.yaml"),
                         {"port": "/tmp/dea_ros_mock_laser", "zero_offset_m": 0.002, "params_file": membrane,
                          "measuring_rate_hz": 1000.0, "poll_period_s": 0.001}]),
        LifecycleNode(package="dea_ros", executable="position_controller_node", name="position_controller_node",
                      namespace=ns, output="screen",
                      parameters=[os.path.join(config, "position_controller.yaml"),
                                  {"params_file": params_file, "autostart": autostart,
                                   "sample_period_s": 0.001}]),
        Node(package="robot_state_publisher", executable="robot_state_publisher", namespace=ns, output="screen",
             condition=IfCondition(LaunchConfiguration("publish_tf")),
             parameters=[{"robot_description": robot_description}]),
    ])
