"""urdf/dea_rig.urdf: parses with urdf_parser_py, REP 103 frames, joint position = displacement (+ down)."""
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

urdf = pytest.importorskip("urdf_parser_py.urdf")

ROOT = Path(__file__).resolve().parents[2]


def _rot(rpy):
    r, p, y = rpy
    cx, sx, cy, sy, cz, sz = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) \
        @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])


def test_urdf_parses_with_the_prismatic_joint_and_frames():
    robot = urdf.URDF.from_xml_string((ROOT / "urdf" / "dea_rig.urdf").read_text())
    assert robot.get_root() == "base_link"
    links = {link.name for link in robot.links}
    assert {"base_link", "membrane_link", "mass_link", "laser_link"} <= links
    joints = {j.name: j for j in robot.joints}
    joint = joints["dea_joint"]
    assert joint.type == "prismatic"
    # + downwards displacement: a positive joint position moves the mass along -z (REP 103: z up)
    assert list(joint.axis) == [0, 0, -1]
    assert joint.limit.lower == 0.0 and joint.limit.upper >= 0.0015
    # the laser looks down: its x axis (the Range axis) is -z of base_link, and it sits above the mass
    laser = joints["laser_joint"]
    x_axis = _rot(laser.origin.rpy) @ np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(x_axis, [0, 0, -1], atol=1e-12)
    assert laser.origin.xyz[2] > 0.0
    mass = next(link for link in robot.links if link.name == "mass_link")
    assert mass.inertial.mass == pytest.approx(0.003)


def test_config_joint_name_matches_the_urdf():
    cfg = yaml.safe_load((ROOT / "config" / "position_controller.yaml").read_text())
    name = cfg["/**/position_controller_node"]["ros__parameters"]["joint_name"]
    robot = urdf.URDF.from_xml_string((ROOT / "urdf" / "dea_rig.urdf").read_text())
    assert name in {j.name for j in robot.joints if j.type == "prismatic"}
