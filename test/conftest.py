"""The suite's shared set-up: the test doubles of ``test/fakes`` are importable as ``fakes``.

The suite runs with ``--import-mode=importlib`` (test folders are not packages), so the folder of
this file goes on ``sys.path`` once, here, for ``from fakes import load_fake``.
"""
import os
import sys
from pathlib import Path

from dea_ros.blas_threads import use_one_blas_thread

# Before numpy is first imported: the suite computes with one BLAS thread, as the package's command
# line and nodes do (dea_ros.blas_threads). A test that compares a node's fit with the same fit
# in the test process (test_identifier_adaptive: to 1e-9) then compares one computation, not two
# thread counts' roundings (4e-8 apart on the CI machine of stop 28).
use_one_blas_thread()

# Under pytest -n (scripts/run_tests.sh runs the suite on two processes) each worker process uses its
# own ROS domain: the caller's ROS_DOMAIN_ID (or one per run) plus the worker's index, so two node
# tests running at once never see each other's topics. The nodes they start inherit it.
_XDIST_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if _XDIST_WORKER.startswith("gw"):
    _base_domain = int(os.environ.get("ROS_DOMAIN_ID") or 100 + os.getppid() % 40 * 3)  # room for 3 workers
    os.environ["ROS_DOMAIN_ID"] = str((_base_domain + int(_XDIST_WORKER[2:])) % 233)

import pytest  # noqa: E402

TEST_DIR = str(Path(__file__).resolve().parent)
if TEST_DIR not in sys.path:
    sys.path.insert(0, TEST_DIR)


#: Long numerical tests that need no ROS (identification on synthetic membranes, continuation and
#: harmonic balance against forward integration, drift tracking on the simulated rig): marked
#: ``numeric_heavy``. The humble stack runs them (scripts/run_tests_stack.sh humble: the oldest
#: numpy 1.21 / scipy 1.8 / numba 0.55 a lab PC has); the README's test command
#: (scripts/run_tests.sh) and the jazzy stack leave them out, ``scripts/run_tests.sh --all`` runs them
#: too. Each test runs on at least one stack of the CI, within its time budget (.ci/run).
NUMERIC_HEAVY_MODULES = (
    "bag/test_extract.py", "control/test_health.py", "control/test_range_ends.py", "control/test_tracking.py",
    "control/test_window_fit.py", "identify/test_creep_basins.py", "identify/test_many.py", "identify/test_planning.py",
    "identify/test_beyond_fold.py", "identify/test_joint_branches.py", "identify/test_record_truth.py",
    "identify/test_roundtrip.py",
    "identify/test_unidentified_curvature.py", "identify/test_unlike_membrane.py",
    "solvers/test_arclength.py", "solvers/test_continuation.py", "solvers/test_harmonic_balance.py",
)
NUMERIC_HEAVY_TESTS = (
    "identify/test_commands.py::test_synth_then_identify_json",
    "identify/test_report.py::test_report_folder",
    "identify/test_rig_synth.py::test_identification_from_a_held_run_is_within_its_intervals",
    "solvers/test_kernels.py::test_sweep_with_bands_is_the_same_as_the_reference",
    "study/test_study.py::test_dask_local_cluster_with_two_workers_matches_the_serial_run_point_by_point",
)


#: Tests that run a rig or nodes on the ROS graph in their own processes against wall-clock limits: under
#: pytest -n (scripts/run_tests.sh, ``--dist loadgroup``) they all run in one worker, one at a time, as in a
#: one-process run; the other worker takes the rest of the suite meanwhile (the end-to-end demo among it:
#: its lockstep rig slows down under load instead of failing, as the demo does beside other work).
RIG_PATHS = ("nodes/", "test_package.py", "test_rig_check.py")


@pytest.hookimpl(tryfirst=True)   # before pytest-xdist's own hook, which reads the xdist_group marks
def pytest_collection_modifyitems(config, items):
    for item in items:
        path = Path(str(item.fspath)).resolve().relative_to(TEST_DIR).as_posix()
        name = f"{path}::{item.originalname}"
        if path in NUMERIC_HEAVY_MODULES or name in NUMERIC_HEAVY_TESTS:
            item.add_marker(pytest.mark.numeric_heavy)
        # a module's tests stay together (its module-scoped fixtures are built once); the rig tests all in one
        item.add_marker(pytest.mark.xdist_group("rig" if path.startswith(RIG_PATHS) else path))
