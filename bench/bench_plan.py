"""One pass against two (issue 21, item 3): does the Fisher-information planner's second pass pay?

Membranes of the coverage family (bench_coverage_family.family: unlike the presets), data from
converged forward integration (dea_ros.identify.synth.synthesize_experiments: static points, a step
by adaptive DOP853 from rest, sine records from the converged periodic orbit at a random start
phase), 1 um laser noise and the ILD1320 quantisation; never from the harmonic balance the fit uses.

* one pass: static points, one 2.2 kV step, the 17-frequency set placed around each membrane's own
  resonance (bench_coverage_family.seventeen), identified at once;
* two passes: the same static points and step with the paper's 4 frequencies, identified; the planner
  (dea_ros.identify.planning.plan_experiments, default criterion and targets) then picks sines
  (frequency x 1500/2000/2500 V, no offset: the synthetic generator makes no offset records) and
  steps (0 -> 1500/2000/2500 V, each after the rest step_rest_s gives: five creep times until session 13, now the
  slowest time constant x ln(transient / 3 nm), dea_ros.model.settling) within a budget equal to the
  experiment time of the 13 sine records the one-pass protocol has beyond the 4 (each sine record
  costs 8 s of settling + 2 s measured, whole periods; a step 0.2 s + 4 s + its rest); their data
  are synthesised the same way (another noise seed) and everything is identified again.

Per parameter (eps_r, k1, eta1, eta2, sigma_h''(1)): relative error, relative 95 % half-width,
whether the interval covers the truth; the eta1/eta2 correlation; sigma_h''(1) identified within
10 %; the experiment time of both protocols.

Run: python bench/bench_plan.py [--membranes 3] [--seeds 2] [--jsonl bench/results/plan.jsonl]
(appends one JSON line per run; --table-only tabulates).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench_coverage_family import PAPER_HZ, family, seventeen, truth  # noqa: E402
from machine_info import machine  # noqa: E402

from dea_ros.identify.pipeline import identify  # noqa: E402
from dea_ros.identify.planning import (PlanLimits, first_fit_from_result, plan_experiments,  # noqa: E402
                                       sine_record_cost, step_rest_s)
from dea_ros.identify.synth import synthesize_experiments  # noqa: E402
from dea_ros.sim.plant import LASER_QUANTISATION_M  # noqa: E402

NAMES = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "sigma_h''(1)_Pa")
LIMITS = PlanLimits(measure_s=2.0, settle_s=8.0, step_pre_s=0.2, step_hold_s=4.0, offsets=False,
                    static_fractions=(), step_fractions=(0.6, 0.8, 1.0))


def _synth(p, seed: int, freqs, **kw):
    return synthesize_experiments(p, 1e-6, seed=seed, sine_frequencies_Hz=freqs, series_frequencies_Hz=(),
                                  quantisation_m=LASER_QUANTISATION_M, random_start_phase=True, **kw)


def _summary(p, res, exp_time_s: float) -> dict:
    st = res.statistics
    out = {"experiment_s": exp_time_s, "curvature_status": res.curvature_status, "params": {}}
    for n in NAMES:
        if n not in st.names:
            continue
        i = st.names.index(n)
        tv = truth(p, n)
        out["params"][n] = {"rel_err": float(st.values[i] / tv - 1),
                            "rel_width": float((st.ci_high[i] - st.ci_low[i]) / 2 / abs(st.values[i])),
                            "covers": bool(st.ci_low[i] <= tv <= st.ci_high[i])}
    if "eta1_Pa_s" in st.names and "eta2_Pa_s" in st.names:
        out["corr_eta1_eta2"] = float(st.correlation[st.names.index("eta1_Pa_s"), st.names.index("eta2_Pa_s")])
    return out


def _planned_data(p, plan, seed: int) -> tuple:
    """(sines, steps) of the planned records, synthesised like the first pass (noise seed + 1000)."""
    sines, steps = [], []
    shapes: dict = {}
    for pick in plan.picks:
        r = pick.record
        if r.kind == "sine":
            shapes.setdefault(r.amplitude_V, []).append(r.frequency_Hz)
        elif r.kind == "step":
            st = _synth(p, seed + 1000 + len(steps), (), step_voltage_V=r.final_V, step_time_s=LIMITS.step_pre_s,
                        step_duration_s=LIMITS.step_hold_s).steps[0]
            steps.append(dataclasses.replace(st, source=f"planned step {r.final_V:.0f} V"))
    for amp, freqs in shapes.items():
        s = _synth(p, seed + 2000 + int(amp), tuple(sorted(freqs)), sine_amplitude_V=amp).sines[0]
        sines.append(dataclasses.replace(s, source=f"planned sines {amp:.0f} V"))
    return sines, steps


def one_run(p, f_r: float, seed: int) -> dict:
    base_s = LIMITS.step_pre_s + LIMITS.step_hold_s       # static points and the step: the same in both
    full = seventeen(f_r)
    extra = [f for f in full if f not in PAPER_HZ]
    sine_s = {f: sine_record_cost(LIMITS, f)[0] for f in full}
    t0 = time.perf_counter()
    one = identify(_synth(p, seed, full), evaluate_fit=False)
    t1 = time.perf_counter()
    first_exp = _synth(p, seed, PAPER_HZ)
    first = identify(first_exp, evaluate_fit=False)
    budget = sum(sine_s[f] for f in extra)
    plan = plan_experiments(first_fit_from_result(first), budget, LIMITS)
    t2 = time.perf_counter()
    sines, steps = _planned_data(p, plan, seed)
    both = dataclasses.replace(first_exp, sines=list(first_exp.sines) + sines, steps=list(first_exp.steps) + steps)
    two = identify(both, evaluate_fit=False)
    t3 = time.perf_counter()
    return {"membrane": p.name, "seed": seed, "creep_s": p.eta1_Pa_s / p.k1_Pa, "f_r_Hz": f_r,
            "sigma2_true_Pa": truth(p, "sigma_h''(1)_Pa"), "step_rest_s": step_rest_s(first.parameters),
            "one": _summary(p, one, base_s + sum(sine_s.values())),
            "first": _summary(p, first, base_s + sum(sine_s[f] for f in PAPER_HZ)),
            "two": _summary(p, two, base_s + sum(sine_s[f] for f in PAPER_HZ) + plan.total_s),
            "plan": [pk.record.label() for pk in plan.picks], "plan_total_s": plan.total_s, "budget_s": budget,
            "predicted_after": {n: plan.widths_after.get(n) for n in NAMES},
            "wall_s": {"one_pass": t1 - t0, "first_and_plan": t2 - t1, "second": t3 - t2}}


def _row(rs, key: str, n: str) -> str:
    vals = [r[key]["params"][n] for r in rs if n in r[key]["params"]]
    if not vals:
        return "| - | - | - |"
    e = np.abs([v["rel_err"] for v in vals]) * 100
    w = np.array([v["rel_width"] for v in vals]) * 100
    cov = sum(v["covers"] for v in vals)
    return f"| {np.median(e):.3g} / {e.max():.3g} % | {np.median(w):.3g} % | {cov}/{len(vals)} |"


def table(records: list) -> list[str]:
    out = ["| parameter | one pass: error median / worst | 95 % half-width (median) | covers | "
           "two passes: error median / worst | 95 % half-width (median) | covers |", "|---|---|---|---|---|---|---|"]
    for n in NAMES:
        out.append(f"| {n} " + _row(records, "one", n) + _row(records, "two", n)[1:])
    for key, label in (("one", "one pass"), ("two", "two passes")):
        c = np.abs([r[key].get("corr_eta1_eta2", np.nan) for r in records])
        ok = sum(r[key]["curvature_status"] == "identified" and "sigma_h''(1)_Pa" in r[key]["params"]
                 and abs(r[key]["params"]["sigma_h''(1)_Pa"]["rel_err"]) <= 0.1 for r in records)
        t = np.array([r[key]["experiment_s"] for r in records])
        out.append(f"\n{label}: |corr(eta1, eta2)| median {np.nanmedian(c):.2f}, max {np.nanmax(c):.2f}; "
                   f"sigma_h''(1) identified within 10 % in {ok}/{len(records)} runs; experiment time median "
                   f"{np.median(t):.0f} s")
    return out


def per_run(records: list) -> list[str]:
    """One line per run: the picks, eta1's interval (one pass, first pass, predicted, two passes), the
    eta1/eta2 correlation and sigma_h''(1)'s status."""
    out = ["| membrane, seed | creep s / f_r Hz | picks: sines, steps (s) | time one / two passes s | eta1 95 % "
           "half-width: one / first / predicted / two | abs corr(eta1, eta2): one / two | sigma_h''(1): one / two |",
           "|---|---|---|---|---|---|---|"]
    for r in records:
        w = [r[k]["params"].get("eta1_Pa_s", {}).get("rel_width", float("nan")) * 100 for k in ("one", "first")]
        pred = (r["predicted_after"].get("eta1_Pa_s") or float("nan")) * 100
        two = r["two"]["params"]["eta1_Pa_s"]["rel_width"] * 100
        n_sine = sum(p.startswith("sine") for p in r["plan"])
        c1, c2 = (abs(r[k].get("corr_eta1_eta2", float("nan"))) for k in ("one", "two"))
        out.append(f"| {r['membrane']}, {r['seed']} | {r['creep_s']:.2g} / {r['f_r_Hz']:.1f} | {n_sine}, "
                   f"{len(r['plan']) - n_sine} ({r['plan_total_s']:.0f}) | {r['one']['experiment_s']:.0f} / "
                   f"{r['two']['experiment_s']:.0f} | {w[0]:.3g} / {w[1]:.3g} / {pred:.3g} / {two:.3g} % | "
                   f"{c1:.2f} / {c2:.2f} | {r['one']['curvature_status']} / {r['two']['curvature_status']} |")
    return out


