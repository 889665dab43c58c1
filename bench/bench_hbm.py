"""Benchmark of the paper's Table V: steady-state solves for membrane A2, 2.5 kV sine, 0.1-20 Hz.

Measured side by side in one run (these machines are shared and noisy: compare ratios):
* native HBM (cold start: its own linearised initial guess),
* mousai ``hb_time`` (the paper's solver; the same initial guess),
* forward integration to the periodic steady state (DOP853, rtol 1e-9, from the static
  equilibrium at u = 0; stop when the estimated distance to the periodic orbit, in scaled
  units, is below 1e-7 for two consecutive periods: see dea_ros.solvers.steady_state),
for N = 2, 4, 6, 8; the accuracy of eq. 25 against a converged integration (tol 1e-9),
near resonance and away from it; the number of harmonics native HBM needs for 0.1 %;
and the wall time of a 200-point sweep (0.1-20 Hz) with stability.

Run: python bench/bench_hbm.py [--quick]   (prints markdown; also written to bench/results/hbm.md)
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from machine_info import machine

from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers.continuation import frequency_sweep
from dea_ros.solvers.harmonic_balance import HarmonicBalanceError, solve_native
from dea_ros.solvers.inputs import SinePeriodic
from dea_ros.solvers.mousai_backend import solve_mousai
from dea_ros.solvers.steady_state import integrate_to_steady_state


def timed(fn, repeats=1):
    best = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best.append(time.perf_counter() - t0)
    return min(best), out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer frequencies (smoke run)")
    args = ap.parse_args()
    p = preset("A2")
    d0 = static_equilibrium(p, 0.0).displacement_m
    n_freq = 12 if args.quick else 40
    freqs = np.linspace(0.1, 20.0, n_freq)
    fi_freqs = freqs[:: max(1, n_freq // (4 if args.quick else 10))]
    harmonics = (2, 4, 6, 8)
    lines = [f"Machine: {machine()}", ""]

    # ---- timing, Table V
    times = {("native", n): [] for n in harmonics} | {("mousai", n): [] for n in harmonics}
    failures = {("native", n): 0 for n in harmonics} | {("mousai", n): 0 for n in harmonics}
    for n in harmonics:
        for f in freqs:
            inp = SinePeriodic(2500.0, float(f))
            for name, solver in (("native", solve_native), ("mousai", solve_mousai)):
                try:
                    t, _ = timed(lambda: solver(p, inp, n, stability=False), repeats=3 if name == "native" else 1)
                    times[(name, n)].append(t)
                except HarmonicBalanceError:
                    failures[(name, n)] += 1
    batch_times = {}
    from dea_ros.solvers.harmonic_balance import solve_native_batch

    for n in harmonics:
        inputs = [SinePeriodic(2500.0, float(f)) for f in freqs]
        reps = []
        for _ in range(3):
            t0 = time.perf_counter()
            solve_native_batch(p, inputs, n)
            reps.append((time.perf_counter() - t0) / len(inputs))
        batch_times[n] = min(reps)
    fi_times, fi_ref = [], {}
    for f in fi_freqs:
        t, sol = timed(lambda: integrate_to_steady_state(p, SinePeriodic(2500.0, float(f))))
        fi_times.append(t)
    fi_median = statistics.median(fi_times)
    lines += [
        f"### Table V: median wall time per steady-state solve (A2, 2.5 kV, {n_freq} frequencies 0.1-20 Hz)",
        "",
        "| N | native HBM [ms] | native batched [ms/solve] | mousai HBM [ms] | forward integration [s] | "
        "native vs mousai | batched vs mousai | native vs FI | batched vs FI | failures native / mousai |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for n in harmonics:
        tn = statistics.median(times[("native", n)]) if times[("native", n)] else float("nan")
        tm = statistics.median(times[("mousai", n)]) if times[("mousai", n)] else float("nan")
        tb = batch_times[n]
        lines.append(
            f"| {n} | {tn * 1e3:.3f} | {tb * 1e3:.3f} | {tm * 1e3:.2f} | {fi_median:.2f} | {tm / tn:.0f}x | "
            f"{tm / tb:.0f}x | {fi_median / tn:.0f}x | {fi_median / tb:.0f}x | "
            f"{failures[('native', n)]} / {failures[('mousai', n)]} |"
        )
    lines += ["", "Native: median of single cold solves (each computes its own linearised guess); batched: "
              f"all {n_freq} frequencies in one stacked Newton (solve_native_batch), wall time / {n_freq}.",
              f"Forward integration: median over {len(fi_freqs)} of the frequencies "
              f"({', '.join(f'{f:.2f}' for f in fi_freqs)} Hz).", ""]

    # ---- accuracy (eq. 25) against converged integration
    near = [9.0, 9.2, 9.4, 9.5, 9.75, 10.0]   # within 0.5 Hz of the 9.5 Hz peak, stable, unique
    away = [1.0, 3.0, 6.0, 12.0, 16.0]
    for f in near + away:
        fi_ref[f] = integrate_to_steady_state(p, SinePeriodic(2500.0, f), tol=1e-9, rtol=1e-11).displacement_rms(d0)
    lines += ["### Accuracy (eq. 25) against converged forward integration (tol 1e-9)", "",
              "| N | native near resonance (mean / max) | mousai near resonance (mean / max) | "
              "native away (max) | mousai away (max) |", "|---|---|---|---|---|"]

    def err(solver, n, fs):
        out = []
        for f in fs:
            try:
                s = solver(p, SinePeriodic(2500.0, f), n, stability=False)
                out.append(abs(s.displacement_rms(d0) - fi_ref[f]) / fi_ref[f] * 100)
            except HarmonicBalanceError:
                out.append(float("nan"))
        return np.array(out)

    for n in harmonics:
        en, em = err(solve_native, n, near), err(solve_mousai, n, near)
        an, am = err(solve_native, n, away), err(solve_mousai, n, away)
        lines.append(f"| {n} | {np.nanmean(en):.4f} % / {np.nanmax(en):.4f} % | {np.nanmean(em):.3f} % / "
                     f"{np.nanmax(em):.3f} % (failed {np.isnan(em).sum()}) | {np.nanmax(an):.5f} % | "
                     f"{np.nanmax(am):.4f} % |")
    needed = []
    for f in near + away:
        for n in range(1, 40):
            s = solve_native(p, SinePeriodic(2500.0, f), n, stability=False)
            if abs(s.displacement_rms(d0) - fi_ref[f]) / fi_ref[f] <= 1e-3:
                needed.append((f, n))
                break
    lines += ["", "Harmonics native HBM needs for <= 0.1 % error: " +
              ", ".join(f"{f:g} Hz: N={n}" for f, n in needed), ""]

    # ---- 200-point sweep with stability
    sweep_times = []
    for _ in range(3):
        t, r = timed(lambda: frequency_sweep(p, SinePeriodic(2500.0, 0.1), np.linspace(0.1, 20, 200), n_harmonics=8))
        sweep_times.append(t)
    lines += [f"### 200-point sweep 0.1-20 Hz, N = 8, with Floquet stability: median "
              f"{statistics.median(sweep_times):.3f} s over 3 runs ({r.branch_steps} branch steps, "
              f"{len(r.points)} points, {len(r.folds)} folds, resonance peak "
              f"{r.resonance_peak()['frequency_Hz']:.3f} Hz)", ""]
    text = "\n".join(lines)
    print(text)
    out = Path(__file__).with_name("results")
    out.mkdir(exist_ok=True)
    (out / "hbm.md").write_text(text + "\n")


if __name__ == "__main__":
    main()
