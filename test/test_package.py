"""The ament_python layout: colcon builds it, every node lands where `ros2 run` looks, configs load."""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
NODES = ("amplifier_node", "laser_sensor_node", "model_node", "mock_hardware_node", "identifier_node")


def colcon():
    exe = Path(sys.executable).with_name("colcon")
    return str(exe) if exe.exists() else shutil.which("colcon")


@pytest.fixture(scope="module")
def install(tmp_path_factory):
    if colcon() is None:
        pytest.skip("colcon not installed (pip install colcon-core colcon-ros colcon-python-setup-py)")
    ws = tmp_path_factory.mktemp("ws")
    src = ws / "src" / "dea_ros"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "install", "log",
                                                             "__pycache__", "*.egg-info", ".pytest_cache"))
    out = subprocess.run([colcon(), "build", "--base-paths", "src"], cwd=ws, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    return ws / "install" / "dea_ros"


def test_every_node_is_installed_where_ros2_run_looks(install):
    for node in NODES + ("dea-ros",):
        script = install / "lib" / "dea_ros" / node
        assert script.is_file() and os.access(script, os.X_OK), node
    share = install / "share" / "dea_ros"
    assert (share / "package.xml").is_file()
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / "dea_ros").is_file()
    for name in ("amplifier.yaml", "laser_sensor.yaml", "model.yaml", "mock_hardware.yaml",
                 "membranes/LP1.yaml", "membranes/A1.yaml", "membranes/A2.yaml"):
        assert (share / "config" / name).is_file(), name
    for name in ("mock_rig.launch.py", "rig.launch.py"):
        assert (share / "launch" / name).is_file(), name


def test_installed_node_runs_with_an_installed_params_file(install):
    env = dict(os.environ)
    site = next((install / "lib").glob("python3*/site-packages"))
    env["PYTHONPATH"] = f"{site}:{env.get('PYTHONPATH', '')}"
    env["AMENT_PREFIX_PATH"] = f"{install}:{env.get('AMENT_PREFIX_PATH', '')}"  # as `source install/setup.bash`
    script = install / "lib" / "dea_ros" / "model_node"
    params = install / "share" / "dea_ros" / "config" / "model.yaml"
    proc = subprocess.Popen([sys.executable, str(script), "--ros-args", "--params-file", str(params),
                             "-p", "params_file:=LP1"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(4.0)
        assert proc.poll() is None, proc.stdout.read()
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=10)
    assert "model LP1" in out


@pytest.mark.parametrize("config", ["amplifier", "laser_sensor", "model", "mock_hardware"])
def test_config_files_match_declared_parameters(config, tmp_path):
    """Every key in config/<node>.yaml is a parameter the node declares (no typos), with the same type."""
    import rclpy
    from rclpy.context import Context

    data = yaml.safe_load((ROOT / "config" / f"{config}.yaml").read_text())
    (node_name, section), = data.items()
    params = section["ros__parameters"]
    ctx = Context()
    rclpy.init(context=ctx, args=["--ros-args", "--params-file", str(ROOT / "config" / f"{config}.yaml")])
    try:
        if config == "amplifier":
            from dea_ros.nodes.amplifier_node import AmplifierNode as cls
        elif config == "laser_sensor":
            from dea_ros.nodes.laser_sensor_node import LaserSensorNode as cls
        elif config == "model":
            from dea_ros.nodes.model_node import ModelNode as cls
        else:
            from dea_ros.nodes.mock_hardware_node import MockHardwareNode as cls
        from rclpy.parameter import Parameter

        overrides = []
        if config == "laser_sensor":
            overrides = [Parameter("backend", value="mock")]
        if config == "mock_hardware":
            overrides = [Parameter("laser_port", value=str(tmp_path / "laser")),
                         Parameter("amplifier_port", value=0)]
        node = cls(context=ctx, parameter_overrides=overrides)
        if config == "amplifier":
            node.declare_parameter("autostart", False)
        for key, value in params.items():
            if any(o.name == key for o in overrides):
                continue
            assert node.has_parameter(key), f"{config}.yaml: '{key}' is not a parameter of {node_name}"
            assert node.get_parameter(key).value == value, key
        if hasattr(node, "shutdown_safely"):
            node.shutdown_safely()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
