#!/usr/bin/env bash
# The test command of the README: set up .venv if needed, then run the whole test suite.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
bash scripts/setup_env.sh
venv="${DEA_ROS_VENV:-$here/.venv}"
export MPLBACKEND=Agg
exec "$venv/bin/python" -m pytest -q "$@"
