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

``--data held`` (session 20; the default): the runs as the rig records them and as identifier_node's
``adaptive: true`` protocol runs them, on the data of the coverage family (bench_coverage_family
``--data held``: synth_rig's held-voltage run from rest through the bag extraction, settle times from the
membrane, static points at the family's other masses, each run's noise seed from (member, seed)):

* one pass: ``rig_protocol`` with the 17 frequencies (the family's 17-frequency run, same noise);
* two passes: ``rig_protocol`` with the paper's 4 (the family's paper run, same noise), identified; then
  ``identify.adaptive.plan_second_pass`` (the node's planner: offsets allowed, records as long as the first
  pass's, no voltage above its peak) with ``adaptive_budget_s`` = the one-pass protocol's duration - the
  first pass's, and ``adaptive_max_settle_s`` = the longest hold of the first pass; the planned protocol
  recorded the same way from rest (its own noise seed) and both passes cut as identifier_node's bag
  (``synth_rig.passes_experiments``: two metadata records, each pass with its own t0) and identified.

``--data orbit``: sessions 9-19's runs (synth.synthesize_experiments, the list above).

``--reach`` (session 21): how far any second pass could go, by the planner's expected widths from the
family's first pass (``one_reach``): the node's plan, a plan aimed at sigma_h''(1) alone (both within the
budget) and every candidate record repeated 100 times (the information the rig's candidate set at the
dynamic mass holds; ~100 x the budget); since session 22 the same three with static points at the family's
other masses (1-5 g, 0 V and the peak voltage) among the candidates, as ``dea-ros plan --other-mass`` offers
them where the rig has those masses.

Run: python bench/bench_plan.py [--membranes 3] [--seeds 2] [--members F00,F01] [--data held] [--reach]
[--jsonl bench/results/plan.jsonl] (appends one JSON line per run; --table-only tabulates).
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

from bench_coverage_family import PAPER_HZ, family, noise_seed, seventeen, truth  # noqa: E402
from machine_info import machine  # noqa: E402

from dea_ros.errors import IntegrationError, PlanningError  # noqa: E402
from dea_ros.identify.adaptive import plan_second_pass  # noqa: E402
from dea_ros.identify.pipeline import identify  # noqa: E402
from dea_ros.identify.planning import (PlanLimits, candidate_information, candidate_records,  # noqa: E402
                                       first_fit_from_result, fit_widths, plan_experiments, sine_record_cost,
                                       step_rest_s)
from dea_ros.identify.synth import DEFAULT_STATIC_MASSES_KG, synthesize_experiments  # noqa: E402
from dea_ros.identify.synth_rig import RecordedPass, passes_experiments, record_protocol, rig_protocol  # noqa: E402
from dea_ros.sim.plant import LASER_QUANTISATION_M  # noqa: E402

NAMES = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "sigma_h''(1)_Pa")
LIMITS = PlanLimits(measure_s=2.0, settle_s=8.0, step_pre_s=0.2, step_hold_s=4.0, offsets=False,
                    static_fractions=(), step_fractions=(0.6, 0.8, 1.0))


def _synth(p, seed: int, freqs, **kw):
    return synthesize_experiments(p, 1e-6, seed=seed, sine_frequencies_Hz=freqs, series_frequencies_Hz=(),
                                  quantisation_m=LASER_QUANTISATION_M, random_start_phase=True, **kw)


def _summary(p, res, exp_time_s: float) -> dict:
    st = res.statistics
    out = {"experiment_s": exp_time_s, "curvature_status": res.curvature_status, "params": {},
           "shape_outcome": res.shape_test.outcome if res.shape_test is not None else None}
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


#: 0 V between the passes (s): the first fit and the plan, as in the node (not recorded; pass 2 from rest)
GAP_S = 30.0


def _hold_s(protocol) -> float:
    """The longest settle/hold of a protocol's segments (s)."""
    return max(float(seg.get(k, 0.0)) for seg in protocol.raw_segments for k in ("settle_s", "hold_s"))


def _held_protocols(p, f_r: float) -> tuple:
    """(the one-pass protocol, the paper-set protocol, the adaptive first pass, the second pass's budget s)."""
    one_proto = rig_protocol(p, seventeen(f_r))
    paper_proto = rig_protocol(p, PAPER_HZ)
    budget = one_proto.duration_s() - paper_proto.duration_s()
    first_proto = dataclasses.replace(paper_proto, adaptive=True, adaptive_budget_s=budget,
                                      adaptive_max_settle_s=_hold_s(paper_proto))
    return one_proto, paper_proto, first_proto, budget


