"""Benchmark of design studies (issue 12): designs per second, serial and on Dask with 1 and 2 workers.

The study: the A2 geometry family, a Latin hypercube over prestretch (1.10-1.35), thickness (30-40 um),
mass (2-4 g) and amplitude (2.0-2.5 kV); per design the content of a ``dea-ros sweep`` (0.1-20 Hz,
200 frequencies, N = 8, Floquet stability, period-doubled branches, bands and the peak located on
the branch) and the static stroke. Run side by side in one process: in-process serial, a Dask
LocalCluster with 1 worker process, then with 2 (one thread each, OpenBLAS at one thread). The
three result files are compared point by point (they must agree), the scaling efficiency from 1 to 2
workers is t1 / (2 t2), and a 10,000-design study is extrapolated from the 2-worker rate.

Run: python bench/bench_study.py [--designs 24] [--points 200]   (markdown to stdout and
bench/results/study.md)
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from machine_info import machine  # noqa: E402

from dea_ros.study import Engine, dask_available, parse_spec, read_results, run_study  # noqa: E402


def spec(designs: int, points: int, chunk: int):
    return parse_spec({
        "name": "a2_family_bench", "base": "A2",
        "parameters": {"prestretch": {"min": 1.10, "max": 1.35}, "thickness_m": {"min": 3.0e-5, "max": 4.0e-5},
                       "mass_kg": {"min": 0.002, "max": 0.004}, "amplitude_V": {"min": 2000.0, "max": 2500.0}},
        "sampling": {"method": "lhs", "n": designs, "seed": 12},
        "excitation": {"f_min_Hz": 0.1, "f_max_Hz": 20.0},
        "sweep": {"points": points, "harmonics": 8},
        "output": {"chunk_size": chunk, "format": "csv"},
    }, source="bench")


def run(kind: str, workers: int, sp, root: Path) -> dict:
    out = root / f"{kind}_{workers}"
    c0 = time.process_time()
    t0 = time.perf_counter()
    with Engine(kind, workers=workers) as engine:
        t_start = time.perf_counter() - t0
        summary = run_study(sp, out, engine=engine, progress=False, plots=False)
    summary["startup_s"] = t_start
    summary["cpu_s"] = time.process_time() - c0   # this process only (the serial run's work)
    summary["table"] = read_results(summary["results"])
    return summary


def agree(a: dict, b: dict) -> float:
    """Largest relative difference over the numeric columns (band edges are located to ~1e-6)."""
    worst = 0.0
    for name, col in a.items():
        if isinstance(col, list) or col.dtype == bool:
            continue
        x, y = col.astype(float), b[name].astype(float)
        both = np.isfinite(x) & np.isfinite(y)
        if not np.array_equal(np.isfinite(x), np.isfinite(y)):
            return float("inf")
        if np.any(both):
            worst = max(worst, float(np.max(np.abs(x[both] - y[both]) / np.maximum(np.abs(x[both]), 1e-300))))
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--designs", type=int, default=24)
    ap.add_argument("--points", type=int, default=200)
    ap.add_argument("--chunk", type=int, default=2)
    args = ap.parse_args()
    if not dask_available():
        raise SystemExit("bench_study needs dask[distributed] (pip install 'dea_ros[study]')")
    sp = spec(args.designs, args.points, args.chunk)
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        runs = {"serial (in process)": run("serial", 1, sp, root),
                "Dask, 1 worker": run("dask", 1, sp, root),
                "Dask, 2 workers": run("dask", 2, sp, root)}
    load1 = os.getloadavg()
    ref = runs["serial (in process)"]["table"]
    t1 = runs["Dask, 1 worker"]["compute_s"]
    t2 = runs["Dask, 2 workers"]["compute_s"]
    rate2 = args.designs / t2
    lines = [f"Machine: {machine()}; load average {load0[0]:.2f} before, {load1[0]:.2f} after "
             "(the machine is shared: other sessions' jobs run alongside)", "",
             f"Study: {args.designs} designs (LHS over prestretch, thickness, mass, amplitude of the A2 family), "
             f"{args.points}-point sweep 0.1-20 Hz, N = 8, stability, period-doubled branches, bands, exact peak; "
             f"chunks of {args.chunk} designs.", "",
             "| engine | compute [s] | designs/s | s/design | engine start [s] | max rel. diff vs serial | failed |",
             "|---|---|---|---|---|---|---|"]
    for name, s in runs.items():
        diff = agree(ref, s["table"])
        lines.append(f"| {name} | {s['compute_s']:.1f} | {args.designs / s['compute_s']:.3f} | "
                     f"{s['compute_s'] / args.designs:.3f} | {s['startup_s']:.1f} | {diff:.1e} | {s['failed']} |")
    eff = t1 / (2.0 * t2)
    serial = runs["serial (in process)"]
    lines += ["", f"Serial run: CPU {serial['cpu_s']:.1f} s for {serial['compute_s']:.1f} s wall "
              f"({100 * serial['cpu_s'] / serial['compute_s']:.0f} % of a core: the rest went to other processes)."]
    table = runs["serial (in process)"]["table"]
    ok = [r for r in table["status"] if r == "ok"]
    lines += ["", f"Scaling 1 -> 2 workers: speed-up {t1 / t2:.2f}, efficiency {100 * eff:.0f} %.",
              f"Extrapolated 10,000 designs at the 2-worker rate: {10000 / rate2 / 60:.1f} min "
              f"(goal: < 5 min, i.e. {10000 / 300:.1f} designs/s).",
              f"Designs ok: {len(ok)}/{args.designs}; with folds {int(np.sum(table['n_folds'] > 0))}, with torus "
              f"bands {int(np.sum(table['quasi_periodic_width_Hz'] > 0))}, with period-doubled bands "
              f"{int(np.sum(table['period_doubled_width_Hz'] > 0))}."]
    text = "\n".join(lines)
    print(text)
    out = Path(__file__).resolve().parent / "results"
    out.mkdir(exist_ok=True)
    (out / "study.md").write_text(text + "\n")
    (out / "study.json").write_text(json.dumps({"designs": args.designs, "points": args.points, "t1_s": t1,
                                                "t2_s": t2, "efficiency": eff, "load": [load0, load1]}, indent=2))


if __name__ == "__main__":
    main()
