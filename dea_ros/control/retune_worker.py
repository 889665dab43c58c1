"""The retune off the control loop: a long-lived worker process for :func:`.adaptive.prepare_plan`.

Why a process: the window fit and the gain design (~0.1-0.3 s of numpy/scipy, much of it Python
that holds the GIL) run beside the 1 kHz control callback. In a thread of the node's process they
take the GIL from the callback for up to ``sys.getswitchinterval()`` at a time: at machine load ~5
the callback's p99 lateness went from 3.4 ms to 11.4 ms while a fit ran (bench/bench_retune_jitter.py,
docs/benchmarks.md, issue 23). In a process they share only the CPU.

* :class:`RetuneWorker`: one process (``spawn``: safe beside the node's threads; started once, at
  configure, never per retune) that receives :class:`~.adaptive.RetuneRequest` (plain data: the
  window's arrays, the estimate, parameters and settings) and answers the :class:`~.adaptive.RetunePlan`.
  The first request after a start may take up to ``start_timeout_s`` (imports, compilation), every
  later one ``timeout_s``. It dies with its owner: it exits at the end of its pipe (the owner closed it, exited or was
  killed) and, as a daemon, at the owner's normal exit. A worker that died, failed or did not answer
  within ``timeout_s`` is replaced and the call raises :class:`~dea_ros.errors.RetuneWorkerError`.
* :class:`BackgroundRetune`: the scheduling the control callback runs per sample (no ROS): observe,
  hand a due retune to a helper thread (which waits on the worker, or runs the plan itself in
  ``"thread"`` mode), apply a finished plan on the control thread (bumpless,
  :func:`~.adaptive.apply_retune`). The callback never waits: it only asks whether the job is done; a
  failed or late job is "no retune this time", counted with its reason.
"""
from __future__ import annotations

import functools
import multiprocessing
import os
import signal
import threading
from concurrent.futures import Future, ThreadPoolExecutor

from ..errors import RetuneWorkerError
from .adaptive import DriftTracking, RetunePlan, RetuneRequest, prepare_plan

__all__ = ["RetuneWorker", "BackgroundRetune", "RETUNE_MODES", "serve"]

#: where :class:`BackgroundRetune` prepares a retune: a worker process, a thread of this process, or not at all
RETUNE_MODES = ("process", "thread", "off")


