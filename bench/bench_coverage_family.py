"""Identification on a family of membranes unlike the presets (issue 21, item 2).

The family (``family``): membranes drawn from a seeded generator, both signs of sigma_h'(1) (they
alternate), creep times eta1/k1 log-uniform over 0.05-30 s, damping eta2 = 24 kPa s (about the
presets') times a log-uniform factor 0.3-3, masses 2-6 g, thicknesses 20-60 um, prestretch
1.1-1.4, eps_r 2.4-3.4, plate radius 4-5.5 mm, electrode width 13-16 mm; the hyperelastic stress
given by its combinations (eq. 10, derivatives in s) sigma_h(1) 0.4-1 MPa, |sigma_h'(1)| 0.15-0.6
MPa, sigma_h''(1) 2-12 MPa, sigma_h'''(1) -(10-25) MPa. A draw is kept when the model has static
equilibria at every mass and voltage of the protocol and a resonance below 35 Hz.

Data (dea_ros.identify.synth.synthesize_experiments, per membrane and noise seed): static points,
a 2.2 kV step (zero-order hold, adaptive DOP853 from rest), 2.5 kV sine records from the converged
periodic orbit (single shooting on DOP853, Floquet-checked; integration in torus bands), each record
starting at a random phase, 1 um laser noise and the ILD1320-10 quantisation (0.156 um) on every
sample. Two sine sets: the paper's four fit frequencies (0.2, 8.3, 11.2, 40 Hz) and 17 frequencies
placed around each membrane's own resonance. The identification is the default one
(``identify(exp, evaluate_fit=False)``: the paper's stage 1, classification, joint refinement).

Noise: run ``seed`` of membrane ``F<i>`` draws its laser noise and start phases from the noise seed
``noise_seed(i, seed)`` (``--noise per-membrane``, the default since session 19): every run independent.
``--noise shared`` uses ``seed`` itself for every membrane (sessions 13-18): the same noise sequence and
start phases on each membrane, so the runs of one seed are correlated (session 18's 17-frequency k1: the
per-seed mean z -1.05, -1.10, +0.17, -0.57, -0.42 over ~19 membranes each, where independent runs would
scatter by ~0.23) and the family's mean z rests on five draws.

Per parameter: median and worst relative error, the share of 95 % intervals that contain the
truth, and z = (value - truth) / std. error (mean and std over all runs); sigma_h''(1) counted only
where identified; the resonance peak of the fitted model against the true one.

Run: python bench/bench_coverage_family.py [--membranes 20] [--seeds 5] [--sets paper,17]
[--jsonl bench/results/family.jsonl] (one JSON line per run, appended: an interrupted run resumes
and ``--table-only`` tabulates what is there).
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

from machine_info import machine  # noqa: E402

from dea_ros.errors import DeaRosError, IntegrationError  # noqa: E402
from dea_ros.identify.pipeline import identify  # noqa: E402
from dea_ros.identify.static_fit import EXTENDED_COMBINATION_MATRIX, OgdenRepresentation  # noqa: E402
from dea_ros.identify.synth import DEFAULT_STATIC_MASSES_KG, synthesize_experiments  # noqa: E402
from dea_ros.identify.synth_rig import rig_experiments, rig_protocol, rig_settle_times  # noqa: E402
from dea_ros.model import preset, static_equilibrium  # noqa: E402
from dea_ros.sim.plant import LASER_QUANTISATION_M  # noqa: E402
from dea_ros.solvers.inputs import SinePeriodic  # noqa: E402
from dea_ros.solvers.sweep import frequency_sweep  # noqa: E402

PAPER_HZ = (0.2, 8.3, 11.2, 40.0)
STRESS = ("sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa", "sigma_h'''(1)_Pa")
NAMES = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa")


def _draw(rng, k: int):
    """One candidate membrane (module docstring); sigma_h'(1) positive for even k, negative for odd."""
    sign = 1.0 if k % 2 == 0 else -1.0
    combos = np.array([rng.uniform(0.4e6, 1.0e6), sign * rng.uniform(0.15e6, 0.6e6), rng.uniform(2e6, 12e6),
                       -rng.uniform(10e6, 25e6)])
    lam = rng.uniform(1.1, 1.4)
    prior = np.r_[preset("A1").beta_Pa, preset("A1").gamma_Pa]
    bg = OgdenRepresentation(lam, 4, prior, matrix=EXTENDED_COMBINATION_MATRIX).beta_gamma(combos)
    k1 = float(np.exp(rng.uniform(np.log(15e6), np.log(70e6))))
    creep = float(np.exp(rng.uniform(np.log(0.05), np.log(30.0))))
    damping = float(np.exp(rng.uniform(np.log(0.3), np.log(3.0))))
    return preset("A2").replace(
        name=f"F{k:02d}", prestretch=lam, thickness_m=rng.uniform(20e-6, 60e-6),
        plate_radius_m=rng.uniform(4.0e-3, 5.5e-3), electrode_width_m=rng.uniform(13e-3, 16e-3),
        mass_kg=rng.uniform(2e-3, 6e-3), relative_permittivity=rng.uniform(2.4, 3.4), k1_Pa=k1,
        eta1_Pa_s=k1 * creep, eta2_Pa_s=24e3 * damping,
        beta_Pa=tuple(float(v) for v in bg[:3]), gamma_Pa=tuple(float(v) for v in bg[3:]))


