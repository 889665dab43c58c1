"""Issue 20: the position controller's per-sample cost under a randomized setpoint stream with the range ends.

A 10-minute (simulated time) stream of setpoints against the core's simulated rig
(:func:`dea_ros.control.run_closed_loop`: the mock rig's plant with its own "true" membrane,
config/rig/mock_membrane.yaml; the controller's model is A2): every 0.3-3 s a new setpoint, 30 %
at or just beyond the lower end (d(0 V), up to 1.5 um beyond), 30 % at or just beyond the upper
end (d(u_max)), 10 % far outside (refused at once), the rest uniform in the range. The setpoint
is delivered as position_controller_node delivers it (``request_setpoint`` in its own callback)
and every laser sample runs ``update`` (one planner check at most). Timed with perf_counter:

* the sample callback (``update`` + reading the plan's outcome), per sample: median, 99th, 99.9th
  percentile, max; wall time (perf_counter) and the thread's CPU time (thread_time, which leaves
  out the time the OS gave other processes: on a shared machine the wall maximum is the scheduler's);
* the setpoint callback (``request_setpoint``: clamp or refuse, no planning);
* side by side, in the same run: the full plan of the same setpoints done synchronously
  (``set_setpoint``, what the callback did before issue 20, with the bounded planner).

Prints a markdown block for docs/benchmarks.md. ``--minutes`` shortens the stream.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from machine_info import machine  # noqa: E402

from dea_ros.control import (  # noqa: E402
    ControllerConfig,
    PositionController,
    SimulatedRig,
    UnreachableReferenceError,
    run_closed_loop,
)
from dea_ros.model import config_dir, load_parameters, static_equilibrium  # noqa: E402

U_MAX = 0.9 * 100e6 * 35e-6       # A2: margin x breakdown field x thickness


def setpoint_stream(ctl: PositionController, minutes: float, seed: int):
    """[(time s, setpoint m)]: the randomized stream with both range ends and refusals."""
    rng = np.random.default_rng(seed)
    lo, hi = ctl.reachable_range_m
    t, out = 0.5, []
    while t < minutes * 60.0:
        r = rng.random()
        if r < 0.3:
            d = lo - rng.choice([0.0, rng.uniform(0.0, 1.5e-6), -0.5e-6])
        elif r < 0.6:
            d = hi + rng.choice([0.0, rng.uniform(0.0, 1.5e-6), -0.5e-6])
        elif r < 0.7:
            d = rng.choice([lo - rng.uniform(20e-6, 500e-6), hi + rng.uniform(20e-6, 500e-6)])
        else:
            d = rng.uniform(lo, hi)
        out.append((t, float(d)))
        t += rng.uniform(0.3, 3.0)
    return out


class TimedLoop:
    """The node's two callbacks on the simulated rig, each timed."""

    def __init__(self, ctl: PositionController, stream):
        self.ctl, self.stream = ctl, list(stream)
        self.k = 0
        self.sample_s, self.setpoint_s, self.sample_cpu_s, self.setpoint_cpu_s = [], [], [], []
        self.accepted = self.refused = self.planned = self.plan_refused = 0

    def __call__(self, t, m):
        ctl = self.ctl
        if not ctl.started:
            ctl.start(t, m)
        while self.k < len(self.stream) and self.stream[self.k][0] <= t:
            c0, t0 = time.thread_time(), time.perf_counter()
            try:
                ctl.request_setpoint(t, self.stream[self.k][1])
                self.accepted += 1
            except UnreachableReferenceError:
                self.refused += 1
            self.setpoint_s.append(time.perf_counter() - t0)
            self.setpoint_cpu_s.append(time.thread_time() - c0)
            self.k += 1
        c0, t0 = time.thread_time(), time.perf_counter()
        out = ctl.update(t, m)
        note = ctl.take_plan_note()
        self.sample_s.append(time.perf_counter() - t0)
        self.sample_cpu_s.append(time.thread_time() - c0)
        if note is not None:
            self.planned += note[0]
            self.plan_refused += not note[0]
        return out.voltage_V


def synchronous_plans(ctl: PositionController, stream) -> np.ndarray:
    """Seconds per setpoint of the full plan done at once (set_setpoint), from a held mid-range position."""
    lo, hi = ctl.reachable_range_m
    times = []
    for _, d in stream:
        ctl.start(0.0, 0.5 * (lo + hi))
        t0 = time.perf_counter()
        try:
            ctl.set_setpoint(0.0, d)
        except UnreachableReferenceError:
            pass
        times.append(time.perf_counter() - t0)
    return np.array(times)


def stats_ms(x) -> str:
    x = np.asarray(x) * 1e3
    return (f"median {np.median(x):.3f}, p99 {np.percentile(x, 99):.3f}, p99.9 {np.percentile(x, 99.9):.3f}, "
            f"max {x.max():.3f} ms (n = {x.size})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=20)
    args = ap.parse_args()
    model = load_parameters("A2")
    truth = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
    cfg = ControllerConfig(max_voltage_V=U_MAX, slew_rate_V_per_s=1e5)
    ctl = PositionController(model, cfg)
    stream = setpoint_stream(ctl, args.minutes, args.seed)
    rig = SimulatedRig(truth, U_MAX, seed=args.seed)
    lo, hi = ctl.reachable_range_m
    d0 = 0.5 * (lo + hi)
    u0 = float(np.sqrt(max(ctl.inverse.static_u2(d0), 0.0)))
    loop = TimedLoop(ctl, stream)
    wall = time.perf_counter()
    res = run_closed_loop(rig, loop, args.minutes * 60.0, initial_voltage_V=u0)
    wall = time.perf_counter() - wall
    c0 = time.thread_time()
    sync = synchronous_plans(PositionController(model, cfg), stream)
    sync_cpu = time.thread_time() - c0
    print(f"machine: {machine()}; load average {open('/proc/loadavg').read().split()[:3]}")
    print(f"stream: {args.minutes:g} min simulated, {len(stream)} setpoints (seed {args.seed}); wall {wall:.0f} s; "
          f"reachable {lo * 1e6:.1f}-{hi * 1e6:.1f} um, usable {ctl.usable_range_m[0] * 1e6:.1f}-"
          f"{ctl.usable_range_m[1] * 1e6:.1f} um; planner checks <= {ctl.plan_checks}")
    print(f"setpoints: {loop.accepted} answered at once (clamped or inside), {loop.refused} refused at once; "
          f"plans: {loop.planned} moves, {loop.plan_refused} refused after planning")
    print(f"sample callback (update), wall: {stats_ms(loop.sample_s)}")
    print(f"sample callback (update), CPU:  {stats_ms(loop.sample_cpu_s)} (thread time: without preemption)")
    print(f"setpoint callback (request), wall: {stats_ms(loop.setpoint_s)}")
    print(f"setpoint callback (request), CPU:  {stats_ms(loop.setpoint_cpu_s)}")
    print(f"synchronous plan (set_setpoint), wall: {stats_ms(sync)}; CPU in total {sync_cpu:.2f} s "
          f"({sync_cpu / len(stream) * 1e3:.2f} ms per setpoint)")
    true_d = res.true_m
    eq = static_equilibrium(truth, [0.0, U_MAX]).displacement_m
    print(f"plant: true displacement {true_d.min() * 1e6:.1f}-{true_d.max() * 1e6:.1f} um "
          f"(plant's own static range {eq[0] * 1e6:.1f}-{eq[1] * 1e6:.1f} um); commands "
          f"{np.nanmin(res.command_V):.0f}-{np.nanmax(res.command_V):.0f} V")


if __name__ == "__main__":
    main()