def one_run_held(p, f_r: float, seed: int) -> dict:
    """One pass against two as identifier_node runs them (module docstring, ``--data held``)."""
    run_seed = noise_seed(p.name, seed)
    kw = {"noise_m": 1e-6, "quantisation_m": LASER_QUANTISATION_M}
    others = {"other_masses_kg": DEFAULT_STATIC_MASSES_KG}
    base = {"membrane": p.name, "seed": seed, "data": "held", "noise_seed": run_seed, "creep_s": p.eta1_Pa_s / p.k1_Pa,
            "f_r_Hz": f_r, "sigma2_true_Pa": truth(p, "sigma_h''(1)_Pa")}
    one_proto, paper_proto, first_proto, budget = _held_protocols(p, f_r)
    t0 = time.perf_counter()
    try:
        one_rec = record_protocol(p, one_proto, run_seed, **kw)
        first_rec = record_protocol(p, first_proto, run_seed, **kw)
    except IntegrationError as exc:         # no converged data (bench_coverage_family counts these too)
        return {**base, "error": str(exc)}
    one = identify(passes_experiments(p, [RecordedPass(one_proto, one_rec)], run_seed, **kw, **others),
                   evaluate_fit=False)
    t1 = time.perf_counter()
    first_pass = RecordedPass(first_proto, first_rec)
    first = identify(passes_experiments(p, [first_pass], run_seed, **kw, **others), evaluate_fit=False)
    try:
        second = plan_second_pass(first, first_proto)
    except PlanningError as exc:
        return {**base, "error": f"plan: {exc}", "one": _summary(p, one, one_proto.duration_s())}
    t2 = time.perf_counter()
    start2 = first_rec.segments[-1].end_s + GAP_S
    try:
        rec2 = record_protocol(p, second.protocol, noise_seed(p.name, seed + 1000), **kw)
    except IntegrationError as exc:
        return {**base, "error": f"pass 2: {exc}", "one": _summary(p, one, one_proto.duration_s())}
    passes = [first_pass, RecordedPass(second.protocol, rec2, start2, second.record_extra())]
    two = identify(passes_experiments(p, passes, run_seed, **kw, **others), evaluate_fit=False)
    t3 = time.perf_counter()
    plan = second.plan
    pass2_s = rec2.segments[-1].end_s
    return {**base, "step_rest_s": step_rest_s(first.parameters),
            "one": _summary(p, one, one_proto.duration_s()), "first": _summary(p, first, paper_proto.duration_s()),
            "two": _summary(p, two, first_proto.duration_s() + pass2_s),
            "plan": [pk.record.label() for pk in plan.picks], "plan_total_s": plan.total_s, "budget_s": budget,
            "predicted_after": {n: plan.widths_after.get(n) for n in NAMES},
            "wall_s": {"one_pass": t1 - t0, "first_and_plan": t2 - t1, "second": t3 - t2}}


#: what --reach reports: the expected sigma_h''(1) half-width and |corr(eta1, eta2)| of these plans; the
#: last three (session 22) with static points at the family's other masses (1-5 g) among the candidates (0 V and the
#: amplifier's peak voltage on each: a mass swap by hand, which the rig's operator would do)
REACH_CASES = ("node's plan", "curvature only", "every candidate x100", "other masses: node's criterion",
               "other masses: curvature only", "other masses: every candidate x100")
S2 = "sigma_h''(1)_Pa"


def one_reach(p, f_r: float, seed: int) -> dict:
    """How far a second pass can shrink sigma_h''(1) (and the eta1/eta2 correlation), by the planner's own
    expected widths from the family's first pass (``--reach``): the node's plan at the budget, a plan aimed at
    sigma_h''(1) alone at the budget, and every candidate record repeated 100 times (the information limit of
    the rig's candidate set at the dynamic mass; ~100 x the budget)."""
    run_seed = noise_seed(p.name, seed)
    kw = {"noise_m": 1e-6, "quantisation_m": LASER_QUANTISATION_M}
    base = {"membrane": p.name, "seed": seed, "data": "reach", "creep_s": p.eta1_Pa_s / p.k1_Pa, "f_r_Hz": f_r}
    _one, _paper, first_proto, budget = _held_protocols(p, f_r)
    try:
        rec = record_protocol(p, first_proto, run_seed, **kw)
        first = identify(passes_experiments(p, [RecordedPass(first_proto, rec)], run_seed, **kw,
                                            other_masses_kg=DEFAULT_STATIC_MASSES_KG), evaluate_fit=False)
        second = plan_second_pass(first, first_proto)
    except (IntegrationError, PlanningError) as exc:
        return {**base, "error": str(exc)}
    fit = first_fit_from_result(first)
    cases = {"node's plan": (second.plan.widths_after, second.plan.correlation_after)}
    masses = dataclasses.replace(second.limits, other_masses_kg=tuple(m for m in DEFAULT_STATIC_MASSES_KG if m > 0))
    scale = fit.scale()
    for prefix, limits in (("", second.limits), ("other masses: ", masses)):
        info, _notes = candidate_information(fit, candidate_records(fit.parameters, limits), limits)
        every = fit.information + 100.0 * sum(g for _c, g in info) / np.outer(scale, scale)
        only = plan_experiments(fit, budget, limits, targets=(S2,), information=info)
        cases[prefix + "curvature only"] = (only.widths_after, only.correlation_after)
        cases[prefix + "every candidate x100"] = fit_widths(dataclasses.replace(fit, information=every))
        if prefix:
            node = plan_experiments(fit, budget, limits, information=info)
            cases[prefix + "node's criterion"] = (node.widths_after, node.correlation_after)
    return {**base, "budget_s": budget, "before": {"s2": second.plan.widths_before.get(S2),
                                                   "corr": second.plan.correlation_before.get("eta1/eta2")},
            "reach": {k: {"s2": w.get(S2), "corr": c.get("eta1/eta2")} for k, (w, c) in cases.items()}}


