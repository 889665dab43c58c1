"""numba for the solvers' kernels: the compile decorators and the on-disk cache they use.

Every kernel of the solvers (``*_kernels.py``, :mod:`.realised`) is compiled by numba on first use
and cached on disk, so a process pays the compile time once per installation, not at every start.

Where the cache lives. numba's default is ``__pycache__`` beside each module, which a read-only
installation (a Debian package, a shared colcon install) does not allow. The kernels are cached in a
per-user directory instead, ``$XDG_CACHE_HOME/dea_ros/numba/<sources>`` (``~/.cache/...`` without
XDG_CACHE_HOME), the same from a source checkout, a colcon install or a read-only one. A user's own
``NUMBA_CACHE_DIR`` is respected (numba then caches there). The last part of the path,
``<sources>``, is a hash of the kernel modules' sources (:data:`KERNEL_SOURCES`): numba checks only
the source file of the function it loads, not those of the kernels it calls from other modules, so a
kernel changed in one file would otherwise leave stale machine code in its callers' cache entries.
The directory is set in ``numba.core.config`` (this process only; the environment is left alone)
before any kernel is decorated. When no cache location is writable, the kernels are compiled at
every start (slower start, same results). Measured on a 2-core AMD EPYC with numba 0.68 (issue 24):
compiling what a first solve with Floquet stability and a first sweep need takes ~54 s of CPU once; a
fresh process then imports the solvers, solves and sweeps in ~1.8 s.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba
from numba.core import config as numba_config

__all__ = ["jit", "jit_uncached", "jit_inline", "cache_directory", "cache_stamp", "KERNEL_SOURCES", "CACHE_DIR"]

#: The modules (relative to the dea_ros package) whose sources the cached kernels are compiled from.
KERNEL_SOURCES = (
    "model/dynamics.py",
    "solvers/jit.py",
    "solvers/collocation_kernels.py",
    "solvers/newton_kernels.py",
    "solvers/floquet_kernels.py",
    "solvers/arclength_kernels.py",
    "solvers/sweep_kernels.py",
    "solvers/integrate_kernels.py",
    "solvers/realised.py",
)


def _sources_key() -> str:
    """16 hex digits of the SHA-256 of the kernel modules' sources (missing files count as empty)."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256(numba.__version__.encode())
    for name in KERNEL_SOURCES:
        path = root / name
        digest.update(name.encode())
        digest.update(path.read_bytes() if path.is_file() else b"")
    return digest.hexdigest()[:16]


def cache_stamp() -> str:
    """16 hex digits naming what numba finds its cache entries by, beyond :func:`cache_directory`: the
    kernel modules' absolute directory and each file's modification time and size (numba.core.caching: a
    user-provided cache directory is divided by the source's directory, and an entry whose file's stamp
    differs is compiled anew). Another clone or install of the same sources, or a touched file, compiles
    the kernels again in the same cache directory: what was compiled for one stamp says nothing of another."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256(str(root).encode())
    for name in KERNEL_SOURCES:
        path = root / name
        stat = path.stat() if path.is_file() else None
        digest.update(f"{name}:{stat.st_mtime if stat else 0}:{stat.st_size if stat else 0};".encode())
    return digest.hexdigest()[:16]


def cache_directory(environ=None) -> Path:
    """The per-user kernel cache directory (module docstring) for the environment ``environ``
    (default: this process's)."""
    env = os.environ if environ is None else environ
    base = env.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "dea_ros" / "numba" / _sources_key()


#: Where the kernels are cached: the user's NUMBA_CACHE_DIR, else :func:`cache_directory`.
CACHE_DIR = os.environ.get("NUMBA_CACHE_DIR") or str(cache_directory())
if not os.environ.get("NUMBA_CACHE_DIR"):
    numba_config.CACHE_DIR = CACHE_DIR


def jit(fn):
    """``fn`` compiled by numba: no Python objects, cached on disk, IEEE arithmetic as written (no
    exceptions on division by zero). Without a writable cache location it is compiled at every start."""
    try:
        return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)
    except RuntimeError:  # no locator could create a cache directory: compile in each process
        return numba.njit(cache=False, nogil=True, error_model="numpy")(fn)


def jit_uncached(fn):
    """``fn`` compiled by numba as :func:`jit` does, but in each process, never cached: for kernels specialised
    on argument types that another process may not be able to import (numba's cache index pickles the
    types of every specialisation by reference, and one it cannot unpickle breaks every load of it)."""
    return numba.njit(cache=False, nogil=True, error_model="numpy")(fn)


def jit_inline(fn):
    """``fn`` compiled by numba and inlined into its compiled callers (numba IR level): for small helpers
    inside loops that must vectorise (LLVM leaves a call in a loop scalar): the 3x3 algebra of the Magnus
    loop of :func:`~dea_ros.solvers.floquet_kernels.monodromy`."""
    return numba.njit(inline="always", nogil=True, error_model="numpy")(fn)
