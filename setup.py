"""ament_python package dea_ros (also pip-installable; ROS packages are NOT pip requirements)."""
from glob import glob

from setuptools import find_packages, setup

package_name = "dea_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "README.md"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/membranes", glob("config/membranes/*.yaml")),
        ("share/" + package_name + "/config/protocols", glob("config/protocols/*.yaml")),
        ("share/" + package_name + "/config/rig", glob("config/rig/*.yaml")),
        ("share/" + package_name + "/config/studies", glob("config/studies/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        ("share/" + package_name + "/urdf", glob("urdf/*.urdf") + glob("urdf/*.xacro")),
    ],
    # rclpy and the message packages come from the ROS 2 installation (apt) or, where no ROS 2
    # is sourced, from requirements-ros-wheels.txt: never from install_requires.
    # Minimum versions: the oldest each line of code needs, tested in CI (.ci/run, stack humble:
    # Ubuntu 22.04's numpy 1.21.5, scipy 1.8.0, matplotlib 3.5.1, PyYAML 5.4.1, pyserial 3.5, numba 0.55.1).
    # On a lab PC apt's packages satisfy them, so pip leaves them alone.
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.21.5",
        "scipy>=1.8.0",
        "PyYAML>=5.4.1",
        "matplotlib>=3.5.1",
        "mcap>=1.1",
        "mcap-ros2-support>=0.5",
        "pyserial>=3.5",
        # the compiled kernels of the solvers (harmonic balance, continuation, Floquet): Ubuntu 22.04's 0.55.1
        "numba>=0.55",
    ],
    extras_require={
        # numba is required now (install_requires); the extra stays so that `pip install dea_ros[fast]` still works
        "fast": ["numba>=0.55"],
        # only for `--method mousai` (the paper's harmonic-balance code, for comparison)
        "mousai": ["mousai==0.3.1"],
        # only for amplifier_node backend uldaq (Measurement Computing DAQ); needs libuldaq (README)
        "uldaq": ["uldaq>=1.2.3"],
        # only for `dea-ros study` / `dea-ros identify` on many inputs: Dask engine (local cluster or
        # --scheduler ADDRESS), Parquet results, a progress bar; without them: local processes, CSV, text
        "study": ["dask[distributed]>=2022.1", "distributed>=2022.1", "pyarrow>=10", "tqdm>=4.57"],
    },
    zip_safe=True,
    maintainer="dea_ros developers",
    maintainer_email="dea-ros@example.org",
    description="DEA model, harmonic-balance identification and ROS 2 rig nodes",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "dea-ros = dea_ros.cli:main",
            "amplifier_node = dea_ros.nodes.amplifier_node:main",
            "laser_sensor_node = dea_ros.nodes.laser_sensor_node:main",
            "model_node = dea_ros.nodes.model_node:main",
            "mock_hardware_node = dea_ros.nodes.mock_hardware_node:main",
            "identifier_node = dea_ros.nodes.identifier_node:main",
            "position_controller_node = dea_ros.nodes.position_controller_node:main",
        ],
    },
)
