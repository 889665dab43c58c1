#!/usr/bin/env bash
# The test suite on the Python stack of a lab PC's ROS 2 distribution (CI runs both, see .ci/run):
#
#   scripts/run_tests_stack.sh humble [pytest args]   Python 3.10, numpy 1.21.5, scipy 1.8.0, matplotlib 3.5.1,
#                                                     PyYAML 5.4.1, numba 0.55.1 (Ubuntu 22.04's apt versions); no ROS 2:
#                                                     the node tests skip
#   scripts/run_tests_stack.sh humble|jazzy --setup-only   build the stack's venv and stop (CI builds the
#                                                     next stacks' venvs while the first stack's tests run)
#   scripts/run_tests_stack.sh jazzy [pytest args]    Python 3.12, numpy 1.26.4, scipy 1.11.4, numba 0.59.0 (Ubuntu 24.04's),
#                                                     matplotlib 3.8.4 (24.04 has 3.6.3, which PyPI has for
#                                                     Python <= 3.11 only), with Jazzy's rclpy and messages from the
#                                                     ros-jazzy-* wheels: the whole suite, nodes and rig included,
#                                                     except the long numerical tests without ROS (marker
#                                                     numeric_heavy, test/conftest.py: the humble stack runs them)
#
# The environment (.venv-<stack>) is built the way a lab PC gets its packages: first the distribution's
# versions (requirements-stack-<stack>.txt, as apt installs them), then the project's own set-up
# (requirements*.txt and the package, as scripts/setup_env.sh installs them), which must leave the
# distribution's versions alone (checked). The linters are left out (they run on the default stack,
# scripts/run_tests.sh) unless a -m of the caller's says otherwise; ROS_DISTRO is set to the stack's name.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
stack="${1:-}"
case "$stack" in
  humble) pyver=3.10 ;;
  jazzy) pyver=3.12 ;;
  *) echo "usage: scripts/run_tests_stack.sh humble|jazzy [pytest args]" >&2; exit 2 ;;
esac
shift
setup_only=0
if [ "${1:-}" = "--setup-only" ]; then setup_only=1; shift; fi
venv="${DEA_ROS_STACK_VENV:-$here/.venv-$stack}"
constraints="requirements-stack-$stack.txt"

find_python() {
  if [ -n "${DEA_ROS_PYTHON:-}" ]; then echo "$DEA_ROS_PYTHON"; return; fi
  if command -v pyenv >/dev/null 2>&1; then  # pyenv: the newest installed $pyver.x
    local v
    v="$(pyenv versions --bare 2>/dev/null | grep -E "^${pyver//./\\.}\.[0-9]+$" | sort -V | tail -1 || true)"
    if [ -n "$v" ]; then PYENV_VERSION="$v" pyenv which "python$pyver"; return; fi
  fi
  command -v "python$pyver"
}

stamp="$venv/.dea_ros_stack_stamp"
want="$(cat requirements.txt requirements-dev.txt "$constraints" requirements-ros-wheels-jazzy.txt setup.py \
        scripts/run_tests_stack.sh | sha256sum | cut -c1-16)"
if ! { [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$venv/bin/python" ]; }; then
  py="$(find_python)" || { echo "[stack $stack] no Python $pyver found (pyenv install $pyver or set DEA_ROS_PYTHON)" >&2; exit 2; }
  echo "[stack $stack] creating $venv with $py (once; a few minutes)" >&2
  rm -rf "$venv"
  "$py" -m venv "$venv"
  pip() { "$venv/bin/python" -m pip --disable-pip-version-check -q "$@" 2> >(grep -v "^WARNING: Location" >&2); }
  pip install -U pip
  # 1. the distribution's packages (what apt installs on a lab PC)
  if [ "$stack" = humble ]; then
    # PyYAML 5.4.1 has no wheel for Python 3.10 and its sdist does not build with Cython 3
    pip install "cython<3" wheel "setuptools<70"
    pip install --no-build-isolation -c "$constraints" PyYAML
  fi
  pip install -c "$constraints" numpy scipy matplotlib PyYAML pyserial numba
  if [ "$stack" = jazzy ]; then
    pip install -c "$constraints" -r requirements-ros-wheels-jazzy.txt
  fi
  # 2. the project's set-up, as scripts/setup_env.sh runs it (pip's default: satisfied packages stay)
  pip install -r requirements.txt -r requirements-dev.txt
  pip install -e .
  # 3. the distribution's versions must have survived
  "$venv/bin/python" - "$constraints" <<'PY'
import sys
from importlib.metadata import version
pins = [l.split("#")[0].strip() for l in open(sys.argv[1])]
bad = []
for pin in filter(None, pins):
    name, _, want = pin.partition("==")
    if version(name) != want:
        bad.append(f"{name} {version(name)} (the distribution has {want})")
if bad:
    sys.exit("[stack] the project's set-up replaced the distribution's packages: " + ", ".join(bad))
PY
  echo "$want" > "$stamp"
fi
"$venv/bin/python" -c "import sys, numpy, scipy, matplotlib, yaml, numba; print('[stack $stack] Python', sys.version.split()[0], \
'numpy', numpy.__version__, 'numba', numba.__version__, 'scipy', scipy.__version__, 'matplotlib', matplotlib.__version__, 'PyYAML', yaml.__version__)"
if [ "$setup_only" = 1 ]; then exit 0; fi
export MPLBACKEND=Agg ROS_DISTRO="$stack"
if [ "$stack" = jazzy ]; then
  marker="not linter and not numeric_heavy"   # humble runs those (test/conftest.py)
else
  marker="not linter"
fi
# a -m of the caller's comes later on the command line and replaces this one (-m "" runs everything)
# two pytest processes with the groups of test/conftest.py, as scripts/run_tests.sh runs them ("-n 0": one)
exec "$venv/bin/python" -m pytest -q -n "${DEA_ROS_TEST_WORKERS:-2}" --dist loadgroup -m "$marker" "$@"
