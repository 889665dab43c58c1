"""The user's heavy commands timed side by side in two checkouts (e.g. before and after a refactoring).

Each checkout runs with its own venv (``<checkout>/.venv``, as ``scripts/setup_env.sh`` makes it);
the two alternate run by run (A, B, A, B, ...) so that the load of a shared machine hits both alike,
and the report gives the median of each measure and the ratio B / A. Measures (in fresh processes):

* ``solve``: median wall time of one native harmonic-balance solve (A2, N = 8, 40 frequencies,
  warm kernels), and of a batched solve with Floquet multipliers, per solution;
* ``sweep``: ``frequency_sweep`` of A2, 0.1-20 Hz, 200 points, N = 8, with stability (warm);
* ``study``: ``dea-ros study`` of config/studies/a2_family.yaml with n = 200, serial engine (compute_s);
* ``identify``: ``dea-ros identify`` of a fixed A2 synthetic set (identification_total of result.json);
* ``startup``: a fresh process importing the solvers and solving once with a warm kernel cache.

Usage: python bench/bench_side_by_side.py --base ../base --new . [--runs 5] [--out FILE.md]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine_info import machine  # noqa: E402

SOLVE_SCRIPT = r"""
import json, time
import numpy as np
from dea_ros.model import preset
from dea_ros.solvers import SinePeriodic, frequency_sweep, solve_native
import dea_ros.solvers as solvers
a2 = preset("A2")
freqs = np.linspace(0.5, 20, 40)
solve_native(a2, SinePeriodic(2500.0, 5.0), n_harmonics=8)       # warm the kernels
times = []
for f in freqs:
    t0 = time.perf_counter(); solve_native(a2, SinePeriodic(2500.0, float(f)), n_harmonics=8)
    times.append(time.perf_counter() - t0)
batch = getattr(solvers, "solve_native_batch", None)
if batch is None:
    from dea_ros.solvers.harmonic_balance import solve_native_batch as batch
inputs = [SinePeriodic(2500.0, float(f)) for f in freqs]
batch(a2, inputs, n_harmonics=8, stability=True)
t0 = time.perf_counter(); batch(a2, inputs, n_harmonics=8, stability=True); t_batch = time.perf_counter() - t0
frequency_sweep(a2, SinePeriodic(2500.0, 1.0), np.linspace(0.1, 20, 200), n_harmonics=8)
sweeps = []
for _ in range(3):
    t0 = time.perf_counter()
    frequency_sweep(a2, SinePeriodic(2500.0, 1.0), np.linspace(0.1, 20, 200), n_harmonics=8)
    sweeps.append(time.perf_counter() - t0)
print(json.dumps({"solve_us": float(np.median(times)) * 1e6, "batch_floquet_us": t_batch / len(inputs) * 1e6,
                  "sweep_s": float(np.median(sweeps))}))
"""

STARTUP_SCRIPT = r"""
import time
t0 = time.perf_counter()
from dea_ros.model import preset
from dea_ros.solvers import SinePeriodic, solve_native
solve_native(preset("A2"), SinePeriodic(2500.0, 5.0), n_harmonics=8)
print(time.perf_counter() - t0)
"""


def python_of(checkout: Path) -> str:
    return str(checkout / ".venv" / "bin" / "python")


def run(checkout: Path, args: list[str], env: dict | None = None) -> str:
    proc = subprocess.run([python_of(checkout)] + args, cwd=checkout, capture_output=True, text=True,
                          env={**os.environ, "MPLBACKEND": "Agg", "OPENBLAS_NUM_THREADS": "1", **(env or {})})
    if proc.returncode != 0:
        raise SystemExit(f"{checkout}: {' '.join(args[:3])} failed:\n{proc.stderr[-2000:]}")
    return proc.stdout


def measure(checkout: Path, work: Path) -> dict:
    out = json.loads(run(checkout, ["-c", SOLVE_SCRIPT]).strip().splitlines()[-1])
    t0 = time.perf_counter()
    out["startup_s"] = float(run(checkout, ["-c", STARTUP_SCRIPT]).strip().splitlines()[-1])
    study_out = work / f"study_{checkout.name}_{time.monotonic_ns()}"
    summary = json.loads(run(checkout, ["-m", "dea_ros.cli", "study", str(work / "spec.yaml"), "--out", str(study_out),
                                        "--engine", "serial", "--no-plots", "--quiet", "--json"]))
    out["study_s"] = summary["compute_s"]
    ident = work / f"ident_{checkout.name}_{time.monotonic_ns()}"
    run(checkout, ["-m", "dea_ros.cli", "identify", str(work / "synth"), "--out", str(ident), "--json", "--quiet",
                   "--engine", "serial", "--no-plots"])
    result = json.loads((ident / "result.json").read_text())
    timings = result.get("timings_s") or result.get("timings") or {}
    out["identify_s"] = float(timings.get("identification_total", float("nan")))
    out["wall_s"] = time.perf_counter() - t0
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True, help="checkout A (e.g. the commit before the change)")
    ap.add_argument("--new", type=Path, default=HERE.parent, help="checkout B (default: this one)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None, help="write the table (markdown) here as well")
    args = ap.parse_args()
    a, b = args.base.resolve(), args.new.resolve()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        spec = (b / "config/studies/a2_family.yaml").read_text().replace("n: 10000", "n: 200")
        (work / "spec.yaml").write_text(spec)
        run(b, ["-m", "dea_ros.cli", "synth", "--membrane", "A2", "--noise", "1e-6", "--seed", "3", "--out",
                str(work / "synth"), "--quiet"])
        for checkout in (a, b):  # compile and cache the kernels of both before timing
            run(checkout, ["-c", STARTUP_SCRIPT])
        rows = {a: [], b: []}
        for k in range(args.runs):
            for checkout in ((a, b) if k % 2 == 0 else (b, a)):
                rows[checkout].append(measure(checkout, work))
                print(f"run {k + 1} {checkout.name}: {rows[checkout][-1]}", file=sys.stderr, flush=True)
    keys = [("solve_us", "one solve, N = 8 (median of 40 frequencies)", "us"),
            ("batch_floquet_us", "batched solve with Floquet, per solution", "us"),
            ("sweep_s", "200-point sweep with stability (median of 3)", "s"),
            ("startup_s", "fresh process: import + first solve, warm cache", "s"),
            ("study_s", "200-design study, serial (compute_s)", "s"),
            ("identify_s", "identification of an A2 synthetic set (identification_total)", "s")]
    lines = [f"Machine: {machine()}; load before: {os.getloadavg()[0]:.2f}; {args.runs} runs each, alternating.",
             f"A = {a}, B = {b}.", "",
             "| measure | A (median) | B (median) | B / A |", "|---|---|---|---|"]
    for key, label, unit in keys:
        ma = statistics.median(r[key] for r in rows[a])
        mb = statistics.median(r[key] for r in rows[b])
        fmt = "{:.1f}" if unit == "us" else "{:.3f}"
        lines.append(f"| {label} | {fmt.format(ma)} {unit} | {fmt.format(mb)} {unit} | {mb / ma:.3f} |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
