"""``dea-ros identify BAG`` timed side by side in two checkouts, in the user's environment (issue 22).

Unlike bench_side_by_side.py this bench does NOT set ``OPENBLAS_NUM_THREADS``: it measures the
command as a user (or ``dea-ros rig demo``) runs it, BLAS threading included. The two checkouts
alternate run by run (A, B, B, A, A, B, ...) so that the load of a shared machine hits both alike;
each run is a fresh process with a warm kernel cache (the kernels compiled by
``dea_ros.identify.warmup`` first, untimed). Per run: wall and CPU time (user + system of the
process and its children), the command's own timings (extract, fit, report), the fit's stages
(result.json: dynamic_fit, classification, joint_fit, evaluation) and the load average at the
start. Options as the demo identifies (``--uncertainty-samples 0``; the plots are written).

Usage: python bench/bench_identify_bag.py --base ../old --new . --bag RUN/bag [--runs 3]
[--python PY] (``--python``: the interpreter of both, with ``PYTHONPATH`` set to each checkout;
default: each checkout's .venv).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from machine_info import machine  # noqa: E402

STAGES = ("dynamic_fit", "classification", "joint_fit", "evaluation", "identification_total")
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def identify_once(checkout: Path, python: str | None, bag: Path, out: Path) -> dict:
    """One ``dea-ros identify`` of ``bag`` in ``checkout``: its timings, wall and CPU time, load."""
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    env.update(MPLBACKEND="Agg", PYTHONPATH=str(checkout))
    exe = python or str(checkout / ".venv" / "bin" / "python")
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([exe, "-m", "dea_ros.cli", "identify", str(bag), "--out", str(out), "--json", "--quiet",
                           "--uncertainty-samples", "0"], cwd=checkout, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{checkout}: identify failed:\n{proc.stderr[-2000:]}")
    summary = json.loads(proc.stdout)
    result = json.loads((out / "report" / "result.json").read_text())
    stages = result.get("timings_s") or result.get("timings") or {}
    row = {"wall_s": wall, "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
           "load1": load, **{k: float(v) for k, v in summary["timings_s"].items()}}
    row.update({k: float(stages[k]) for k in STAGES if k in stages})
    return row


def table(rows: dict, names: dict) -> str:
    a, b = list(rows)
    keys = [k for k in rows[a][0] if k != "load1"]
    lines = [f"| measure (median of {len(rows[a])}) | {names[a]} | {names[b]} | ratio new / old |",
             "| --- | ---: | ---: | ---: |"]
    for k in keys:
        ma = statistics.median(r[k] for r in rows[a])
        mb = statistics.median(r[k] for r in rows[b])
        lines.append(f"| {k} | {ma:.1f} s | {mb:.1f} s | {mb / ma:.3f} |")
    loads = [r["load1"] for c in rows for r in rows[c]]
    lines.append(f"\nLoad average (1 min) at the runs' starts: {min(loads):.1f}-{max(loads):.1f}.")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True, help="checkout A (old)")
    ap.add_argument("--new", type=Path, default=HERE.parent, help="checkout B (default: this one)")
    ap.add_argument("--bag", type=Path, required=True)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--python", default=None, help="interpreter for both checkouts (default: each .venv)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the outputs here (params.yaml of every run)")
    args = ap.parse_args()
    a, b = args.base.resolve(), args.new.resolve()
    names = {a: f"old ({a.name})", b: f"new ({b.name})"}
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        for checkout in (a, b):   # compile the kernels of each checkout into its cache, untimed
            subprocess.run([args.python or str(checkout / ".venv" / "bin" / "python"), "-m", "dea_ros.identify.warmup"],
                           cwd=checkout, env={**os.environ, "PYTHONPATH": str(checkout)}, check=True,
                           capture_output=True)
        rows = {a: [], b: []}
        for k in range(args.runs):
            for checkout in ((a, b) if k % 2 == 0 else (b, a)):
                row = identify_once(checkout, args.python, args.bag.resolve(), work / f"run{k}_{checkout.name}")
                rows[checkout].append(row)
                print(names[checkout], json.dumps({key: round(v, 2) for key, v in row.items()}), flush=True)
    print(f"Machine: {machine()}")
    print(table(rows, names))
    return 0


if __name__ == "__main__":
    sys.exit(main())
