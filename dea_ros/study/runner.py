"""Run a study: designs -> chunks -> engine -> chunk files -> results file, plots, summary.

:func:`run_study` is the library entry point (``dea-ros study`` calls it). The output folder
holds ``study.json`` (the spec, the base membrane and the fingerprint that resuming checks),
``chunks/`` (one file per finished batch of designs), ``results.parquet`` or ``results.csv``,
``map_*.png`` and ``summary.json`` (counts, timings, engine: what differs between runs is
kept out of the results file). Run it again on the same folder and only the missing chunks
are computed.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..model.parameters import MembraneParameters, load_parameters
from .engine import Engine, Progress
from .evaluate import evaluate_chunk, result_columns
from .results import parquet_problem, read_chunk, write_chunk, write_results
from .spec import SpecError, StudySpec
from ..errors import StudyInterrupted

__all__ = ["run_study", "study_chunks", "StudyInterrupted"]


def study_chunks(spec: StudySpec) -> list:
    """[(chunk index, [[design index, values], ...]), ...] in design order."""
    designs = spec.designs()
    items = [[i, [float(x) for x in row]] for i, row in enumerate(designs)]
    size = spec.chunk_size
    return [(k, items[s:s + size]) for k, s in enumerate(range(0, len(items), size))]


def _fingerprint(spec: StudySpec, base: MembraneParameters) -> str:
    import hashlib

    text = spec.fingerprint() + json.dumps(base.to_dict(), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _check_folder(out: Path, fingerprint: str, restart: bool) -> int:
    """Prepare ``out``; return how many chunk files a previous run of the same spec left."""
    meta = out / "study.json"
    if out.exists() and not out.is_dir():
        raise SpecError(f"--out {out}: exists and is not a folder")
    if meta.is_file():
        try:
            old = json.loads(meta.read_text()).get("fingerprint")
        except (OSError, ValueError):
            old = None
        if old != fingerprint and not restart:
            raise SpecError(f"--out {out}: holds a study of another spec or base membrane (fingerprint {old}, this "
                            f"one {fingerprint}); give a new --out, or --restart to discard it")
    if restart:
        for p in sorted((out / "chunks").glob("chunk_*.json")) if (out / "chunks").is_dir() else []:
            p.unlink()
    elif (out / "chunks").is_dir() and not meta.is_file():
        raise SpecError(f"--out {out}: has chunk files but no study.json; give a new --out or --restart")
    return len(list((out / "chunks").glob("chunk_*.json"))) if (out / "chunks").is_dir() else 0


def run_study(spec: StudySpec, out_dir, engine: Engine | None = None, progress: bool = True, restart: bool = False,
              plots: bool = True, base: MembraneParameters | None = None, on_chunk=None) -> dict:
    """Run (or resume) ``spec`` into ``out_dir``; return a summary dict (paths, counts, timings).

    ``engine``: an :class:`Engine` (entered here if not yet); default serial. ``on_chunk(k, rows)``
    is called after each chunk file is written (e.g. to stop a test run). Raises
    :class:`StudyInterrupted` (finished chunks kept) on KeyboardInterrupt.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    if base is None:
        try:
            base = load_parameters(spec.base)
        except OSError as exc:
            raise SpecError(f"base: {spec.base}: {exc}") from None
    fmt = spec.output_format
    problem = parquet_problem() if fmt in ("auto", "parquet") else None   # imports pyarrow: once
    if fmt == "auto":
        fmt = "csv" if problem else "parquet"
    elif fmt == "parquet" and problem:
        raise SpecError(f"output.format parquet needs a working pyarrow ({problem}): pip install a "
                        "pyarrow that matches this numpy (extra: dea_ros[study]; apt: python3-pyarrow where "
                        "packaged), or use format csv")
    fingerprint = _fingerprint(spec, base)
    previous = _check_folder(out, fingerprint, restart)
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.json").write_text(json.dumps({"fingerprint": fingerprint, "spec": spec.to_dict(),
                                                "source": spec.source, "base": base.to_dict(),
                                                "n_designs": spec.n_designs, "chunk_size": spec.chunk_size,
                                                "columns": result_columns(spec)}, indent=2, default=str))
    chunks = study_chunks(spec)
    done = {k for k, _items in chunks if read_chunk(out, k) is not None}
    todo = [(k, {"spec": spec.to_dict(), "source": spec.source, "base": base.to_dict(), "designs": items})
            for k, items in chunks if k not in done]
    own_engine = engine is None
    engine = engine or Engine("serial")
    bar = Progress(len(chunks), "chunks", enabled=progress, initial=len(done))
    errors = []
    t_run = time.perf_counter()
    try:
        engine.open()
        engine_text = engine.describe()
        for k, rows, exc in engine.map_unordered(evaluate_chunk, todo):
            if exc is not None:
                errors.append(f"chunk {k}: {type(exc).__name__}: {exc}")
                bar.update(1, "(chunk failed)")
                continue
            write_chunk(out, k, rows)
            bar.update(1)
            if on_chunk is not None:
                on_chunk(k, rows)
    except KeyboardInterrupt:
        raise StudyInterrupted(f"interrupted; {len(list((out / 'chunks').glob('chunk_*.json')))} of {len(chunks)} "
                               f"chunks are kept in {out / 'chunks'}: run the same command again to resume") from None
    finally:
        bar.close()
        if own_engine:
            engine.close()
    t_compute = time.perf_counter() - t_run
    if errors:
        raise StudyInterrupted(f"{len(errors)} chunk(s) failed on the engine ({errors[0]}); the others are kept in "
                               f"{out / 'chunks'}: run again to retry them")
    rows = []
    for k, _items in chunks:
        rows.extend(read_chunk(out, k))
    columns = result_columns(spec)
    path = out / f"results.{fmt}"
    for other in ("results.parquet", "results.csv"):
        if (out / other).exists() and (out / other) != path:
            (out / other).unlink()
    write_results(rows, columns, path, fmt)
    figures = []
    if plots:
        from .plots import plot_maps

        figures = plot_maps(spec, rows, out)
    status = [r["status"] for r in rows]
    failures = {}
    for r in rows:
        if r["status"] != "ok":
            failures[r["failure"]] = failures.get(r["failure"], 0) + 1
    summary = {
        "name": spec.name, "results": str(path), "format": fmt, "figures": [str(f) for f in figures],
        "designs": len(rows), "ok": status.count("ok"), "failed": len(rows) - status.count("ok"),
        "failures": failures, "chunks": len(chunks), "chunks_resumed": len(done),
        "chunks_computed": len(todo), "previous_chunk_files": previous, "engine": engine_text,
        "compute_s": t_compute, "total_s": time.perf_counter() - t0,
        "designs_per_s": (len(todo) and sum(len(t[1]["designs"]) for t in todo) / t_compute) or float("nan"),
        "with_bands": int(sum(1 for r in rows if r["quasi_periodic_width_Hz"] > 0 or r["period_doubled_width_Hz"] > 0)),
        "with_folds": int(sum(1 for r in rows if r["n_folds"] > 0)),
    }
    ok = [r for r in rows if r["status"] == "ok"]
    if ok:
        f = np.array([r["peak_frequency_Hz"] for r in ok])
        s = np.array([r["stroke_m"] for r in ok])
        summary["peak_frequency_Hz_range"] = [float(np.nanmin(f)), float(np.nanmax(f))]
        summary["stroke_m_range"] = [float(np.nanmin(s)), float(np.nanmax(s))]
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary
