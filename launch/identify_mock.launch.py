"""Identification run on the mock rig in simulated time: ``ros2 launch dea_ros identify_mock.launch.py``.

The launch equivalent of ``dea-ros rig demo``. mock_hardware_node simulates ``true_params`` and is
the clock master (``/clock`` up to ``speed`` times real time, lockstep with the amplifier and the
identifier); every node runs with ``use_sim_time``. identifier_node runs ``protocol``, records the
bag into ``output_dir/run_name/bag`` and identifies the membrane offline when the protocol ends
(``params.yaml``, ``report/``, ``summary.json`` beside the bag); then the launch shuts down.

The amplifier is a lifecycle node, autostarted (safe: it drives the simulation only). The mock
publishes ``displacement`` itself (no serial emulator in simulated time), so there is no
laser_sensor_node.

Arguments: ``membrane`` (nominal membrane: limits, model, geometry of the fit), ``true_params``
(simulated membrane, default ``config/rig/mock_membrane.yaml``), ``protocol`` (paper, quick, test
or a YAML), ``speed``, ``rate`` (command/amplifier/clock rate, Hz), ``laser_rate`` (Hz), ``noise``
(m), ``command_batch`` (commands of K amplifier updates per message, as ``dea-ros rig demo
--command-batch``), ``output_dir``, ``run_name`` (empty: date and time), ``namespace``,
``amplifier_port``. The clock waits for the amplifier's receipt of each command (batch) and stands
while the identifier identifies.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    """Mock rig in simulated time + identifier_node; ends when the identification is written."""
    config = os.path.join(get_package_share_directory("dea_ros"), "config")
    ns = LaunchConfiguration("namespace")

    def arg(name, value_type):
        return ParameterValue(LaunchConfiguration(name), value_type=value_type)

    membrane = arg("membrane", str)
    rate = arg("rate", float)
    port = arg("amplifier_port", int)
    sim = {"use_sim_time": True}
    identifier = Node(
        package="dea_ros", executable="identifier_node", name="identifier_node", namespace=ns, output="screen",
        parameters=[os.path.join(config, "identifier.yaml"),
                    {**sim, "protocol": arg("protocol", str), "output_dir": arg("output_dir", str),
                     "run_name": arg("run_name", str), "membrane": membrane, "command_rate_hz": rate,
                     "identify": True, "exit_when_done": True,
                     # as dea-ros rig demo: one command per amplifier update, sent K updates at a time
                     "command_trigger": "applied_voltage", "command_batch": arg("command_batch", int)}])
    return LaunchDescription([
        DeclareLaunchArgument("membrane", default_value="A2", description="nominal membrane (preset or YAML)"),
        DeclareLaunchArgument("true_params", default_value=os.path.join(config, "rig", "mock_membrane.yaml"),
                              description="the simulated membrane (preset or YAML)"),
        DeclareLaunchArgument("protocol", default_value="paper", description="paper, quick, test or a YAML"),
        DeclareLaunchArgument("speed", default_value="10.0", description="simulated seconds per wall second (max)"),
        DeclareLaunchArgument("rate", default_value="250.0", description="command, amplifier and clock rate, Hz"),
        DeclareLaunchArgument("laser_rate", default_value="500.0", description="displacement sample rate, Hz"),
        DeclareLaunchArgument("noise", default_value="1.0e-6", description="laser noise sigma, m"),
        DeclareLaunchArgument("command_batch", default_value="25",
                              description="commands per voltage_cmd_batch (1: one voltage_cmd per update)"),
        DeclareLaunchArgument("output_dir", default_value="runs", description="folder of the runs"),
        DeclareLaunchArgument("run_name", default_value="", description="folder of this run (empty: date)"),
        DeclareLaunchArgument("namespace", default_value="dea", description="namespace of the rig"),
        DeclareLaunchArgument("amplifier_port", default_value="5765", description="UDP port of the mock amplifier"),
        Node(package="dea_ros", executable="mock_hardware_node", name="mock_hardware_node", namespace=ns,
             output="screen",
             parameters=[os.path.join(config, "mock_hardware.yaml"),
                         {"params_file": arg("true_params", str), "amplifier_port": port,
                          "noise_m": arg("noise", float), "sample_rate_hz": arg("laser_rate", float),
                          "laser_output": "topic", "publish_clock": True, "real_time_factor": arg("speed", float),
                          "clock_rate_hz": rate, "lockstep": True,
                          # the clock waits for the amplifier's receipt of each command (batch) and
                          # stands while nobody acknowledges (the identification after the protocol)
                          "lockstep_topics": ["amplifier_node/command_received"], "pause_when_idle": True,
                          # the ticks of one batch of commands per /clock message (the amplifier runs each)
                          "max_ticks_per_clock": 50}]),
        LifecycleNode(package="dea_ros", executable="amplifier_node", name="amplifier_node", namespace=ns,
                      output="screen",
                      parameters=[os.path.join(config, "amplifier.yaml"),
                                  {**sim, "backend": "mock", "mock_port": port, "params_file": membrane,
                                   "autostart": True, "update_rate_hz": rate, "slew_rate_V_per_s": 400000.0,
                                   "ramp_down_rate_V_per_s": 20000.0, "watchdog_timeout_s": 0.5}]),
        Node(package="dea_ros", executable="model_node", name="model_node", namespace=ns, output="screen",
             parameters=[os.path.join(config, "model.yaml"), {**sim, "params_file": membrane, "rate_hz": rate}]),
        identifier,
        RegisterEventHandler(OnProcessExit(target_action=identifier, on_exit=[
            EmitEvent(event=Shutdown(reason="identifier_node finished"))])),
    ])
