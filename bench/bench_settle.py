"""Settle times from the slowest time constant (issue 21, session 13): what the planner's holds become.

Membranes: the mock rig's (config/rig/mock_membrane.yaml), the A2 preset, A2 with k1 halved and a creep
time eta1/k1 of 3 s ("slow") and of 30 s ("very slow", the slow end of the issue's family).

1. Per membrane: eta1/k1, the slowest time constant of the linearised model (dea_ros.model.settling) at
   0 V and 2500 V, and the holds of the planner (record_settle, 3 nm tolerance, 60 s cap) against the
   old rules (static: 3 s before the 1 s measurement; rest before a step: 5 eta1/k1 in [2, 60] s; sine: 8 s).
2. Static points checked by converged forward integration (simulate_held, rtol 1e-10 and 1e-11 agree):
   from rest at 0 V the level held; |mean over the 1 s measurement - static equilibrium (eq. 20)| after the
   planned hold and after the old one.
3. Sines (2500 V, 5 and 9 Hz) from rest: d_rms measured after the old 8 s settle and after the planned one
   against a settled reference (after 100 s).
4. The adaptive second pass of quick_adaptive (limits_for_protocol, 40 s budget): the first fit's Fisher
   information taken as that of quick_adaptive's first-pass records at the true parameters (the planner's own
   candidate_information, 1 um noise), planned with the new holds and with the old rules (the same limits with
   the tolerance at 1 m, so every hold is its floor, and the step rest floor at 5 eta1/k1); and the old plan's
   picks re-priced with the new holds (how long the same records take when each is settled).

Run: nice -n 10 python bench/bench_settle.py [--plan]
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench_coverage_family import truth  # noqa: E402
from machine_info import machine  # noqa: E402

from dea_ros.errors import PlanningError  # noqa: E402
from dea_ros.identify.adaptive import limits_for_protocol  # noqa: E402
from dea_ros.identify.planning import (CandidateRecord, FirstFit, PlanLimits, candidate_information,  # noqa: E402
                                       plan_experiments, record_settle)
from dea_ros.identify.protocols import load_protocol  # noqa: E402
from dea_ros.model import MembraneParameters, preset, slowest_time_constant_s, static_equilibrium  # noqa: E402
from dea_ros.solvers.inputs import SinePeriodic  # noqa: E402
from dea_ros.solvers.integrate import simulate_held  # noqa: E402
from dea_ros.solvers.sweep import frequency_sweep  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NAMES = ("sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa", "sigma_h'''(1)_Pa", "eps_r", "k1_Pa", "eta1_Pa_s",
         "eta2_Pa_s")


def membranes() -> list:
    a2 = preset("A2")
    k1 = 0.5 * a2.k1_Pa
    return [("mock", MembraneParameters.from_yaml(ROOT / "config/rig/mock_membrane.yaml")), ("A2", a2),
            ("slow", a2.replace(name="slow", k1_Pa=k1, eta1_Pa_s=3.0 * k1)),
            ("very slow", a2.replace(name="very_slow", k1_Pa=k1, eta1_Pa_s=30.0 * k1))]


def old_rest_s(p, min_s: float = 2.0) -> float:
    return float(min(max(5.0 * p.eta1_Pa_s / p.k1_Pa, min_s), max(60.0, min_s)))


def holds_table(rows: list) -> list:
    lines = ["| membrane | eta1/k1 s | tau 0 V s | tau 2500 V s | static holds 1250/1750/2250/2500 V s (old 3) "
             "| step rest s (old) | sine settle 2500 V s (old 8) |", "|---|---|---|---|---|---|---|"]
    lim = PlanLimits()
    for name, p in rows:
        st = [record_settle(p, lim, "static", voltage_V=u) for u in (1250.0, 1750.0, 2250.0, 2500.0)]
        rest = record_settle(p, lim, "rest")
        sine = record_settle(p, lim, "sine", amplitude_V=2500.0)
        cap = lambda s: f"{s.settle_s:.1f}" + (" (cap)" if s.capped else "")  # noqa: E731
        lines.append(f"| {name} | {p.eta1_Pa_s / p.k1_Pa:.2f} | {slowest_time_constant_s(p, 0.0):.2f} | "
                     f"{slowest_time_constant_s(p, 2500.0):.2f} | {' / '.join(cap(s) for s in st)} | "
                     f"{cap(rest)} ({old_rest_s(p):.1f}) | {cap(sine)} |")
    return lines


def static_check(rows: list, dt: float = 0.02) -> list:
    lines = ["| membrane | level V | planned hold s | mean - equilibrium, planned nm | after the old 3 s hold nm "
             "| rtol check nm |", "|---|---|---|---|---|---|"]
    lim = PlanLimits()
    for name, p in rows:
        x0 = np.asarray(static_equilibrium(p, 0.0).state, float).reshape(3)
        for u in (1250.0, 2500.0):
            hold = record_settle(p, lim, "static", voltage_V=u)
            n = int(math.ceil((hold.settle_s + lim.static_measure_s) / dt)) + 1
            runs = [simulate_held(p, np.full(n, u), dt, x0=x0, rtol=r, atol_scale=r) for r in (1e-10, 1e-11)]
            t, d = runs[1].time_s, runs[1].displacement_m
            d_eq = float(static_equilibrium(p, u).displacement_m)

            def off(t0):
                w = (t >= t0 - 1e-9) & (t <= t0 + lim.static_measure_s + 1e-9)
                return abs(float(np.mean(d[w])) - d_eq) * 1e9
            conv = float(np.max(np.abs(runs[0].displacement_m - d))) * 1e9
            lines.append(f"| {name} | {u:.0f} | {hold.settle_s:.1f}{' (cap)' if hold.capped else ''} | "
                         f"{off(hold.settle_s):.2g} | {off(3.0):.3g} | {conv:.1g} |")
    return lines


def sine_check(rows: list, freqs=(5.0, 9.0), amplitude_V: float = 2500.0, measure_s: float = 2.0,
               rate_Hz: float = 1000.0) -> list:
    """d_rms (eq. 21: RMS of d - d0 over whole periods, d0 the rest at 0 V) of a sine from rest, measured after
    the old 8 s settle and after the planned one, against the same after 100 s (settled): the error and
    the record's own standard uncertainty (1 um noise, 2000 samples and 1000 of the baseline: 39 nm)."""
    lines = ["| membrane | f Hz | tau of the orbit s | planned settle s | d_rms after 100 s um | error after 8 s nm "
             "| error after the planned settle nm |", "|---|---|---|---|---|---|---|"]
    lim = PlanLimits()
    for name, p in rows[:3]:
        d0 = float(static_equilibrium(p, 0.0).displacement_m)
        sweep = frequency_sweep(p, SinePeriodic(amplitude_V, 1.0), np.asarray(freqs, float), n_harmonics=8,
                                branch_switching=False, realised=False)
        for f in freqs:
            tau = max(pt.solution.slowest_time_constant_s for pt in sweep.points
                      if abs(pt.frequency_Hz - f) < 1e-6)
            settle = record_settle(p, lim, "sine", amplitude_V=amplitude_V, orbit_time_constant_s=tau)
            n = int(round(100.0 * rate_Hz)) + int(round(measure_s * rate_Hz)) + 1
            t = np.arange(n) / rate_Hz
            resp = simulate_held(p, amplitude_V * np.sin(2 * np.pi * f * t), 1.0 / rate_Hz)
            d = resp.displacement_m[:n]

            def rms(t0):
                k0 = int(round(math.ceil(t0 * f - 1e-9) / f * rate_Hz))
                k1 = k0 + int(round(math.ceil(measure_s * f - 1e-9) / f * rate_Hz))
                return math.sqrt(float(np.mean((d[k0:k1] - d0) ** 2)))
            ref = rms(100.0)
            lines.append(f"| {name} | {f:g} | {tau:.2f} | {settle.settle_s:.1f} | {ref * 1e6:.2f} | "
                         f"{(rms(8.0) - ref) * 1e9:+.3g} | {(rms(settle.settle_s) - ref) * 1e9:+.3g} |")
    return lines