def serve(conn, nice: int = 0) -> None:
    """The worker process's loop: a request in, ``("ok", plan)`` or ``("error", text)`` out; ends with the pipe.

    ``nice``: added to the process's niceness first (the control loop gets the CPU first when it is contended).
    SIGINT is ignored (a Ctrl-C in the terminal reaches the whole process group): the owner ends the worker.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if nice > 0:
        os.nice(int(nice))
    conn.send(("ready", os.getpid()))
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return                       # the owner closed the pipe, exited or was killed
        try:
            answer = ("ok", prepare_plan(request))
        except Exception as exc:         # noqa: BLE001 -- any failure of the plan is reported, the worker lives on
            answer = ("error", f"{type(exc).__name__}: {exc}")
        try:
            conn.send(answer)
        except (OSError, ValueError):
            return


class RetuneWorker:
    """One long-lived process that runs :func:`~.adaptive.prepare_plan` (see the module's docstring).

    :meth:`prepare` blocks (call it from a helper thread, never from the control loop).
    """

    def __init__(self, timeout_s: float = 10.0, start_timeout_s: float = 120.0, method: str = "spawn", nice: int = 0):
        if not timeout_s > 0.0 or not start_timeout_s > 0.0:
            raise ValueError(f"timeout_s, start_timeout_s: must be > 0 s, got {timeout_s!r}, {start_timeout_s!r}")
        self.context = multiprocessing.get_context(method)
        self.timeout_s = float(timeout_s)
        self.start_timeout_s = float(start_timeout_s)
        self.nice = int(nice)
        self.process = None
        self.conn = None
        self.ready = False
        self.warm = False                # answered once since its start (the first plan compiles, imports)
        self.starts = 0
        self.closed = False
        self.lock = threading.Lock()

    @property
    def pid(self) -> int | None:
        return None if self.process is None else self.process.pid

    def start(self) -> None:
        """Start the process (returns at once; the child imports the core meanwhile)."""
        parent, child = self.context.Pipe(duplex=True)
        proc = self.context.Process(target=serve, args=(child, self.nice), name="dea_retune_worker", daemon=True)
        proc.start()
        child.close()                    # the child's end lives in the child only: its exit is our EOF
        self.process, self.conn, self.ready, self.warm = proc, parent, False, False
        self.starts += 1

    def prepare(self, request: RetuneRequest) -> RetunePlan:
        """The plan of ``request`` from the worker (blocking; RetuneWorkerError: no plan, worker replaced)."""
        with self.lock:
            if self.closed:
                raise RetuneWorkerError("the retune worker is closed")
            if self.process is None or not self.process.is_alive():
                self._replace()               # died while idle: a new one serves this request
            conn, proc = self.conn, self.process
            if conn is None:
                raise RetuneWorkerError("the retune worker is closed")
            try:
                if not self.ready:
                    if not conn.poll(self.start_timeout_s):
                        self._fail(f"the worker did not start within {self.start_timeout_s:g} s")
                    conn.recv()
                    self.ready = True
                conn.send(request)
                timeout = self.timeout_s if self.warm else max(self.timeout_s, self.start_timeout_s)
                if not conn.poll(timeout):
                    self._fail(f"no answer within {timeout:g} s (retune_timeout_s; worker replaced)")
                status, value = conn.recv()
                self.warm = True
            except (EOFError, OSError, TypeError) as exc:
                if self.closed:                      # close() from another thread took the pipe away
                    raise RetuneWorkerError("the retune worker was closed during the request") from None
                if isinstance(exc, TypeError):       # not a pipe's end: e.g. an unpicklable request
                    raise
                proc.join(1.0)
                self._fail(f"the worker died (exit code {proc.exitcode}; {type(exc).__name__})")
        if status != "ok":
            raise RetuneWorkerError(f"the plan failed in the worker: {value}")
        return value

    def _fail(self, text: str) -> None:
        self._replace()
        raise RetuneWorkerError(text)

    def _replace(self) -> None:
        self._stop()
        if not self.closed:
            self.start()

    def _stop(self) -> None:
        proc, conn = self.process, self.conn
        self.process = self.conn = None
        if conn is not None:
            conn.close()
        if proc is not None:
            if proc.is_alive():
                proc.terminate()
                proc.join(1.0)
            if proc.is_alive():
                proc.kill()
            proc.join(1.0)

    def close(self) -> None:
        """End the process (a helper thread waiting on it gets RetuneWorkerError)."""
        self.closed = True
        self._stop()


class BackgroundRetune:
    """Tracking and retuning of an :class:`~.adaptive.AdaptiveModel` (or the window fit of a
    :class:`~.adaptive.DriftTracking`: model_node) with the slow part off the control loop.

    Per sample, after ``ctl.update``: :meth:`observe`. ``mode``: :data:`RETUNE_MODES` ("process": the
    worker process, started here; "thread": the plan computed by the helper thread in this process, as
    before issue 23; "off": tracking only, never a retune). Counters: ``submitted``, ``applied``,
    ``failures`` (each with ``last_failure``).
    """

    def __init__(self, adaptive: DriftTracking, mode: str = "process", timeout_s: float = 10.0,
                 start_timeout_s: float = 120.0, nice: int = 0):
        if mode not in RETUNE_MODES:
            raise ValueError(f"retune mode: one of {RETUNE_MODES}, got {mode!r}")
        self.adaptive = adaptive
        self.mode = mode if adaptive.enabled else "off"
        self.worker = None
        self.job = None
        if self.mode == "process":
            self.worker = RetuneWorker(timeout_s, start_timeout_s, nice=nice)
            self.worker.start()
            self.job = self.worker.prepare
        elif self.mode == "thread":
            self.job = functools.partial(prepare_plan, tracker=adaptive.tracker)
        self.helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="dea_retune") if self.job else None
        self.pending: Future | None = None
        self.submitted = self.applied = self.failures = 0
        self.last_failure = ""

    @property
    def busy(self) -> bool:
        """A retune is being prepared."""
        return self.pending is not None and not self.pending.done()

    def observe(self, t_s: float, measured_m: float, out) -> None:
        """One control step: track; apply a finished plan, or hand a due retune to the helper (never waits).

        ``out``: the sample's input as ``adaptive.observe`` takes it (AdaptiveModel: the controller's
        ControlOutput; DriftTracking: the applied voltage, V)."""
        adaptive = self.adaptive
        adaptive.observe(t_s, measured_m, out)
        if self.helper is None:
            return
        if self.pending is not None:
            if self.pending.done():
                self._finish(t_s)
            return
        window = adaptive.due(t_s)
        if window is not None:
            self.pending = self.helper.submit(self.job, adaptive.request(window))
            self.submitted += 1

    def _finish(self, t_s: float) -> None:
        job, self.pending = self.pending, None
        exc = job.exception()
        if exc is not None:                  # no retune this time (a replaced worker serves the next one)
            self.failures += 1
            self.last_failure = f"{type(exc).__name__}: {exc}"
            return
        self.adaptive.apply(job.result(), t_s)
        self.applied += 1

    def describe(self) -> str:
        if self.worker is not None:
            return f"process (pid {self.worker.pid}, started {self.worker.starts} time(s))"
        return self.mode

    def close(self) -> None:
        if self.worker is not None:
            self.worker.close()
        if self.helper is not None:
            self.helper.shutdown(wait=False, cancel_futures=True)   # a fit under way is not waited for here
