"""Benchmark of the frequency sweep with bands (issue 10): speed, band edges, realised responses.

* Speed: the whole 0.1-20 Hz sweep of A2 at 2.5 kV (200 frequencies, N = 8) with stability at every
  branch step, located bifurcations, the period-doubled branch and the realised (quasi-periodic)
  responses: wall time (median of 3 runs) and CPU time of this process. OpenBLAS is limited to one
  thread (set below, before numpy loads): the systems are small (51-99 unknowns) and on a shared
  2-core machine multithreaded BLAS spends more time contending than computing.
* Bands of LP1, A1, A2 (edges and the bifurcations bounding them) and, in every band that is not
  plainly periodic, the realised d_rms against converged forward integration:
  - period-doubled / coexisting: the periodic orbit by shooting on DOP853 (rtol 1e-10, independent
    of harmonic balance except for its start) at every requested frequency in the band, and
    brute-force integration from rest to steady state (DOP853, tol 1e-9) in the middle of the
    period-doubling band;
  - quasi-periodic: the window mean (100 periods settled, 200 measured, RK4 at 64 steps/period)
    against adaptive integration (DOP853, rtol 1e-9) over 100 + 600 periods from the same start:
    the statistical spread of a window mean, stated.

Run: python bench/bench_sweep.py [--quick]   (markdown to stdout and bench/results/sweep.md)
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from machine_info import machine  # noqa: E402

from dea_ros.model import preset, static_equilibrium  # noqa: E402
from dea_ros.solvers.sweep import frequency_sweep  # noqa: E402
from dea_ros.solvers.inputs import SinePeriodic, SineVoltage  # noqa: E402
from dea_ros.solvers.integrate import simulate  # noqa: E402
from dea_ros.solvers.steady_state import (  # noqa: E402
    SteadyStateError,
    integrate_to_steady_state,
    shoot_periodic_orbit,
)

GRID = np.linspace(0.1, 20.0, 200)


def speed(repeats: int) -> tuple[list, float, object]:
    p = preset("A2")
    inp = SinePeriodic(2500.0, 1.0)
    walls, cpus = [], []
    res = None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        res = frequency_sweep(p, inp, GRID, n_harmonics=8)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return walls, statistics.median(cpus), res


def band_rows(name: str, quick: bool) -> list[str]:
    p = preset(name)
    d0 = float(static_equilibrium(p, 0.0).displacement_m)
    res = frequency_sweep(p, SinePeriodic(2500.0, 1.0), GRID, n_harmonics=8)
    rows = []
    for b in res.bands:
        inside = [r for r in res.responses if b.f_start_Hz <= r.frequency_Hz <= b.f_end_Hz]
        if b.kind == "periodic":
            rows.append(f"| {name} | {b.f_start_Hz:.4f}-{b.f_end_Hz:.4f} | {b.kind} ({', '.join(b.branches)}) | "
                        f"{b.start_edge} .. {b.end_edge} | {len(inside)} frequencies | (issue 2: <= 0.006 %) |")
            continue
        cells = []
        worst = 0.0
        for r in inside:
            if r.branch == "integration":
                start = [pt for br in res.branches for pt in br.points
                         if abs(pt.frequency_Hz - r.frequency_Hz) < 1e-9][0].solution.evaluate(0.0)[:, 0]
                start = start + np.array([1e-3 * abs(start[0]), 0.0, 0.0])
                f = r.frequency_Hz
                n_set, n_win = (100, 200) if quick else (100, 600)
                t = n_set / f + np.arange(n_win * 64) / (64 * f)
                sim = simulate(p, SineVoltage(2500.0, f), t[-1] + 1.0 / (64 * f), t_eval=t, x0=start,
                               rtol=1e-9, atol_scale=1e-9).displacement_m
                ref = float(np.sqrt(np.mean((sim - d0) ** 2)))
                err = 100 * (r.d_rms_m / ref - 1)
                cells.append(f"{f:g} Hz: {r.d_rms_m * 1e6:.1f} um "
                             f"[{r.d_rms_min_m * 1e6:.0f}-{r.d_rms_max_m * 1e6:.0f}] "
                             f"vs DOP853 {n_win} periods {ref * 1e6:.1f} um ({err:+.1f} %)")
                continue
            pts = [pt for br in res.branches for pt in br.points
                   if br.name == r.branch and abs(pt.frequency_Hz - r.frequency_Hz) < 1e-9]
            pt = min(pts, key=lambda q: abs(q.d_rms_m - r.d_rms_m))
            ref = shoot_periodic_orbit(p, pt.solution.periodic_input, pt.solution.evaluate(0.0)[:, 0])
            err = 100 * abs(r.d_rms_m / ref.displacement_rms(d0) - 1)
            worst = max(worst, err)
            cells.append(f"{r.frequency_Hz:g}: {r.d_rms_m * 1e6:.1f}")
        extra = ""
        if b.kind == "period-doubled" and inside:
            mid = inside[len(inside) // 2]
            try:
                fi = integrate_to_steady_state(p, SinePeriodic(2500.0, mid.frequency_Hz), tol=1e-8,
                                               max_time_s=3000.0)
                e = 100 * abs(mid.d_rms_m / fi.displacement_rms(d0) - 1)
                extra = (f"; from rest at {mid.frequency_Hz:g} Hz: {fi.displacement_rms(d0) * 1e6:.2f} um "
                         f"({e:.2g} %, {fi.iterations} periods)")
            except SteadyStateError as exc:
                extra = f"; from rest at {mid.frequency_Hz:g} Hz: not converged ({exc})"
        rows.append(f"| {name} | {b.f_start_Hz:.4f}-{b.f_end_Hz:.4f} | {b.kind} ({', '.join(b.branches)}) | "
                    f"{b.start_edge} .. {b.end_edge} | " + "; ".join(cells) + " um | "
                    + (f"max {worst:.2g} % vs shooting" if worst else "window mean, see text") + extra + " |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="1 speed run, shorter reference windows")
    args = ap.parse_args()
    out = [f"Machine: {machine()}; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}", ""]
    walls, cpu, res = speed(1 if args.quick else 3)
    t = res.timings_s
    out.append(f"### Whole sweep of A2, 0.1-20 Hz, 200 frequencies, N = 8, with bands: median wall "
               f"{statistics.median(walls):.2f} s over {len(walls)} runs (each: "
               + ", ".join(f"{w:.2f}" for w in walls) + f" s), CPU {cpu:.2f} s")
    out.append("")
    out.append("Split of the last run: " + ", ".join(f"{k} {v:.2f} s" for k, v in t.items())
               + f"; {res.branch_steps} branch steps, {len(res.bifurcations)} bifurcations.")
    out.append("")
    out.append("### Bands at 2.5 kV (edges located on the branches) and the realised response against integration")
    out.append("")
    out.append("| Membrane | band [Hz] | kind (stable branches) | bounded by | realised d_rms | error vs integration |")
    out.append("|---|---|---|---|---|---|")
    for name in ("LP1", "A1", "A2"):
        out += band_rows(name, args.quick)
        print(out[-1], flush=True)
    out.append("")
    text = "\n".join(out)
    print(text)
    Path(__file__).with_name("results").mkdir(exist_ok=True)
    (Path(__file__).with_name("results") / "sweep.md").write_text(text + "\n")


if __name__ == "__main__":
    main()
