"""Lateness of the 1 kHz control updates while a retune is prepared (issue 23, session 10).

What runs: the position controller's control step exactly as position_controller_node's laser
callback runs it -- ``ctl.update(t, d)`` then the membrane health's ``BackgroundRetune.observe``
(tracker EKF, a due retune handed to the helper, a finished plan applied bumpless) -- paced by the wall
clock at 1 kHz in this process's main thread, with the retune prepared three ways, side by side:

* ``none``: tracking only, never a retune (the baseline: what the loop costs by itself);
* ``thread``: the plan (window fit + gain design) computed in a thread of this process, as the node did
  before this change;
* ``process``: the plan computed in the long-lived worker process (control/retune_worker.py), the node's
  default now.

Why this and not the node on the mock rig: the mock rig in simulated time runs in lockstep (the rig
waits for each command), so a late callback is invisible by construction; in wall time the node's
lateness adds the DDS transport and executor jitter, the same in all three modes, and needs two more
processes on a 2-core machine. What differs between the modes is who holds the GIL and the CPU beside
the callback, and that is measured here with the callback's own code. The simulated membrane (the
identified model with eps_r -6 %, so that retunes redesign the gains, not only fit) is stepped in the
same thread after each update (pure-Python RK4, ~0.1-0.2 ms per sample): it stands for the executor's
own Python work between callbacks, which holds the GIL too.

Lateness of a control update = end of the step (command ready) - the sample's due time (t0 + k ms).
A step that ends after the next due time skips the samples missed (the node's depth-1 QoS does the
same), counted. Each mode runs ``--seconds`` per repetition, the modes interleaved, after a warm-up
(the tracker's window filled, the worker started and warm); statistics over all updates and over the
updates while a retune is being prepared. ``--load N`` adds N busy processes (the machine load of the
run is printed, 1-min load average before and after each segment).

    python3 bench/bench_retune_jitter.py --reps 3 --seconds 10 [--load 3]
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from dea_ros.control import (
    AdaptiveModel,
    BackgroundRetune,
    ControllerConfig,
    ModelInverse,
    PositionController,
    prepare_plan,
)
from dea_ros.model import preset
from dea_ros.solvers.integrate import RealTimeStepper

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import machine  # noqa: E402

PERIOD_S = 1e-3
MODES = ("none", "thread", "process", "process nice 10")
NICE = {"process": 0, "process nice 10": 10}


def _burn() -> None:
    while True:
        pass


class Loop:
    """One closed loop (controller, tracker, retuning in one mode, simulated membrane), advanced in segments."""

    def __init__(self, mode: str, retune_period_s: float):
        kind = "off" if mode == "none" else mode.split()[0]
        ident = preset("A2")
        plant = ident.replace(relative_permittivity=ident.relative_permittivity * 0.94)
        cfg = ControllerConfig.for_membrane(ident, 0.9, slew_rate_V_per_s=1e5, sample_period_s=PERIOD_S)
        self.ctl = PositionController(ident, cfg)
        self.adaptive = AdaptiveModel(self.ctl, retune_period_s=retune_period_s)
        self.retune = BackgroundRetune(self.adaptive, kind, timeout_s=30.0, nice=NICE.get(mode, 0))
        lo, hi = self.ctl.reachable_range_m
        self.targets = [lo + f * (hi - lo) for f in (0.3, 0.6, 0.45, 0.75, 0.35, 0.65, 0.5)]
        u0 = ModelInverse(plant, cfg.max_voltage_V).static_voltage(self.targets[0])
        self.plant = RealTimeStepper(plant, dt_s=2.5e-4, initial_voltage_V=u0)
        self.u = u0
        self.k = 0                                  # simulated samples so far

    def callback(self, t: float, d: float) -> bool:
        """The node's control step; True when a retune was in flight at its start."""
        ctl = self.ctl
        busy = self.retune.busy
        if not ctl.started:
            ctl.start(t, d)
        if self.k % 700 == 0:
            ctl.set_setpoint(t, self.targets[(self.k // 700) % len(self.targets)])
        out = ctl.update(t, d)
        self.retune.observe(t, d, out)
        self.u = out.voltage_V
        return busy

    def advance(self, samples: int) -> None:
        for _ in range(4 * samples):
            self.plant.step(self.u, 2.5e-4)
        self.k += samples

    def run(self, seconds: float):
        """``seconds`` of wall-clock 1 kHz steps: (lateness s, in-flight flags, skipped samples)."""
        n = int(round(seconds / PERIOD_S))
        late = np.empty(n)
        busy = np.zeros(n, dtype=bool)
        skipped = 0
        clock, sleep = time.perf_counter, time.sleep
        t0 = clock()
        j = due_k = 0
        while j < n:
            due = t0 + due_k * PERIOD_S
            now = clock()
            if now < due:
                sleep(due - now)
            busy[j] = self.callback(self.k * PERIOD_S, self.plant.displacement_m)
            end = clock()
            late[j] = end - due
            j += 1
            missed = max(int((end - t0) / PERIOD_S) - due_k, 0)    # due times already passed: newest only
            skipped += missed
            due_k += 1 + missed
            self.advance(1 + min(missed, 50))
        return late, busy, skipped


def _stats(x) -> str:
    if len(x) == 0:
        return "-"
    p50, p99 = np.percentile(x, [50, 99]) * 1e3
    return f"{p50:.2f} / {p99:.2f} / {np.max(x) * 1e3:.1f}"


def transfer_line(lp: Loop) -> str:
    """What crossing the process boundary costs the node: the request built and pickled (the helper thread
    pickles it; the control thread builds it), the plan unpickled (helper thread)."""
    ad = lp.adaptive
    window = ad.tracker.window()
    t_req, t_pickle, t_plan = [], [], []
    plan = prepare_plan(ad.request(window), ad.tracker)
    for _ in range(20):
        t0 = time.perf_counter()
        req = ad.request(ad.tracker.window())
        t1 = time.perf_counter()
        blob = pickle.dumps(req, protocol=pickle.HIGHEST_PROTOCOL)
        t2 = time.perf_counter()
        pickle.loads(pickle.dumps(plan, protocol=pickle.HIGHEST_PROTOCOL))
        t3 = time.perf_counter()
        t_req.append(t1 - t0)
        t_pickle.append(t2 - t1)
        t_plan.append(t3 - t2)
    med = lambda xs: np.median(xs) * 1e3  # noqa: E731
    return (f"Crossing the process boundary (medians of 20): window copy + request {med(t_req):.2f} ms; "
            f"request pickled ({len(blob) / 1e3:.0f} kB) {med(t_pickle):.2f} ms; plan pickled + unpickled "
            f"({len(pickle.dumps(plan)) / 1e3:.1f} kB) {med(t_plan):.2f} ms.")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0, help="per mode and repetition")
    ap.add_argument("--retune-period", type=float, default=1.0, help="s between retunes (node: 2 s)")
    ap.add_argument("--load", type=int, default=0, help="busy processes added during the run")
    ap.add_argument("--warmup", type=float, default=6.0, help="s of each loop before the first measured segment")
    args = ap.parse_args(argv)
    ctx = multiprocessing.get_context("spawn")
    burners = [ctx.Process(target=_burn, daemon=True) for _ in range(args.load)]
    for b in burners:
        b.start()
    loops = {m: Loop(m, args.retune_period) for m in MODES}
    try:
        for m in MODES:
            loops[m].run(args.warmup)
        for lp in loops.values():          # a worker's first plan (imports, compilation) is not measured
            deadline = time.monotonic() + 120.0
            while lp.retune.worker is not None and lp.retune.applied == 0 and time.monotonic() < deadline:
                lp.run(1.0)
        rows, pooled = [], {m: ([], []) for m in MODES}
        for rep in range(args.reps):
            for m in MODES:
                lp = loops[m]
                before = (lp.retune.submitted, lp.retune.applied, lp.retune.failures)
                la0 = os.getloadavg()[0]
                late, busy, skipped = lp.run(args.seconds)
                la1 = os.getloadavg()[0]
                pooled[m][0].append(late)
                pooled[m][1].append(late[busy])
                r = lp.retune
                rows.append(f"| {rep + 1} | {m} | {_stats(late)} | {_stats(late[busy])} ({busy.sum()}) | {skipped} | "
                            f"{r.applied - before[1]} / {r.failures - before[2]} | {la0:.1f} -> {la1:.1f} |")
        transfer = transfer_line(loops["process"])
    finally:
        for lp in loops.values():
            lp.retune.close()
        for b in burners:
            b.terminate()
    print(f"Machine: {machine()}; {args.load} busy processes added; sys.getswitchinterval() "
          f"{sys.getswitchinterval() * 1e3:g} ms; retune every {args.retune_period:g} s; {args.seconds:g} s per mode "
          f"and repetition, {args.reps} repetitions interleaved.\n")
    print("Lateness of the control updates (end of the step - the sample's due time), p50 / p99 / max in ms:\n")
    print("| rep | retune | all updates | while a retune is prepared (updates) | skipped samples | "
          "plans applied / failed | load avg (1 min) |")
    print("|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    print("\nAll repetitions pooled:\n")
    print("| retune | all updates | while a retune is prepared |")
    print("|---|---|---|")
    for m in MODES:
        allx = np.concatenate(pooled[m][0])
        busyx = np.concatenate(pooled[m][1])
        print(f"| {m} | {_stats(allx)} | {_stats(busyx)} ({busyx.size} updates) |")
    print("\n" + transfer)


if __name__ == "__main__":
    main()