def _first_fit(p, limits: PlanLimits) -> FirstFit:
    """The Fisher information of quick_adaptive's first pass at the true parameters (module docstring)."""
    values = np.array([truth(p, n) for n in NAMES])
    probe = FirstFit(p, NAMES, values, np.eye(len(NAMES)), 1.0, 1e-6, 1e-6 / math.sqrt(1000.0))
    m = p.mass_kg
    recs = [CandidateRecord("static", 4.0, m, voltage_V=u, measured_samples=1000) for u in (0.0, 2000, 2250, 2500)]
    recs.append(CandidateRecord("step", 14.5, m, final_V=2200.0))
    recs += [CandidateRecord("sine", 9.0, m, f, 2500.0, measured_samples=int(2000)) for f in (2, 8, 9, 9.5, 10, 12)]
    info, notes = candidate_information(probe, recs, limits)
    rel = sum(g for _c, g in info)
    scale = probe.scale()
    return dataclasses.replace(probe, information=rel / np.outer(scale, scale))


def plan_lengths(rows: list) -> list:
    base = load_protocol("quick_adaptive")
    lines = ["| membrane | plan | picks | total s | eta1 width after | picks (hold s) |", "|---|---|---|---|---|---|"]
    for name, p in rows:
        new = limits_for_protocol(base)
        old = dataclasses.replace(new, settle_tolerance_m=1.0,
                                  step_rest_min_s=old_rest_s(p, new.step_rest_min_s))
        first = _first_fit(p, new)
        plans = {}
        for label, lim in (("new holds", new), ("old rules", old)):
            t0 = time.perf_counter()
            try:
                plan = plan_experiments(first, base.adaptive_budget_s, lim)
            except PlanningError as exc:
                lines.append(f"| {name} | {label} | - | - | - | {exc} |")
                continue
            plans[label] = plan
            picks = "; ".join(f"{q.record.label()} ({q.record.settle_s:.1f})" for q in plan.picks)
            lines.append(f"| {name} | {label} | {len(plan.picks)} | {plan.total_s:.1f} | "
                         f"{plan.widths_after['eta1_Pa_s']:.3g} | {picks} ({time.perf_counter() - t0:.0f} s wall) |")
        if "old rules" in plans:
            repriced = 0.0
            for q in plans["old rules"].picks:
                r = q.record
                kind = {"step": "rest"}.get(r.kind, r.kind)
                s = record_settle(p, new, kind, voltage_V=r.voltage_V if r.kind == "static" else 0.0,
                                  amplitude_V=r.amplitude_V if r.kind == "sine" else 0.0, offset_V=r.offset_V)
                repriced += r.duration_s - r.settle_s + s.settle_s
            lines.append(f"| {name} | old picks, new holds | {len(plans['old rules'].picks)} | {repriced:.1f} | | "
                         f"(the old plan's records each settled) |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan", action="store_true", help="also plan quick_adaptive's second pass (minutes)")
    args = ap.parse_args()
    rows = membranes()
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.1f}")
    for line in holds_table(rows) + [""] + static_check(rows) + [""] + sine_check(rows):
        print(line)
    if args.plan:
        print()
        for line in plan_lengths(rows):
            print(line, flush=True)


if __name__ == "__main__":
    main()
