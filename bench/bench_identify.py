"""Benchmark of the identification (issue: static and dynamic fits, accelerated by harmonic balance).

Measures, per membrane (synthetic data from the preset, 1 um laser noise, the CLI's default
protocol: 12 static points, a 2.2 kV step over 4.2 s at 1 kHz, 26 sine frequencies 0.2-40 Hz):

1. the whole identification as the CLI runs it (load + static fit + dynamic fit + evaluation
   + report with figures), wall time -- target <= 10 s;
2. the dynamic fit with harmonic balance vs forward integration for the frequency response,
   same optimizer (least squares) and data. A full integration fit takes minutes to hours
   (eta1/k1 = 24 s for LP1: reaching the periodic steady state from rest takes hundreds of
   simulated seconds), so by default the integration objective is timed on a fixed number of
   evaluations and the total is *projected* from the evaluation/Jacobian counts of the
   harmonic-balance fit (the optimizer takes the same path: both objectives agree to < 1 nm);
   ``--full-integration NAME`` runs the real integration fit for one membrane;
3. the static fit: the paper's Nelder-Mead on eq. 19 vs bounded least squares on the same data;
4. the fast transient solver vs adaptive integration (time per step response, max difference).

Run:  /work/venv/bin/python bench/bench_identify.py [--membranes LP1,A1,A2] [--full-integration A2]
Prints markdown tables (machine, results) for docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dea_ros.identify.dynamic_fit import fit_dynamic, select_fit_frequencies
from dea_ros.identify.dynamic_objective import DynamicObjective
from dea_ros.identify.experiments import load_experiment_set
from dea_ros.identify.pipeline import identify
from dea_ros.identify.report import write_report
from dea_ros.identify.static_fit import fit_static
from dea_ros.identify.synth import synthesize
sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine_info import machine_info  # noqa: E402

from dea_ros.model import preset  # noqa: E402
from dea_ros.solvers.inputs import SampledVoltage  # noqa: E402
from dea_ros.solvers.integrate import simulate  # noqa: E402
from dea_ros.solvers.transient import TransientCollocation  # noqa: E402


machine = machine_info


def bench_whole(folder: Path, out: Path) -> dict:
    t0 = time.perf_counter()
    exp = load_experiment_set(folder)
    res = identify(exp)
    write_report(res, out)
    total = time.perf_counter() - t0
    return {"total_s": total, "result": res}


def bench_dynamic(exp, static_params, integration_evals: int) -> dict:
    """HBM fit (timed), integration objective (timed per evaluation), projection."""
    t0 = time.perf_counter()
    hbm = fit_dynamic(static_params, exp.steps, exp.sines)  # paper weights and frequencies
    t_hbm = time.perf_counter() - t0
    points = select_fit_frequencies(exp.sines)
    theta = np.log([hbm.parameters.k1_Pa, hbm.parameters.eta1_Pa_s, hbm.parameters.eta2_Pa_s])
    per_eval_hbm = (hbm.time_step_s + hbm.time_frequency_s) / hbm.n_evaluations
    freq_hbm = hbm.time_frequency_s / hbm.n_evaluations
    step_eval = hbm.time_step_s / hbm.n_evaluations
    fi = DynamicObjective(static_params, exp.steps, points, frequency_method="integration")
    times = []
    for k in range(integration_evals):
        fi.evaluate(theta * (1.0 + 1e-4 * (k + 1)), jacobian=False)
    freq_fi = fi.time_frequency_s / integration_evals
    step_fi = fi.time_step_s / integration_evals
    per_eval_fi = freq_fi + step_fi
    # Same optimizer path: n_evaluations objective values, n_jacobians Jacobians; with integration
    # every Jacobian needs 3 extra frequency-response solves (forward differences).
    projected_fi = hbm.n_evaluations * per_eval_fi + hbm.n_jacobians * 3 * freq_fi
    projected_hbm = hbm.n_evaluations * per_eval_hbm
    return {
        "hbm_fit_s": t_hbm, "n_evaluations": hbm.n_evaluations, "n_jacobians": hbm.n_jacobians,
        "per_eval_hbm_s": per_eval_hbm, "per_eval_fi_s": per_eval_fi, "freq_hbm_s": freq_hbm, "freq_fi_s": freq_fi,
        "step_s": step_eval, "projected_fi_s": projected_fi, "projected_hbm_s": projected_hbm,
        "fit_frequencies": [p.frequency_Hz for p in points], "times": times,
    }


def bench_static(exp, truth) -> dict:
    data = exp.all_static()
    template = exp.template_parameters()
    out = {}
    for method in ("paper", "lsq"):
        t0 = time.perf_counter()
        res = fit_static(data, template, method=method, prior_from_template=False)
        out[method] = {
            "time_s": time.perf_counter() - t0, "evaluations": res.n_evaluations,
            "rms_um": res.errors_um["rms_error_um"], "max_um": res.errors_um["max_error_um"],
            "eps_r_error_percent": 100 * (res.parameters.relative_permittivity / truth.relative_permittivity - 1),
        }
    return out


def bench_transient(exp, params) -> dict:
    step = exp.steps[0]
    solver = TransientCollocation(step.time_s, step.voltage_V)
    t0 = time.perf_counter()
    cold = solver.solve(params)
    t_cold = time.perf_counter() - t0
    n = 10
    t0 = time.perf_counter()
    for k in range(n):
        solver.solve(params.replace(k1_Pa=params.k1_Pa * (1 + 1e-3 * k)), sensitivities=True)
    t_warm = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    ref = simulate(params, SampledVoltage(step.time_s, step.voltage_V, hold="zoh"), step.time_s[-1],
                   t_eval=step.time_s, rtol=1e-11, atol_scale=1e-11)
    t_ref = time.perf_counter() - t0
    t0 = time.perf_counter()
    simulate(params, SampledVoltage(step.time_s, step.voltage_V, hold="zoh"), step.time_s[-1], t_eval=step.time_s)
    t_default = time.perf_counter() - t0
    return {"cold_s": t_cold, "warm_sens_s": t_warm, "simulate_tight_s": t_ref, "simulate_default_s": t_default,
            "max_diff_um": float(np.max(np.abs(cold.displacement_m - ref.displacement_m)) * 1e6),
            "samples": step.n_samples}


def fmt_s(x: float) -> str:
    if x >= 3600:
        return f"{x / 3600:.1f} h"
    if x >= 60:
        return f"{x / 60:.1f} min"
    if x >= 1:
        return f"{x:.2f} s"
    return f"{x * 1e3:.1f} ms"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--membranes", default="LP1,A1,A2")
    ap.add_argument("--integration-evals", type=int, default=1,
                    help="objective evaluations timed with forward integration (each takes seconds to minutes)")
    ap.add_argument("--full-integration", default=None, metavar="NAME",
                    help="also run the complete integration-based dynamic fit for this membrane (slow)")
    ap.add_argument("--workdir", default=None, help="keep synthetic data and reports here")
    args = ap.parse_args(argv)
    names = [n.strip() for n in args.membranes.split(",") if n.strip()]
    work = Path(args.workdir or tempfile.mkdtemp(prefix="bench_identify_"))
    m = machine()
    rows = {}
    for name in names:
        truth = preset(name)
        folder = work / f"data_{name}"
        t0 = time.perf_counter()
        synthesize(truth, 1e-6, folder, seed=0)
        t_synth = time.perf_counter() - t0
        print(f"[{name}] synthetic data in {t_synth:.1f} s", file=sys.stderr, flush=True)
        whole = bench_whole(folder, work / f"report_{name}")
        res = whole["result"]
        print(f"[{name}] whole identification {whole['total_s']:.2f} s", file=sys.stderr, flush=True)
        exp = load_experiment_set(folder)
        static_params = res.static.parameters
        dyn = bench_dynamic(exp, static_params, args.integration_evals)
        print(f"[{name}] dynamic: HBM fit {dyn['hbm_fit_s']:.2f} s, integration {fmt_s(dyn['per_eval_fi_s'])}"
              "/evaluation", file=sys.stderr, flush=True)
        rows[name] = {"synth_s": t_synth, "whole": whole, "dyn": dyn, "static": bench_static(exp, truth),
                      "transient": bench_transient(exp, res.parameters), "result": res}
    full = None
    if args.full_integration:
        name = args.full_integration
        exp = load_experiment_set(work / f"data_{name}")
        static_params = rows[name]["result"].static.parameters if name in rows else \
            fit_static(exp.all_static(), exp.template_parameters(), prior_from_template=False).parameters
        t0 = time.perf_counter()
        fi = fit_dynamic(static_params, exp.steps, exp.sines, frequency_method="integration")
        full = {"name": name, "time_s": time.perf_counter() - t0, "evals": fi.n_evaluations, "jacs": fi.n_jacobians,
                "cost": fi.cost, "params": fi.parameters}
        print(f"[{name}] full integration fit {fmt_s(full['time_s'])}", file=sys.stderr, flush=True)

    print("### Machine\n")
    print("| nproc | CPU | Python | numpy | scipy |")
    print("|---|---|---|---|---|")
    print(f"| {m['nproc']} | {m['cpu']} | {m['python']} | {m['numpy']} | {m['scipy']} |\n")
    print("### Whole identification (CLI path: load, static + dynamic fit, evaluation, report with figures)\n")
    print("| Membrane | Total | static fit | dynamic fit | evaluation | report | target |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        t = r["whole"]["result"].timings_s
        report = r["whole"]["total_s"] - t["identification_total"]
        print(f"| {name} | **{fmt_s(r['whole']['total_s'])}** | {fmt_s(t['static_fit'])} | {fmt_s(t['dynamic_fit'])} | "
              f"{fmt_s(t['evaluation'])} | {fmt_s(report)} | <= 10 s |")
    print("\n### Dynamic fit: harmonic balance vs forward integration (same least-squares optimizer, same data)\n")
    print(f"Fit frequencies {', '.join(f'{f:g}' for f in next(iter(rows.values()))['dyn']['fit_frequencies'])} Hz "
          "(the paper's); each evaluation also simulates the 4.2 s step (collocation, with sensitivities).")
    print(f"Integration timed on {args.integration_evals} evaluation(s) per membrane; its total is projected from "
          "the evaluation and Jacobian counts of the harmonic-balance fit (forward differences: 3 extra "
          "steady states per frequency per Jacobian).\n")
    print("| Membrane | evaluations / Jacobians | HBM fit (measured) | frequency part per evaluation: HBM | "
          "integration | ratio | per evaluation incl. step: HBM | integration | ratio | integration fit "
          "(projected) | speed-up of the fit |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        d = r["dyn"]
        print(f"| {name} | {d['n_evaluations']} / {d['n_jacobians']} | {fmt_s(d['hbm_fit_s'])} | "
              f"{fmt_s(d['freq_hbm_s'])} | "
              f"{fmt_s(d['freq_fi_s'])} | {d['freq_fi_s'] / d['freq_hbm_s']:.0f}x | {fmt_s(d['per_eval_hbm_s'])} | "
              f"{fmt_s(d['per_eval_fi_s'])} | {d['per_eval_fi_s'] / d['per_eval_hbm_s']:.0f}x | "
              f"{fmt_s(d['projected_fi_s'])} | **{d['projected_fi_s'] / d['hbm_fit_s']:.0f}x** |")
    if full:
        r = rows.get(full["name"])
        ratio = f"{full['time_s'] / r['dyn']['hbm_fit_s']:.0f}x" if r else "-"
        print(f"\nFull integration fit, measured ({full['name']}): {fmt_s(full['time_s'])}, "
              f"{full['evals']} evaluations, "
              f"{full['jacs']} Jacobians; speed-up of the HBM fit: {ratio}.")
    print("\n### Static fit: paper (Nelder-Mead on eq. 19) vs least squares (default), same data\n")
    print("| Membrane | method | time | evaluations | RMS error [um] | max error [um] | eps_r error |")
    print("|---|---|---|---|---|---|---|")
    for name, r in rows.items():
        for method, s in r["static"].items():
            print(f"| {name} | {method} | {fmt_s(s['time_s'])} | {s['evaluations']} | {s['rms_um']:.3f} | "
                  f"{s['max_um']:.3f} | {s['eps_r_error_percent']:+.3f} % |")
    print("\n### Fast transient solver (Hermite-Simpson collocation) vs adaptive integration, 2.2 kV step\n")
    print("| Membrane | samples | collocation cold | warm + sensitivities | simulate (rtol 1e-8) | "
          "max difference vs DOP853 rtol 1e-11 |")
    print("|---|---|---|---|---|---|")
    for name, r in rows.items():
        t = r["transient"]
        print(f"| {name} | {t['samples']} | {fmt_s(t['cold_s'])} | {fmt_s(t['warm_sens_s'])} | "
              f"{fmt_s(t['simulate_default_s'])} | {t['max_diff_um'] * 1e3:.2f} nm |")
    print(f"\n(data and reports in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
