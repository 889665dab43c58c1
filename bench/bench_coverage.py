"""Coverage of the identification's 95 % intervals over noise seeds (issue 10).

Membrane X7, unlike the presets (geometry, mass and every material parameter; see
test/identify/conftest.py), 1 um laser noise, synthetic data by forward integration
(dea_ros.identify.synth: shooting on DOP853 on the realised branch, integration in torus bands),
the default identification (the paper's stage 1, classification, joint refinement):

* "wide": 19 frequencies 0.2-40 Hz across the resonance, with a quasi-periodic (10.19 Hz) and two
  period-doubled (19.5, 20.2 Hz) records, |U sin| waveform, sampled records at 2, 10, 10.19, 19.5 Hz;
* "paper": the paper's four frequencies 0.2, 8.3, 11.2, 40 Hz.

For every parameter: the largest error over the seeds and in how many seeds the 95 % interval
covers the truth; sigma_h''(1): identified or not, and its error when identified; the model's
resonance peak against the true model's (both located on the branch).

The family of membranes of issue 21 (20 membranes unlike the presets, the paper's four and 17
frequencies, quantised laser, random start phases): bench/bench_coverage_family.py.

Run: python bench/bench_coverage.py [--seeds 10] [--first-seed 1] [--kinds wide,paper] [--out coverage.md]
(markdown to stdout and bench/results/<out>). The z column: (value - truth) / std. error over the
seeds, mean (with its standard error) and standard deviation: a real under-coverage shows as a mean
away from 0 (bias) or a std above 1 (intervals too narrow), a chance one does not.
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from machine_info import machine  # noqa: E402

from dea_ros.identify.pipeline import identify  # noqa: E402
from dea_ros.identify.static_fit import EXTENDED_COMBINATION_MATRIX  # noqa: E402
from dea_ros.identify.synth import synthesize_experiments  # noqa: E402
from dea_ros.solvers.inputs import SinePeriodic  # noqa: E402
from dea_ros.solvers.sweep import frequency_sweep  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test" / "identify"))
from conftest import PAPER_FREQUENCIES_HZ, UNLIKE, UNLIKE_FREQUENCIES_HZ, UNLIKE_SERIES_HZ  # noqa: E402

NAMES = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa")
COMBOS = EXTENDED_COMBINATION_MATRIX @ np.r_[UNLIKE.beta_Pa, UNLIKE.gamma_Pa]


def truth(name):
    stress = ("sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa", "sigma_h'''(1)_Pa")
    if name in stress:
        return COMBOS[stress.index(name)]
    return UNLIKE.relative_permittivity if name == "eps_r" else getattr(UNLIKE, name)


def peak(params):
    return frequency_sweep(params, SinePeriodic(2500.0, 1.0), np.linspace(9.0, 11.0, 21), n_harmonics=8,
                           branch_switching=False, realised=False).resonance_peak()


def run(kind: str, seeds) -> list[str]:
    freqs = UNLIKE_FREQUENCIES_HZ if kind == "wide" else PAPER_FREQUENCIES_HZ
    series = UNLIKE_SERIES_HZ if kind == "wide" else (8.3,)
    waveform = "abs_sine" if kind == "wide" else "sine"
    true_peak = peak(UNLIKE)
    errs = {n: [] for n in NAMES}
    zs = {n: [] for n in NAMES}
    cover = {n: 0 for n in NAMES}
    fitted = {n: 0 for n in NAMES}
    curv_ok = []
    peak_err = []
    times = []
    for seed in seeds:
        exp = synthesize_experiments(UNLIKE, 1e-6, seed=seed, sine_frequencies_Hz=freqs,
                                     series_frequencies_Hz=series, waveform=waveform)
        t0 = time.perf_counter()
        res = identify(exp)
        times.append(time.perf_counter() - t0)
        st = res.statistics
        for n in NAMES:
            if n not in st.names:
                continue
            i = st.names.index(n)
            tv = truth(n)
            fitted[n] += 1
            errs[n].append(100 * (st.values[i] / tv - 1))
            zs[n].append((st.values[i] - tv) / st.std_error[i])
            cover[n] += int(st.ci_low[i] <= tv <= st.ci_high[i])
        curv_ok.append(bool(res.curvature_identified))
        pk = peak(res.parameters)
        peak_err.append((100 * (pk["frequency_Hz"] / true_peak["frequency_Hz"] - 1),
                         100 * (pk["d_rms_m"] / true_peak["d_rms_m"] - 1)))
        print(f"[{kind}] seed {seed}: {times[-1]:.1f} s, curvature identified {res.curvature_identified}, "
              + ", ".join(f"{n} {e[-1]:+.3f} %" for n, e in errs.items() if e), file=sys.stderr, flush=True)
    rows = []
    for n in NAMES:
        if not fitted[n]:
            continue
        e = np.abs(errs[n])
        z = np.array(zs[n])
        # (value - truth) / std. error: mean 0 (no bias) and std 1 (intervals of the right width)
        z_text = (f"{z.mean():+.2f} +- {z.std(ddof=1) / np.sqrt(z.size):.2f} / {z.std(ddof=1):.2f}"
                  if z.size > 1 else "-")
        rows.append(f"| {kind} ({len(freqs)} freq.) | {n} | {np.max(e):.3g} % | {np.median(e):.3g} % | "
                    f"{cover[n]} / {fitted[n]} | {z_text} |")
    pf = np.abs([p[0] for p in peak_err])
    pa = np.abs([p[1] for p in peak_err])
    rows.append(f"| {kind} ({len(freqs)} freq.) | resonance peak (f / d_rms) | {pf.max():.3g} % / {pa.max():.3g} % | "
                f"{np.median(pf):.3g} % / {np.median(pa):.3g} % | - | |")
    rows.append(f"| {kind} ({len(freqs)} freq.) | sigma_h''(1) identified (written) | "
                f"{sum(curv_ok)} / {len(curv_ok)} seeds | | - | |")
    rows.append(f"| {kind} ({len(freqs)} freq.) | identification time | {max(times):.1f} s | "
                f"{np.median(times):.1f} s | - | |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--kinds", default="wide,paper")
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--out", default="coverage.md", help="file name in bench/results")
    args = ap.parse_args()
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    out = [f"Machine: {machine()}; OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}", "",
           f"Membrane X7 (unlike the presets), 1 um noise, seeds {seeds[0]}-{seeds[-1]}; errors of the "
           "identified values, coverage of their 95 % intervals.", "",
           "| data | parameter | max abs error | median abs error | 95 % CI covers the truth | "
           "z = (value - truth) / std. error: mean +- its std. error / std |",
           "|---|---|---|---|---|---|"]
    for kind in args.kinds.split(","):
        out += run(kind, seeds)
    text = "\n".join(out) + "\n"
    print(text)
    Path(__file__).with_name("results").mkdir(exist_ok=True)
    (Path(__file__).with_name("results") / args.out).write_text(text)


if __name__ == "__main__":
    main()
