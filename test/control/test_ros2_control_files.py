"""The ros2_control description, controllers and launch example: installed by setup.py and consistent.

urdf/dea_rig.ros2_control.xacro (the <ros2_control> tag: topic-based interface, one plugin per
distribution), config/ros2_controllers.yaml (joint_trajectory_controller on dea_joint) and
launch/ros2_control_mock.launch.py must be in setup.py's data_files, parse, and agree with the URDF
and with position_controller_node's installed configuration.
"""
import runpy
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import setuptools
import yaml

ROOT = Path(__file__).resolve().parents[2]
XACRO = ROOT / "urdf" / "dea_rig.ros2_control.xacro"
CONTROLLERS = ROOT / "config" / "ros2_controllers.yaml"
LAUNCH = ROOT / "launch" / "ros2_control_mock.launch.py"
PLUGINS = {"humble": "topic_based_ros2_control/TopicBasedSystem",
           "jazzy": "joint_state_topic_hardware_interface/JointStateTopicSystem"}


def test_setup_installs_the_ros2_control_files(monkeypatch):
    captured = {}
    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(setuptools, "setup", lambda **kw: captured.update(kw))
    runpy.run_path(str(ROOT / "setup.py"))
    files = {(dest, Path(src).name) for dest, srcs in captured["data_files"] for src in srcs}
    assert ("share/dea_ros/urdf", XACRO.name) in files
    assert ("share/dea_ros/config", CONTROLLERS.name) in files
    assert ("share/dea_ros/launch", LAUNCH.name) in files
    assert ("share/dea_ros/urdf", "dea_rig.urdf") in files      # the xacro includes it


def _tag():
    root = ET.parse(XACRO).getroot()
    tags = root.findall("ros2_control")
    assert len(tags) == 1
    return root, tags[0]


def test_the_ros2_control_tag_names_both_plugins_and_the_node_topics():
    root, tag = _tag()
    ns = "{http://www.ros.org/wiki/xacro}"
    hardware = tag.find("hardware")
    branches = {b.tag: b.find("plugin").text for b in hardware if b.tag in (ns + "if", ns + "unless")}
    assert branches == {ns + "if": PLUGINS["humble"], ns + "unless": PLUGINS["jazzy"]}
    assert "humble" in hardware.find(ns + "if").get("value")
    params = {p.get("name"): p.text for p in hardware.findall("param")}
    # the node's topics, in the node's namespace (launch files: /dea)
    node_cfg = yaml.safe_load((ROOT / "config" / "position_controller.yaml").read_text())
    node = node_cfg["/**/position_controller_node"]["ros__parameters"]
    assert params["joint_commands_topic"] == "${ns}/" + node["joint_commands_topic"]
    assert params["joint_states_topic"] == "${ns}/joint_states"
    assert float(params["trigger_joint_command_threshold"]) < 0      # every cycle: 1e-5 m would be 10 um
    assert params["sum_wrapped_joint_states"] == "false"
    joints = tag.findall("joint")
    assert [j.get("name") for j in joints] == [node["joint_name"]]
    assert [c.get("name") for c in joints[0].findall("command_interface")] == ["position", "velocity"]
    assert {s.get("name") for s in joints[0].findall("state_interface")} == {"position", "velocity"}


def test_the_tag_joint_is_the_urdf_prismatic_joint():
    urdf = pytest.importorskip("urdf_parser_py.urdf")
    _, tag = _tag()
    robot = urdf.URDF.from_xml_string((ROOT / "urdf" / "dea_rig.urdf").read_text())
    prismatic = {j.name for j in robot.joints if j.type == "prismatic"}
    assert {j.get("name") for j in tag.findall("joint")} == prismatic


@pytest.mark.parametrize("distro", ["humble", "jazzy"])
def test_xacro_expands_to_one_plugin_per_distribution(distro, tmp_path):
    xacro = pytest.importorskip("xacro")
    src = tmp_path / "urdf"
    src.mkdir()
    (src / XACRO.name).write_text(XACRO.read_text().replace("$(find dea_ros)/urdf", str(ROOT / "urdf")))
    doc = xacro.process_file(str(src / XACRO.name), mappings={"distro": distro, "namespace": "/dea"})
    plugins = [p.firstChild.data for p in doc.getElementsByTagName("plugin")]
    assert plugins == [PLUGINS[distro]]
    assert any(j.getAttribute("name") == "dea_joint" and j.getAttribute("type") == "prismatic"
               for j in doc.getElementsByTagName("joint"))


def test_controllers_yaml_drives_the_joint_with_a_trajectory_controller():
    cfg = yaml.safe_load(CONTROLLERS.read_text())
    cm = cfg["controller_manager"]["ros__parameters"]
    assert cm["update_rate"] > 0
    assert cm["dea_trajectory_controller"]["type"] == "joint_trajectory_controller/JointTrajectoryController"
    assert cm["joint_state_broadcaster"]["type"] == "joint_state_broadcaster/JointStateBroadcaster"
    jtc = cfg["dea_trajectory_controller"]["ros__parameters"]
    _, tag = _tag()
    joint = tag.find("joint")
    assert jtc["joints"] == [joint.get("name")]
    assert jtc["command_interfaces"] == [c.get("name") for c in joint.findall("command_interface")]
    assert set(jtc["state_interfaces"]) <= {s.get("name") for s in joint.findall("state_interface")}


def test_the_launch_example_compiles_and_uses_the_shipped_files():
    text = LAUNCH.read_text()
    compile(text, str(LAUNCH), "exec")
    for name in (XACRO.name, CONTROLLERS.name, "mock_rig_control.launch.py", "ros2_control_node", "spawner",
                 "dea_trajectory_controller", "joint_state_broadcaster"):
        assert name in text
