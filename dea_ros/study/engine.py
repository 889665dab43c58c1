"""Where batches of independent work run: in this process, in local processes, or on Dask.

:class:`Engine` maps a picklable function over items (batches of designs, identification
inputs) and yields ``(key, result, error)`` as they complete:

* ``serial``: in this process (no extra dependency; the reference for the others);
* ``processes``: :class:`concurrent.futures.ProcessPoolExecutor` on the local cores (no extra
  dependency);
* ``dask``: a Dask ``distributed`` cluster: an embedded :class:`distributed.LocalCluster` with
  one single-threaded worker process per core (default), or an existing cluster given by its
  scheduler address (``tcp://host:8786``), unchanged.

``auto`` (the default) is ``dask`` on a local cluster when ``distributed`` is installed, else
``processes`` (``serial`` for one worker). Items are whole batches: one task per batch, never one
per solve, so the scheduling overhead (~1 ms per Dask task) is paid once per batch. Worker
processes get ``OMP_NUM_THREADS=1`` (and the BLAS equivalents): the solves are small, and one
thread per process is what scales.
"""
from __future__ import annotations

import os
import sys
import time
from ..blas_threads import ONE_BLAS_THREAD, use_one_blas_thread
from ..errors import EngineError

__all__ = ["Engine", "EngineError", "ENGINE_KINDS", "Progress", "dask_available"]

ENGINE_KINDS = ("auto", "serial", "processes", "dask")
_NO_WORKER_PROFILER = {"distributed.worker.profile.enabled": False, "distributed.worker.profile.interval": "1s",
                       "distributed.worker.profile.cycle": "10s"}