def reach_text(records: list) -> str:
    """The --reach table: per run the expected sigma_h''(1) half-width and |corr(eta1, eta2)| by case, and how
    many runs each case brings within 10 % / below 0.9 (the cases the runs recorded: session 21's have three)."""
    ok = [r for r in records if "reach" in r]
    cases = [k for k in REACH_CASES if any(k in r["reach"] for r in ok)]
    out = [f"Machine: {machine()}", "", f"{len(ok)} runs (failed: {len(records) - len(ok)})", "",
           "| membrane, seed | creep s | budget s | sigma_h''(1) 95 % half-width: first / " + " / ".join(cases)
           + " | abs corr(eta1, eta2): first / " + " / ".join(cases) + " |", "|---|---|---|---|---|"]

    def pct(w):
        return "inf" if w is None or not np.isfinite(w) else f"{w * 100:.3g} %"

    def corr(v):
        return "-" if v is None else f"{abs(v):.2f}"
    for r in ok:
        got = [r["reach"].get(k, {}) for k in cases]
        out.append(f"| {r['membrane']}, {r['seed']} | {r['creep_s']:.2g} | {r['budget_s']:.0f} | "
                   + " / ".join(pct(v) for v in [r["before"]["s2"]] + [g.get("s2") for g in got])
                   + " | " + " / ".join(corr(v) for v in [r["before"]["corr"]] + [g.get("corr") for g in got]) + " |")
    for k in cases:
        got = [r["reach"][k] for r in ok if k in r["reach"]]
        s2 = sum(g["s2"] is not None and g["s2"] <= 0.1 for g in got)
        c = sum(g["corr"] is not None and abs(g["corr"]) < 0.9 for g in got)
        out.append(f"\n{k}: expected sigma_h''(1) half-width <= 10 % in {s2}/{len(got)}, |corr| < 0.9 in "
                   f"{c}/{len(got)}")
    return "\n".join(out) + "\n"


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
            head = f"plan {rec.get('plan')} ({rec.get('plan_total_s', 0):.0f} of {rec.get('budget_s', 0):.0f} s), "
            tail = head + f"wall {rec['wall_s']}" if "two" in rec else rec.get("reach", rec.get("error"))
            print(f"{p.name} seed {seed}: {tail}", file=sys.stderr, flush=True)
    return done


def runs_text(done: list) -> str:
    """The machine, the runs' count, the summary table and the per-run table (runs without both arms --
    no converged data, nothing planned -- counted and named)."""
    both = [r for r in done if "two" in r]
    failed = [f"{r['membrane']} seed {r['seed']}: {r['error']}" for r in done if "two" not in r]
    return "\n".join([f"Machine: {machine()}; OPENBLAS_NUM_THREADS=1", "",
                      f"{len({r['membrane'] for r in done})} membranes, seeds {sorted({r['seed'] for r in done})}, "
                      f"{len(done)} runs, {len(both)} with both arms." + (" Without: " + "; ".join(failed) if failed
                                                                          else ""), ""]
                     + table(both) + [""] + per_run(both)) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--membranes", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--jsonl", default=str(Path(__file__).with_name("results") / "plan.jsonl"))
    ap.add_argument("--table-only", action="store_true")
    ap.add_argument("--members", default="", help="comma-separated membrane names (default: the first --membranes)")
    ap.add_argument("--data", default="held", choices=("held", "orbit"),
                    help="held: the rig's runs and identifier_node's adaptive pass (module docstring); orbit: "
                         "synth's records (sessions 9-19)")
    ap.add_argument("--reach", action="store_true",
                    help="instead: how far a second pass can shrink sigma_h''(1) and the eta1/eta2 correlation, by "
                         "the planner's expected widths (one_reach)")
    args = ap.parse_args()
    only = [m for m in args.members.split(",") if m]
    members = [] if args.table_only else [(p, f_r) for p, f_r in family(max(args.membranes, 20 if only else 0))
                                          if not only or p.name in only]
    if args.reach:
        print(reach_text(resume_runs(Path(args.jsonl), members, args.seeds, one_reach)))
        return
    print(runs_text(resume_runs(Path(args.jsonl), members, args.seeds,
                                one_run_held if args.data == "held" else one_run)))


if __name__ == "__main__":
    main()
