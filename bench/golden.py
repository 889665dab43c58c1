"""Golden outputs of the user's commands, recorded before a structural change and compared after it.

A refactoring that changes no behaviour must leave these unchanged to rounding (issue 24):

* ``dea-ros equilibrium``, ``simulate`` (step and sine) and ``sweep`` (A2, 0.1-20 Hz, N = 8, bands,
  folds and peak) as JSON;
* ``dea-ros synth`` + ``dea-ros identify`` on fixed synthetic sets (A2 and LP1; params.yaml,
  result.json and the numbers of report.md);
* a 200-design study chunk (``config/studies/a2_family.yaml`` with n = 200, serial engine);
* ``bench/bench_control.py`` on the simulated plant (tracking table, one seed, no node timing).

Usage (from the project root, with the package importable, e.g. ``.venv/bin/python``)::

    python bench/golden.py record DIR        # on the commit before the change
    python bench/golden.py compare DIR NEW   # records NEW, then compares numbers with DIR

Numbers are compared with a relative tolerance (``--rtol``, default 1e-6) and an absolute floor
(``--atol``, default 1e-12); text must match exactly apart from numbers, timings and paths.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
#: keys whose values are wall-clock timings, paths or versions: not compared
VOLATILE_KEYS = re.compile(r"(time_s$|compute_s$|total_s$|per_s$|_ms$|_s_wall|elapsed|seconds|wall|timing|"
                           r"duration_wall|path|file|folder|dir$|version|created|date|host|machine|cpu)", re.I)
#: report lines that carry timings or paths: not compared
VOLATILE_LINE = re.compile(r"(took|elapsed|wall|seconds? of CPU|/tmp/|/work/|runs/|\bs per\b|ms per|evaluations in|"
                           r"generated|version|machine|python \d|numpy \d|scipy \d|time:)", re.I)


def run(cmd: list[str], out: Path | None = None, cwd: Path = ROOT) -> str:
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONHASHSEED="0")
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stderr[-3000:]}")
    if out is not None:
        out.write_text(proc.stdout)
    return proc.stdout


def record(folder: Path) -> None:
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    py = sys.executable
    cli = [py, "-m", "dea_ros.cli"]
    run(cli + ["equilibrium", "--membrane", "A2", "--voltage", "0", "1000", "2000", "2500", "3000", "--json"],
        folder / "equilibrium.json")
    run(cli + ["simulate", "--membrane", "A2", "--step", "2200", "--duration", "1", "--json"],
        folder / "simulate_step.json")
    run(cli + ["simulate", "--membrane", "LP1", "--sine", "2000", "--frequency", "7", "--duration", "1",
               "--json"], folder / "simulate_sine.json")
    run(cli + ["sweep", "--membrane", "A2", "--amplitude", "2500", "--fmin", "0.1", "--fmax", "20",
               "--points", "200", "--harmonics", "8", "--json"], folder / "sweep_A2.json")
    run(cli + ["sweep", "--membrane", "LP1", "--amplitude", "2000", "--offset", "500", "--fmin", "1",
               "--fmax", "60", "--points", "120", "--harmonics", "6", "--spacing", "log", "--json"],
        folder / "sweep_LP1_offset.json")
    for name, extra in (("A2", []), ("LP1", ["--frequencies", "0.2,2,8.3,11.2,15,25,40"])):
        data = folder / f"synth_{name}"
        run(cli + ["synth", "--membrane", name, "--noise", "1e-6", "--seed", "3", "--out", str(data), "--quiet"]
            + extra)
        ident = folder / f"identify_{name}"
        run(cli + ["identify", str(data), "--out", str(ident), "--json", "--quiet", "--engine", "serial"],
            folder / f"identify_{name}.json")
        for png in ident.rglob("*.png"):
            png.unlink()
    spec = folder / "study_spec.yaml"
    text = (ROOT / "config/studies/a2_family.yaml").read_text().replace("n: 10000", "n: 200")
    spec.write_text(text)
    run(cli + ["study", str(spec), "--out", str(folder / "study"), "--engine", "serial", "--no-plots", "--quiet",
               "--json"], folder / "study.json")
    run([py, "bench/bench_control.py", "--params", str(folder / "identify_A2" / "params.yaml"), "--seeds", "1",
         "--pid-evals", "20", "--timing-s", "0", "--out", str(folder / "control.md")])
    results = folder / "study"
    for parquet in results.glob("*.parquet"):
        try:
            import pandas as pd
            pd.read_parquet(parquet).to_csv(parquet.with_suffix(".golden.csv"), index=False)
        except ImportError:
            pass
    print(f"recorded {folder}")


#: wall-clock timings inside otherwise compared lines, and rows of a report's timing table
TIMING = re.compile(r"(evaluations(?: in)?,? [\d.]+ m?s\b|\([\d.]+ s\)|^\| [\w (),-]+ \| [\d.]+ \|$)")


def numbers_of(text: str) -> list[float]:
    return [float(x) for x in NUMBER.findall(text)]


def close(a: float, b: float, rtol: float, atol: float) -> bool:
    if math.isnan(a) and math.isnan(b):
        return True
    return math.isclose(a, b, rel_tol=rtol, abs_tol=atol)


def compare_json(a, b, where: str, rtol: float, atol: float, diffs: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if VOLATILE_KEYS.search(str(key)):
                continue
            if key not in a or key not in b:
                diffs.append(f"{where}.{key}: only in {'new' if key in b else 'golden'}")
                continue
            compare_json(a[key], b[key], f"{where}.{key}", rtol, atol, diffs)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diffs.append(f"{where}: length {len(a)} -> {len(b)}")
        for i, (x, y) in enumerate(zip(a, b)):
            compare_json(x, y, f"{where}[{i}]", rtol, atol, diffs)
    elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        if not close(float(a), float(b), rtol, atol):
            diffs.append(f"{where}: {a!r} -> {b!r}")
    elif isinstance(a, str) and isinstance(b, str):
        compare_text(a, b, where, rtol, atol, diffs)
    elif a != b:
        diffs.append(f"{where}: {a!r} -> {b!r}")


def compare_text(a: str, b: str, where: str, rtol: float, atol: float, diffs: list[str]) -> None:
    la, lb = a.splitlines(), b.splitlines()
    if len(la) != len(lb):
        diffs.append(f"{where}: {len(la)} lines -> {len(lb)} lines")
    for i, (x, y) in enumerate(zip(la, lb)):
        if VOLATILE_LINE.search(x) or VOLATILE_LINE.search(y):
            continue
        x, y = TIMING.sub("~", x), TIMING.sub("~", y)
        if NUMBER.sub("#", x) != NUMBER.sub("#", y):
            diffs.append(f"{where}:{i + 1}: {x.strip()[:120]!r} -> {y.strip()[:120]!r}")
            continue
        for u, v in zip(numbers_of(x), numbers_of(y)):
            if not close(u, v, rtol, atol):
                diffs.append(f"{where}:{i + 1}: {u} -> {v} in {x.strip()[:100]!r}")
                break


def compare(golden: Path, new: Path, rtol: float, atol: float) -> int:
    record(new)
    diffs: list[str] = []
    files = sorted(p.relative_to(golden) for p in golden.rglob("*") if p.is_file())
    for rel in files:
        a, b = golden / rel, new / rel
        if not b.exists():
            diffs.append(f"{rel}: missing in the new outputs")
            continue
        if rel.suffix in (".png", ".parquet", ".mcap"):
            continue
        ta, tb = a.read_text(), b.read_text()
        if rel.suffix == ".json":
            try:
                compare_json(json.loads(ta), json.loads(tb), str(rel), rtol, atol, diffs)
                continue
            except json.JSONDecodeError:
                pass
        compare_text(ta, tb, str(rel), rtol, atol, diffs)
    extra = sorted(str(p.relative_to(new)) for p in new.rglob("*") if p.is_file()
                   and not (golden / p.relative_to(new)).exists())
    for rel in extra:
        diffs.append(f"{rel}: only in the new outputs")
    for d in diffs:
        print(d)
    print(f"{len(files)} golden files compared: {len(diffs)} differences (rtol {rtol}, atol {atol})")
    return 1 if diffs else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("folder", type=Path)
    cmp_ = sub.add_parser("compare")
    cmp_.add_argument("golden", type=Path)
    cmp_.add_argument("new", type=Path)
    cmp_.add_argument("--rtol", type=float, default=1e-6)
    cmp_.add_argument("--atol", type=float, default=1e-12)
    args = ap.parse_args()
    if args.command == "record":
        record(args.folder)
        return 0
    return compare(args.golden, args.new, args.rtol, args.atol)


if __name__ == "__main__":
    sys.exit(main())
