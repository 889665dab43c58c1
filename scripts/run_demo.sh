#!/usr/bin/env bash
# The main job of the README: set up .venv if needed, then run the whole rig on mock hardware,
# ending in identified parameters and plots (see README).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
bash scripts/setup_env.sh
venv="${DEA_ROS_VENV:-$here/.venv}"
export MPLBACKEND=Agg
exec "$venv/bin/dea-ros" rig demo "$@"
