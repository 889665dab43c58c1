"""The compiled kernels are cached on disk in a per-user directory, also from a read-only installation."""
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import dea_ros
from dea_ros.solvers import jit

SCRIPT = """
import sys, numpy as np
import dea_ros
from dea_ros.solvers import jit
from dea_ros.solvers.floquet_kernels import eigenvalues3
assert dea_ros.__file__.startswith(sys.argv[1]), dea_ros.__file__
eigenvalues3(np.eye(3)[None])
print(jit.CACHE_DIR)
print(sum(eigenvalues3.stats.cache_hits.values()))
"""


def _make_writable(path: Path) -> None:
    for root, dirs, files in os.walk(path):
        os.chmod(root, 0o755)
        for name in files:
            os.chmod(os.path.join(root, name), 0o644)


def test_kernels_of_a_read_only_install_are_cached_in_the_user_cache(tmp_path):
    install = tmp_path / "install"
    shutil.copytree(Path(dea_ros.__file__).parent, install / "dea_ros",
                    ignore=shutil.ignore_patterns("__pycache__"))
    for root, dirs, files in os.walk(install):
        for name in files + dirs:
            mode = os.stat(os.path.join(root, name)).st_mode
            os.chmod(os.path.join(root, name), mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    os.chmod(install, 0o555)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(HOME=str(tmp_path / "home"), XDG_CACHE_HOME=str(tmp_path / "cache"), PYTHONPATH=str(install))
    try:
        runs = [subprocess.run([sys.executable, "-c", SCRIPT, str(install)], env=env, cwd=tmp_path,
                               capture_output=True, text=True, timeout=900) for _ in range(2)]
    finally:
        _make_writable(install)
    for run in runs:
        assert run.returncode == 0, run.stderr[-2000:]
    cache_dir = Path(runs[0].stdout.split()[0])
    assert cache_dir == jit.cache_directory({"XDG_CACHE_HOME": str(tmp_path / "cache")})
    assert cache_dir.is_relative_to(tmp_path / "cache" / "dea_ros" / "numba")
    assert list(cache_dir.rglob("*.nbi")), "no numba index in the user cache"
    assert not list(install.rglob("*.nbi")), "numba wrote into the installation"
    assert int(runs[0].stdout.split()[1]) == 0 and int(runs[1].stdout.split()[1]) >= 1   # compiled, then loaded


def test_a_users_numba_cache_dir_is_respected(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    out = subprocess.run([sys.executable, "-c", "from dea_ros.solvers import jit; print(jit.CACHE_DIR)"], env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == str(tmp_path / "mine")


def test_every_module_with_kernels_is_part_of_the_cache_key():
    """jit.KERNEL_SOURCES: the sources whose hash names the cache directory (a kernel compiled into its
    callers from another module must invalidate their cache entries when it changes)."""
    root = Path(dea_ros.__file__).parent
    with_kernels = {path.relative_to(root).as_posix() for path in root.rglob("*.py")
                    if "from .jit import" in path.read_text() or path.name == "jit.py"}
    assert with_kernels <= set(jit.KERNEL_SOURCES)
    assert all((root / name).is_file() for name in jit.KERNEL_SOURCES)
