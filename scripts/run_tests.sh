#!/usr/bin/env bash
# The test command of the README: set up .venv if needed, then run the test suite.
#   scripts/run_tests.sh [pytest args]         every test but the long numerical ones without ROS
#                                              (marker numeric_heavy, test/conftest.py): ~10-12 min on 2 cores
#   scripts/run_tests.sh --all [pytest args]   the whole suite (~20 min on 2 cores)
# CI (.ci/run) runs the numeric_heavy tests on the humble stack (scripts/run_tests_stack.sh humble), so
# each test runs on at least one stack and the whole CI stays within its time budget.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
bash scripts/setup_env.sh
venv="${DEA_ROS_VENV:-$here/.venv}"
export MPLBACKEND=Agg
if [ "${1:-}" = "--all" ]; then
  shift
  exec "$venv/bin/python" -m pytest -q "$@"
fi
# a -m of the caller's comes later on the command line and replaces this one
exec "$venv/bin/python" -m pytest -q -m "not numeric_heavy" "$@"
