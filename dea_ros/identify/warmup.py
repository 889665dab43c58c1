"""The identification's compiled kernels, compiled (or loaded from numba's on-disk cache) ahead of use.

``dea-ros rig demo`` calls :func:`compile_kernels` in a background process while the protocol runs
(the identifier is idle then), so the identification after it finds every kernel in the cache
(:mod:`dea_ros.solvers.jit`: a per-user directory keyed by the kernels' sources and numba's version).
The kernels are compiled by running the identification itself on a small synthetic experiment set
(the same entry points and argument types as a run on a bag), so nothing has to be listed by hand.
A marker file in the cache directory records a completed warm-up for this installation (its path and
the kernel files' stamps, :func:`~dea_ros.solvers.jit.cache_stamp`: numba compiles anew for another
clone or install even in the same cache directory): :func:`kernels_cached` is then True and the demo
skips it.

``scripts/setup_env.sh`` starts the same warm-up in the background as soon as the package is installed
(while pip installs the ROS 2 wheels and the test tools); the demo's warm-up waits for it. Two
warm-ups of one installation never compile side by side: :func:`compile_kernels` holds a lock file in the
cache directory, and a second one waits for the first and then finds the marker (it returns at once).
"""
from __future__ import annotations

import contextlib
import time
from pathlib import Path

from ..model import preset
from ..solvers.jit import CACHE_DIR, cache_stamp
from .pipeline import identify
from .synth import synthesize_experiments

try:
    import fcntl
except ImportError:  # not POSIX: no lock; a second warm-up compiles beside the first (same results)
    fcntl = None

__all__ = ["compile_kernels", "kernels_cached", "warmup_running", "marker_path", "lock_path", "MARKER"]

#: Written into the kernel cache directory once a warm-up completed.
MARKER = ".dea_ros_identify_warm"


def marker_path(cache_dir: str | Path = CACHE_DIR) -> Path:
    """The marker of a completed warm-up of this installation's kernels in ``cache_dir``."""
    return Path(cache_dir) / f"{MARKER}_{cache_stamp()}"


def lock_path(cache_dir: str | Path = CACHE_DIR) -> Path:
    """The lock file a warm-up of this installation's kernels holds while it compiles (``cache_dir``)."""
    return Path(cache_dir) / f"{MARKER}_{cache_stamp()}.lock"


@contextlib.contextmanager
def _warmup_lock(cache_dir: str | Path):
    """Hold the warm-up lock of this installation (waiting for another process's warm-up to end); without a
    writable cache directory or on a system without ``fcntl``, no lock."""
    try:
        Path(cache_dir).mkdir(parents=True, exist_ok=True)
        handle = open(lock_path(cache_dir), "a")
    except OSError:
        handle = None
    try:
        if handle is not None and fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        if handle is not None:
            handle.close()  # releases the lock


def warmup_running(cache_dir: str | Path = CACHE_DIR) -> bool:
    """True while another process's warm-up of this installation holds its lock (set-up's, in the
    background); False without a lock file or without ``fcntl``."""
    if fcntl is None or not lock_path(cache_dir).is_file():
        return False
    try:
        with open(lock_path(cache_dir), "a") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:
        return False
    return False


def kernels_cached(cache_dir: str | Path = CACHE_DIR) -> bool:
    """True when a warm-up completed for this cache directory (this numba, these kernel sources) and this
    installation (its path, the kernel files' stamps: :func:`~dea_ros.solvers.jit.cache_stamp`)."""
    return marker_path(cache_dir).is_file()


def compile_kernels(cache_dir: str | Path = CACHE_DIR) -> float:
    """Run a small identification (static points, one step, three sines, noise 1 um) so that numba compiles
    and caches every kernel the identification uses; writes the marker. Returns the wall time, s, of the
    compilation (0.0 when the kernels were cached, by another warm-up this one waited for or before)."""
    with _warmup_lock(cache_dir):
        if kernels_cached(cache_dir):
            return 0.0
        return _compile_and_mark(cache_dir)


def _compile_and_mark(cache_dir: str | Path) -> float:
    t0 = time.perf_counter()
    truth = preset("A2")
    experiments = synthesize_experiments(truth, 1e-6, seed=1, static_samples=20, step_duration_s=1.0,
                                         sample_rate_Hz=500.0, sine_frequencies_Hz=(5.0, 9.0, 12.0),
                                         series_frequencies_Hz=(9.0,), sine_record_s=1.0, baseline_samples=200)
    identify(experiments, stress_terms=1, joint_slope=True)
    elapsed = time.perf_counter() - t0
    try:
        Path(cache_dir).mkdir(parents=True, exist_ok=True)
        marker_path(cache_dir).write_text(f"warm-up completed in {elapsed:.1f} s for {Path(__file__).parent}\n")
    except OSError:
        pass  # no writable cache: the kernels are compiled in each process anyway
    return elapsed


if __name__ == "__main__":
    _t0 = time.perf_counter()
    _compiled_s = compile_kernels()
    _how = f"compiled in {_compiled_s:.1f} s" if _compiled_s else "already compiled"
    print(f"identification kernels ready ({_how}, waited {time.perf_counter() - _t0:.1f} s; cache {CACHE_DIR})")