def _peak(params, lo: float, hi: float, n: int = 25) -> dict:
    return frequency_sweep(params, SinePeriodic(2500.0, 1.0), np.linspace(lo, hi, n), n_harmonics=8,
                           branch_switching=False, realised=False).resonance_peak()


def _usable(p) -> float | None:
    """The resonance frequency (Hz) of a usable draw, else None."""
    try:
        for m in (0.0, 0.001, 0.002, 0.003, 0.004, 0.005):
            static_equilibrium(p, 0.0, mass_kg=m)
        static_equilibrium(p, np.linspace(2000.0, 2500.0, 6))
        pk = _peak(p, 1.0, 38.0, 38)
    except (DeaRosError, ArithmeticError, ValueError):
        return None
    f = float(pk["frequency_Hz"])
    return f if np.isfinite(f) and 2.0 < f < 35.0 else None


def family(n: int, seed: int = 2110) -> list:
    """[(membrane, resonance Hz)]: ``n`` usable draws (module docstring)."""
    rng = np.random.default_rng(seed)
    out, k = [], 0
    while len(out) < n:
        p = _draw(rng, len(out))
        k += 1
        f = _usable(p)
        if f is not None:
            out.append((p, f))
        if k > 20 * n:
            raise RuntimeError("too few usable membranes drawn")
    return out


def seventeen(f_r: float) -> tuple:
    """17 sine frequencies: the paper's four (stage 1 fits them) and 13 placed on the membrane's own
    resonance f_r: 0.25, 0.5, 0.7 f_r, nine across 0.85-1.15 f_r, 1.5 f_r."""
    near = list(np.linspace(0.85, 1.15, 9) * f_r)
    return tuple(sorted({round(float(f), 3) for f in list(PAPER_HZ) + [0.25 * f_r, 0.5 * f_r, 0.7 * f_r] + near
                         + [1.5 * f_r]}))


def truth(p, name: str) -> float:
    if name in STRESS:
        return float((EXTENDED_COMBINATION_MATRIX @ np.r_[p.beta_Pa, p.gamma_Pa])[STRESS.index(name)])
    return p.relative_permittivity if name == "eps_r" else float(getattr(p, name))


def noise_seed(member: str, seed: int) -> int:
    """The noise seed of run ``seed`` (1, 2, ...) of family member ``member`` ('F07'): independent per member."""
    index = int(member.lstrip("F")) if member.lstrip("F").isdigit() else sum(map(ord, member))
    return int(np.random.SeedSequence([2110, index, seed]).generate_state(1)[0])


def one_run(p, f_r: float, true_peak: dict, kind: str, seed: int, data: str = "orbit",
            noise: str = "per-membrane") -> dict:
    freqs = PAPER_HZ if kind == "paper" else seventeen(f_r)
    run_seed = seed if noise == "shared" else noise_seed(p.name, seed)
    t0 = time.perf_counter()
    held = {}
    if data == "held":     # one held-voltage run from rest through the bag extraction (identify.synth_rig)
        protocol = rig_protocol(p, freqs)
        try:
            exp, rec = rig_experiments(p, protocol, seed=run_seed, other_masses_kg=DEFAULT_STATIC_MASSES_KG,
                                       quantisation_m=LASER_QUANTISATION_M)
        except IntegrationError as exc:    # halving the tolerance moved the run: no converged data
            return {"membrane": p.name, "kind": kind, "seed": seed, "data": data, "error": str(exc), "params": {},
                    "creep_s": p.eta1_Pa_s / p.k1_Pa, "f_r_Hz": f_r, "curvature_status": "-", "identify_s": 0.0}
        held = {"protocol_s": protocol.duration_s(), "settle": dataclasses.asdict(rig_settle_times(p)),
                "tolerance_check_m": rec.tolerance_check_m}
    else:
        exp = synthesize_experiments(p, 1e-6, seed=run_seed, sine_frequencies_Hz=freqs, series_frequencies_Hz=(),
                                     quantisation_m=LASER_QUANTISATION_M, random_start_phase=True)
    t1 = time.perf_counter()
    res = identify(exp, evaluate_fit=False)
    t2 = time.perf_counter()
    st = res.statistics
    rec = {"membrane": p.name, "kind": kind, "seed": seed, "noise": noise, "noise_seed": run_seed,
           "creep_s": p.eta1_Pa_s / p.k1_Pa, "f_r_Hz": f_r,
           "curvature_status": res.curvature_status, "joint_failed": res.joint is None, "synth_s": t1 - t0,
           "identify_s": t2 - t1, "params": {}, "data": data, **held}
    for n in NAMES:
        if n not in st.names:
            continue
        i = st.names.index(n)
        tv = truth(p, n)
        rec["params"][n] = {"rel_err": float(st.values[i] / tv - 1), "z": float((st.values[i] - tv) / st.std_error[i]),
                            "covers": bool(st.ci_low[i] <= tv <= st.ci_high[i]), "status": res.curvature_status
                            if n == "sigma_h''(1)_Pa" else "-"}
    try:
        pk = _peak(res.parameters, 0.9 * true_peak["frequency_Hz"], 1.1 * true_peak["frequency_Hz"])
        rec["peak_f_err"] = float(pk["frequency_Hz"] / true_peak["frequency_Hz"] - 1)
        rec["peak_d_err"] = float(pk["d_rms_m"] / true_peak["d_rms_m"] - 1)
    except (DeaRosError, ArithmeticError, ValueError) as exc:
        rec["peak_error"] = str(exc)
    return rec


