"""The command line runs BLAS on one thread unless the user's environment says otherwise (issue 22:
a multi-threaded OpenBLAS spin-waiting against the other processes of a busy 2-core machine made the
identification of the demo's bag 5-20x slower). The setting only works when made before numpy is first
imported, so that is checked too, in a fresh process as the ``dea-ros`` console script and ``ros2 run``
(a node module's ``main``) start."""
import importlib.util
import json
import os
import subprocess
import sys

import pytest

VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
PROBE = ("import json, os, sys; import dea_ros.cli; "
         "print(json.dumps({'numpy_before': 'numpy' in sys.modules, "
         "'env': {k: os.environ.get(k) for k in %r}}))" % (VARIABLES,))
# a node's entry point: the variables are set when numpy is first imported (it is, by the node module)
NODE_PROBE = ("import json, os, sys, builtins\n"
              "seen = {}\n"
              "real_import = builtins.__import__\n"
              "def spy(name, *args, **kw):\n"
              "    if name == 'numpy' and 'numpy' not in sys.modules and not seen:\n"
              "        seen.update({k: os.environ.get(k) for k in %r})\n"
              "    return real_import(name, *args, **kw)\n"
              "builtins.__import__ = spy\n"
              "import dea_ros.nodes.identifier_node\n"
              "print(json.dumps({'numpy_loaded': 'numpy' in sys.modules, 'env_at_numpy_import': seen}))"
              % (VARIABLES,))


def _probe(probe=PROBE, **env_extra):
    env = {k: v for k, v in os.environ.items() if k not in VARIABLES}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_cli_sets_one_blas_thread_before_numpy_is_imported():
    seen = _probe()
    assert seen["numpy_before"] is False
    assert seen["env"] == {k: "1" for k in VARIABLES}


def test_a_users_thread_setting_is_kept():
    seen = _probe(OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="3")
    assert seen["env"] == {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "3", "MKL_NUM_THREADS": "1"}


def test_a_node_sets_one_blas_thread_before_numpy_is_imported():
    if importlib.util.find_spec("rclpy") is None:   # (a stack without ROS 2: the node module needs rclpy)
        pytest.skip("rclpy is not installed")
    seen = _probe(NODE_PROBE)
    assert seen["numpy_loaded"] is True
    assert seen["env_at_numpy_import"] == {k: "1" for k in VARIABLES}