def dask_available() -> bool:
    """True when ``dask.distributed`` can be imported."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True


def _need_dask(why: str):
    if not dask_available():
        raise EngineError(f"{why} needs Dask: pip install 'dask[distributed]' (or the extra: pip install "
                          "'dea_ros[dask]'; apt: python3-dask python3-distributed); without it run locally "
                          "with --engine processes or --engine serial")


def _init_worker():
    use_one_blas_thread()


class Engine:
    """A context manager running batches of work (module docstring)."""

    def __init__(self, kind: str = "auto", workers: int | None = None, scheduler: str | None = None):
        if kind not in ENGINE_KINDS:
            raise EngineError(f"engine: one of {ENGINE_KINDS}, got {kind!r}")
        if workers is not None and (not isinstance(workers, int) or workers < 1):
            raise EngineError(f"workers: a positive integer is needed, got {workers!r}")
        if scheduler:
            if kind not in ("auto", "dask"):
                raise EngineError(f"--scheduler runs on Dask; it cannot be combined with engine {kind}")
            _need_dask("--scheduler")
            kind = "dask"
        cores = os.cpu_count() or 1
        self.workers = workers or cores
        if kind == "auto":
            if self.workers == 1:
                kind = "serial"
            else:
                kind = "dask" if dask_available() else "processes"
        if kind == "dask":
            _need_dask("engine dask")
        self.kind = kind
        self.scheduler = scheduler
        self._pool = None
        self._client = None
        self._cluster = None
        self._opened = False

    # ------------------------------------------------------------------ lifetime
    def __enter__(self) -> "Engine":
        return self.open()

    def open(self) -> "Engine":
        """Start the pool or the cluster connection (once; a second call does nothing)."""
        if self._opened:
            return self
        self._opened = True
        if self.kind == "processes":
            from concurrent.futures import ProcessPoolExecutor

            use_one_blas_thread()   # inherited by the workers at their start
            self._pool = ProcessPoolExecutor(max_workers=self.workers, initializer=_init_worker)
        elif self.kind == "dask":
            from distributed import Client, LocalCluster

            if self.scheduler:
                try:
                    self._client = Client(self.scheduler, timeout="20s")
                except (OSError, TimeoutError) as exc:
                    raise EngineError(f"--scheduler {self.scheduler}: cannot connect ({exc}); is the scheduler "
                                      "running (dask scheduler) and reachable?") from None
            else:
                import dask

                # Dask's statistical profiler samples every worker's stack each 10 ms: ~25 % of the
                # time of this Python-heavy work (measured, bench/bench_study.py). The local workers
                # start without it (older distributed versions, without the switch: sampled each 1 s).
                with dask.config.set(_NO_WORKER_PROFILER):
                    self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                                 dashboard_address=None, env=dict(ONE_BLAS_THREAD))
                self._client = Client(self._cluster)
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._opened = False
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    def describe(self) -> str:
        if self.kind == "dask":
            where = self.scheduler or "local cluster"
            n = self.worker_count()
            return f"dask ({where}, {n} worker{'s' if n != 1 else ''})"
        if self.kind == "processes":
            return f"processes ({self.workers} local)"
        return "serial (this process)"

    def worker_count(self) -> int:
        if self.kind == "dask" and self._client is not None:
            try:
                return len(self._client.scheduler_info().get("workers", {}))
            except Exception:  # noqa: BLE001 - informational only
                return self.workers
        return self.workers if self.kind != "serial" else 1

    # ------------------------------------------------------------------ work
    def map_unordered(self, fn, items):
        """Yield ``(key, result, error)`` for ``items`` = [(key, argument), ...] as they complete
        (``error`` is None or the exception the call raised)."""
        items = list(items)
        if self.kind == "serial":
            for key, arg in items:
                try:
                    yield key, fn(arg), None
                except (KeyboardInterrupt, SystemExit):
                    raise
                except Exception as exc:  # noqa: BLE001 - reported to the caller per item
                    yield key, None, exc
            return
        if self.kind == "processes":
            from concurrent.futures import as_completed

            futures = {self._pool.submit(fn, arg): key for key, arg in items}
            try:
                for fut in as_completed(futures):
                    exc = fut.exception()
                    yield futures[fut], (None if exc else fut.result()), exc
            finally:
                for fut in futures:
                    fut.cancel()
            return
        from distributed import as_completed as dask_completed

        futures = {}
        for key, arg in items:
            futures[self._client.submit(fn, arg, pure=False)] = key
        try:
            for fut in dask_completed(list(futures)):
                try:
                    result, exc = fut.result(), None
                except (KeyboardInterrupt, SystemExit):
                    raise
                except Exception as err:  # noqa: BLE001 - reported to the caller per item
                    result, exc = None, err
                yield futures[fut], result, exc
                fut.release()
        finally:
            for fut in futures:
                fut.cancel()


class Progress:
    """A progress bar: tqdm when installed, else one plain line per update at most every 2 s."""

    def __init__(self, total: int, what: str = "chunks", enabled: bool = True, stream=None, initial: int = 0):
        self.total, self.what, self.enabled = int(total), what, enabled
        self.stream = stream or sys.stderr
        self.done = int(initial)
        self.t0 = time.perf_counter()
        self._last = 0.0
        self._start_done = self.done
        self._bar = None
        if enabled:
            try:
                from tqdm import tqdm

                self._bar = tqdm(total=self.total, initial=self.done, unit=what[:-1] if what.endswith("s") else what,
                                 file=self.stream, dynamic_ncols=True)
            except ImportError:
                self._bar = None

    def update(self, n: int = 1, note: str = "") -> None:
        self.done += n
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(n)
            if note:
                self._bar.set_postfix_str(note)
            return
        now = time.perf_counter()
        if now - self._last < 2.0 and self.done < self.total:
            return
        self._last = now
        elapsed = now - self.t0
        rate = (self.done - self._start_done) / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        pct = 100.0 * self.done / max(self.total, 1)
        eta_text = f", ETA {eta:.0f} s" if eta == eta else ""
        print(f"[{self.done}/{self.total} {self.what}, {pct:.0f} %] {elapsed:.0f} s{eta_text}"
              + (f" {note}" if note else ""), file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