def resume_runs(path: Path, members, seeds: int, one_run) -> list:
    """Every (membrane, seed) run of ``one_run(params, f_r, seed)`` not yet in the JSON lines file
    ``path``, appended one line per run (an interrupted benchmark resumes); all records returned."""
    path.parent.mkdir(exist_ok=True)
    done = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    have = {(r["membrane"], r["seed"]) for r in done}
    for seed in range(1, seeds + 1):
        for p, f_r in members:
            if (p.name, seed) in have:
                continue
            rec = one_run(p, f_r, seed)
            done.append(rec)
            with path.open("a") as fh:
                fh.write(json.dumps(rec) + "\n")
            print(f"{p.name} seed {seed}: plan {rec['plan']} ({rec['plan_total_s']:.0f} of "
                  f"{rec['budget_s']:.0f} s), wall {rec['wall_s']}", file=sys.stderr, flush=True)
    return done


def runs_text(done: list) -> str:
    """The machine, the runs' count, the summary table and the per-run table."""
    return "\n".join([f"Machine: {machine()}; OPENBLAS_NUM_THREADS=1", "",
                      f"{len({r['membrane'] for r in done})} membranes, seeds {sorted({r['seed'] for r in done})}, "
                      f"{len(done)} runs.", ""] + table(done) + [""] + per_run(done)) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--membranes", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--jsonl", default=str(Path(__file__).with_name("results") / "plan.jsonl"))
    ap.add_argument("--table-only", action="store_true")
    args = ap.parse_args()
    members = [] if args.table_only else family(args.membranes)
    print(runs_text(resume_runs(Path(args.jsonl), members, args.seeds, one_run)))


if __name__ == "__main__":
    main()
