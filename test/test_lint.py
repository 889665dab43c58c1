"""The ament_python linter tests with the project's style (setup.cfg): flake8 and PEP 257 docstrings.

The linters come from PyPI (requirements-dev.txt) or, on a lab PC, from python3-flake8 and
ament_pep257 (package.xml test_depend); without them these tests are skipped. The ROS ament_flake8
defaults (99 columns, single quotes, Google import order) do not match this code, so the checks run
plain flake8 and pydocstyle with the configuration in setup.cfg.
"""
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: what is linted: the package, its tests and benchmarks, the launch files and the setup script
PATHS = ["dea_ros", "test", "bench", "launch", "setup.py"]


def run(module: str) -> subprocess.CompletedProcess:
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} not installed (pip install -r requirements-dev.txt)")
    return subprocess.run([sys.executable, "-m", module] + PATHS, cwd=ROOT, capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)


@pytest.mark.linter
def test_flake8():
    out = run("flake8")
    assert out.returncode == 0, f"flake8 found problems (config: setup.cfg [flake8]):\n{out.stdout}{out.stderr}"


@pytest.mark.linter
def test_pep257():
    out = run("pydocstyle")
    assert out.returncode == 0, \
        f"pydocstyle found problems (config: setup.cfg [pydocstyle]):\n{out.stdout}{out.stderr}"