def table(records: list) -> list[str]:
    out = ["| data | parameter | runs | median abs rel. error | worst | 95 % CI covers the truth | "
           "z: mean / std |", "|---|---|---|---|---|---|---|"]
    for kind in ("paper", "17"):
        rs = [r for r in records if r["kind"] == kind and "error" not in r]
        errors = [r for r in records if r["kind"] == kind and "error" in r]
        if errors:
            out.append(f"| {'paper' if kind == 'paper' else '17'} | no converged data (left out) | {len(errors)} | "
                       + ", ".join(f"{r['membrane']} seed {r['seed']}" for r in errors) + " | | | |")
        if not rs:
            continue
        label = "paper's 4 freq." if kind == "paper" else "17 freq."
        for n in NAMES:
            vals = [r["params"][n] for r in rs if n in r["params"]
                    and (n != "sigma_h''(1)_Pa" or r["curvature_status"] == "identified")]
            if not vals:
                continue
            e = np.abs([v["rel_err"] for v in vals]) * 100
            z = np.array([v["z"] for v in vals])
            cov = sum(v["covers"] for v in vals)
            name = n + (" (where identified)" if n == "sigma_h''(1)_Pa" else "")
            out.append(f"| {label} | {name} | {len(vals)} | {np.median(e):.3g} % | {e.max():.3g} % | "
                       f"{cov} / {len(vals)} ({100 * cov / len(vals):.0f} %) | {z.mean():+.2f} / {z.std(ddof=1):.2f} |"
                       if len(vals) > 1 else f"| {label} | {name} | 1 | {e[0]:.3g} % | | {cov} / 1 | |")
        pf = np.abs([r["peak_f_err"] for r in rs if "peak_f_err" in r]) * 100
        pd = np.abs([r["peak_d_err"] for r in rs if "peak_d_err" in r]) * 100
        if pf.size:
            out.append(f"| {label} | resonance peak f / d_rms | {pf.size} | "
                       f"{np.median(pf):.3g} % / {np.median(pd):.3g} % "
                       f"| {pf.max():.3g} % / {pd.max():.3g} % | | |")
        seeds = sorted({r["seed"] for r in rs})
        if len(seeds) > 1:        # runs of one seed share their noise under --noise shared: see the spread
            per_seed = []
            for n in NAMES[:4]:
                means = [np.mean([r["params"][n]["z"] for r in rs if r["seed"] == sd and n in r["params"]] or [np.nan])
                         for sd in seeds]
                per_seed.append(f"{n} " + " ".join(f"{m:+.2f}" for m in means))
            noise = sorted({r.get("noise", "shared") for r in rs})
            out.append(f"| {label} | mean z per seed {seeds} (noise: {', '.join(noise)}) | {len(rs)} | "
                       + "; ".join(per_seed) + " | | | |")
        failed = sum(bool(r.get("joint_failed")) for r in rs)
        out.append(f"| {label} | joint refinement failed (the two-stage result is counted) | {len(rs)} | "
                   f"{failed} / {len(rs)} runs | | | |")
        ident = sum(r["curvature_status"] == "identified" for r in rs)
        out.append(f"| {label} | sigma_h''(1) identified | {len(rs)} | {ident} / {len(rs)} runs | | | |")
        t = np.array([r["identify_s"] for r in rs])
        out.append(f"| {label} | identification time | {len(rs)} | {np.median(t):.1f} s | {t.max():.1f} s | | |")
    return out


