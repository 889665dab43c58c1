#!/usr/bin/env bash
# The test command of the README: set up .venv if needed, then run the test suite.
#   scripts/run_tests.sh [pytest args]         every test but the long numerical ones without ROS
#                                              (marker numeric_heavy, test/conftest.py): ~8 min on 2
#                                              cores from a fresh clone, set-up included
#   scripts/run_tests.sh --all [pytest args]   the whole suite (~14 min on 2 cores)
# The suite runs on DEA_ROS_TEST_WORKERS (default 2) pytest processes (pytest-xdist, --dist loadgroup,
# groups in test/conftest.py): a module's tests stay in one process (its fixtures are built once) and the
# tests that run a rig or nodes all run in one process, one at a time; each process uses its own ROS
# domain. "-n 0" among the pytest args runs the suite in one process. (Three processes on two cores were
# faster -- 386 s against 415 s, warm venv -- but the rig tests' lockstep and wall-clock checks failed
# under the CI's load: two.) On a first run the set-up's compilation of the identification's kernels
# (scripts/setup_env.sh) goes on beside the first tests (waiting for it first was slower: 8 min 22 s
# against 8 min 01 s from a fresh clone).
# CI (.ci/run) runs the numeric_heavy tests on the humble stack (scripts/run_tests_stack.sh humble), so
# each test runs on at least one stack and the whole CI stays within its time budget.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
bash scripts/setup_env.sh
venv="${DEA_ROS_VENV:-$here/.venv}"
export MPLBACKEND=Agg
workers=(-n "${DEA_ROS_TEST_WORKERS:-2}" --dist loadgroup)
if [ "${1:-}" = "--all" ]; then
  shift
  exec "$venv/bin/python" -m pytest -q "${workers[@]}" "$@"
fi
# a -m of the caller's comes later on the command line and replaces this one
exec "$venv/bin/python" -m pytest -q "${workers[@]}" -m "not numeric_heavy" "$@"
