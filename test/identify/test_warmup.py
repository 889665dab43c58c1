"""The demo's kernel warm-up is skipped once its marker for this installation is in the kernel cache.

numba finds a cache entry by the kernel module's absolute directory and its file's modification time and
size: a fresh clone (or another install) of the same sources compiles every kernel again although the cache
directory (keyed by the sources) is the same. A marker that ignored this said "cached" to every new clone of
a machine that had run the demo once, and the demo then compiled in its identification instead of in the
background during the protocol (fresh clone, session 12: identification 103 s, of it ~75 s compiling;
23-28 s once compiled)."""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import dea_ros
from dea_ros.identify.warmup import MARKER, kernels_cached, marker_path
from dea_ros.solvers.jit import CACHE_DIR, KERNEL_SOURCES

STAMP = "from dea_ros.solvers.jit import cache_stamp; print(cache_stamp())"


def test_marker_of_this_installation_means_cached(tmp_path):
    assert not kernels_cached(tmp_path)
    (tmp_path / MARKER).write_text("warm-up completed in 1.0 s\n")      # the old, installation-blind marker
    (tmp_path / f"{MARKER}_0123456789abcdef").write_text("warm-up completed in 1.0 s\n")   # another clone's
    assert not kernels_cached(tmp_path)
    marker_path(tmp_path).write_text("warm-up completed in 1.0 s\n")
    assert kernels_cached(tmp_path)
    assert isinstance(kernels_cached(), bool) and CACHE_DIR  # the default: this process's kernel cache


def _stamp(package_parent: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(package_parent)}
    out = subprocess.run([sys.executable, "-c", STAMP], env=env, cwd=package_parent, capture_output=True,
                         text=True, check=True)
    return out.stdout.strip()


def test_another_clone_or_a_touched_kernel_file_is_another_stamp(tmp_path):
    source = Path(dea_ros.__file__).resolve().parent
    clones = []
    for name in ("clone_a", "clone_b"):
        shutil.copytree(source, tmp_path / name / "dea_ros", ignore=shutil.ignore_patterns("__pycache__"))
        clones.append(tmp_path / name)
    a, b = _stamp(clones[0]), _stamp(clones[1])
    assert a != b                                        # same sources, another directory
    assert _stamp(clones[0]) == a                        # stable
    kernel_file = clones[0] / "dea_ros" / KERNEL_SOURCES[0]
    stat = kernel_file.stat()
    os.utime(kernel_file, ns=(stat.st_atime_ns, stat.st_mtime_ns + 5_000_000_000))
    assert _stamp(clones[0]) != a                        # touched: numba recompiles it


def test_two_warmups_of_one_installation_compile_once(tmp_path, monkeypatch):
    """scripts/setup_env.sh starts a warm-up in the background and the demo (or the test command) starts
    another: the second waits for the first's lock and then finds its marker instead of compiling beside it
    (two compilations of the same kernels on two cores would each take twice as long)."""
    import threading
    import time

    from dea_ros.identify import warmup

    calls = []

    def slow_compile(cache_dir):
        calls.append(threading.current_thread().name)
        time.sleep(0.5)                                   # the first holds the lock while "compiling"
        marker_path(cache_dir).write_text("warm-up completed in 0.5 s\n")
        return 0.5

    monkeypatch.setattr(warmup, "_compile_and_mark", slow_compile)
    results = {}
    threads = [threading.Thread(target=lambda n=n: results.__setitem__(n, warmup.compile_kernels(tmp_path)),
                                name=f"warmup-{n}") for n in range(2)]
    for t in threads:
        t.start()
        time.sleep(0.05)
    for t in threads:
        t.join(timeout=10)
    assert len(calls) == 1                               # one compilation
    assert sorted(results.values()) == [0.0, 0.5]        # the other waited and found the kernels cached
    assert kernels_cached(tmp_path) and warmup.lock_path(tmp_path).is_file()


def test_a_running_warmup_is_seen_by_its_lock(tmp_path):
    """The demo says whether the set-up's warm-up is still compiling (its lock held) or it starts one."""
    import fcntl

    from dea_ros.identify.warmup import lock_path, warmup_running

    assert not warmup_running(tmp_path)                  # no lock file yet
    with open(lock_path(tmp_path), "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)                 # another warm-up compiling
        assert warmup_running(tmp_path)
    assert not warmup_running(tmp_path)                  # released (its process ended)