def _stats(vals: list) -> str:
    e = np.abs([v["rel_err"] for v in vals]) * 100
    z = np.array([v["z"] for v in vals])
    cov = sum(v["covers"] for v in vals)
    share = f"{cov}/{len(vals)} ({100 * cov / len(vals):.0f} %)"
    return f"{np.median(e):.3g} % / {e.max():.3g} % / {share} / {z.mean():+.2f}"


def compare(before: list, after: list) -> list[str]:
    """Side by side on the runs (membrane, set, seed) present in both files: per parameter median / worst
    abs. relative error / 95 % CI covers the truth / mean z."""
    key = {(r["membrane"], r["kind"], r["seed"]): r for r in before}
    pairs = [(key[(r["membrane"], r["kind"], r["seed"])], r) for r in after
             if (r["membrane"], r["kind"], r["seed"]) in key]
    out = ["| data | parameter | runs | before: median / worst / covers / mean z | after: median / worst / covers / "
           "mean z |", "|---|---|---|---|---|"]
    for kind in ("paper", "17"):
        ps = [(b, a) for b, a in pairs if a["kind"] == kind]
        for n in NAMES[:4]:
            both = [(b["params"][n], a["params"][n]) for b, a in ps if n in b["params"] and n in a["params"]]
            if both:
                out.append(f"| {'paper' if kind == 'paper' else '17'} | {n} | {len(both)} | "
                           f"{_stats([b for b, _ in both])} | {_stats([a for _, a in both])} |")
        if ps:
            failed_before = sum(bool(b.get('joint_failed')) for b, _ in ps)
            failed_after = sum(bool(a.get('joint_failed')) for _, a in ps)
            out.append(f"| {kind} | joint refinement failed | {len(ps)} | {failed_before} | {failed_after} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--membranes", type=int, default=20)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--sets", default="paper,17")
    ap.add_argument("--jsonl", default=str(Path(__file__).with_name("results") / "family.jsonl"))
    ap.add_argument("--table-only", action="store_true")
    ap.add_argument("--compare", default="", help="an earlier results file: side by side on the common runs")
    ap.add_argument("--members", default="", help="comma-separated membrane names (default: all)")
    ap.add_argument("--data", default="orbit", choices=("orbit", "held"),
                    help="orbit: synth's records (periodic orbit, step from rest); held: one held-voltage run "
                         "from rest per set, cut by the bag extraction (identify.synth_rig)")
    ap.add_argument("--noise", default="per-membrane", choices=("per-membrane", "shared"),
                    help="per-membrane: each run's noise seed from (member, seed), independent runs; shared: the "
                         "seed itself on every member (sessions 13-18; the runs of a seed are correlated)")
    args = ap.parse_args()
    path = Path(args.jsonl)
    path.parent.mkdir(exist_ok=True)
    done = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    if not args.table_only:
        have = {(r["membrane"], r["kind"], r["seed"]) for r in done}
        only = [m for m in args.members.split(",") if m]      # in the order given
        drawn = {p.name: (p, f_r) for p, f_r in family(args.membranes)}
        members = [(p, f_r, _peak(p, 0.9 * f_r, 1.1 * f_r)) for p, f_r in (
            [drawn[m] for m in only] if only else list(drawn.values()))]
        for seed in range(1, args.seeds + 1):       # seed-major: an interrupted run has every membrane
            for p, f_r, true_peak in members:
                for kind in args.sets.split(","):
                    if (p.name, kind, seed) in have:
                        continue
                    rec = one_run(p, f_r, true_peak, kind, seed, args.data, args.noise)
                    done.append(rec)
                    with path.open("a") as fh:
                        fh.write(json.dumps(rec) + "\n")
                    print(f"{p.name} (creep {rec['creep_s']:.3g} s, f_r {f_r:.2f} Hz) {kind} seed {seed}: "
                          f"{rec['identify_s']:.1f} s, curvature {rec['curvature_status']}, "
                          + ", ".join(f"{n} {v['rel_err'] * 100:+.3f} %" for n, v in rec["params"].items()),
                          file=sys.stderr, flush=True)
    membranes = sorted({r["membrane"] for r in done})
    seeds = sorted({r["seed"] for r in done})
    text = "\n".join([f"Machine: {machine()}; 1 worker, OPENBLAS_NUM_THREADS=1", "",
                      f"{len(membranes)} membranes ({', '.join(membranes)}), seeds {seeds}, {len(done)} runs.", ""]
                     + table(done)) + "\n"
    if args.compare:
        before = [json.loads(line) for line in Path(args.compare).read_text().splitlines()]
        text += "\n" + "\n".join(compare(before, done)) + "\n"
    print(text)


if __name__ == "__main__":
    main()
