"""Run a study: designs -> chunks -> engine -> chunk files -> results file, plots, summary.

:func:`run_study` is the library entry point (``dea-ros study`` calls it). The output folder
holds ``study.json`` (the spec, the base membrane and the fingerprint that resuming checks),
``chunks/`` (one file per finished batch of designs), ``results.parquet`` or ``results.csv``,
``map_*.png`` and ``summary.json`` (counts, timings, engine: what differs between runs is
kept out of the results file). Run it again on the same folder and only the missing chunks
are computed.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from ..errors import StudyInterrupted
from ..model.parameters import MembraneParameters, load_parameters
from .engine import Engine, Progress
from .evaluate import evaluate_chunk, result_columns
from .plots import plot_maps
from .results import parquet_problem, read_chunk, write_chunk, write_results
from .spec import SpecError, StudySpec

__all__ = ["run_study", "study_chunks", "StudyInterrupted"]


def study_chunks(spec: StudySpec) -> list:
    """[(chunk index, [[design index, values], ...]), ...] in design order."""
    designs = spec.designs()
    items = [[i, [float(x) for x in row]] for i, row in enumerate(designs)]
    size = spec.chunk_size
    return [(k, items[s:s + size]) for k, s in enumerate(range(0, len(items), size))]


def _fingerprint(spec: StudySpec, base: MembraneParameters) -> str:
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
    base = base if base is not None else _base_parameters(spec)
    fmt = _results_format(spec)
    fingerprint = _fingerprint(spec, base)
    previous = _check_folder(out, fingerprint, restart)
    _write_study_file(out, spec, base, fingerprint)
    chunks = study_chunks(spec)
    done = {k for k, _items in chunks if read_chunk(out, k) is not None}
    todo = [(k, {"spec": spec.to_dict(), "source": spec.source, "base": base.to_dict(), "designs": items})
            for k, items in chunks if k not in done]
    t_run = time.perf_counter()
    engine_text = _compute_chunks(out, todo, len(chunks), len(done), engine, progress, on_chunk)
    t_compute = time.perf_counter() - t_run
    rows = [row for k, _items in chunks for row in read_chunk(out, k)]
    path = _write_results_file(out, spec, rows, fmt)
    figures = plot_maps(spec, rows, out) if plots else []
    counts = _row_counts(rows)
    summary = {
        "name": spec.name, "results": str(path), "format": fmt, "figures": [str(f) for f in figures],
        "designs": len(rows), "ok": counts["ok"], "failed": counts["failed"], "failures": counts["failures"],
        "chunks": len(chunks), "chunks_resumed": len(done), "chunks_computed": len(todo),
        "previous_chunk_files": previous, "engine": engine_text, "compute_s": t_compute,
        "total_s": time.perf_counter() - t0,
        "designs_per_s": (len(todo) and sum(len(t[1]["designs"]) for t in todo) / t_compute) or float("nan"),
        "with_bands": counts["with_bands"], "with_folds": counts["with_folds"],
    }
    summary.update(_ranges_of_ok_designs(rows))
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    return summary


def _base_parameters(spec: StudySpec) -> MembraneParameters:
    """The spec's base membrane (a preset or a parameters YAML)."""
    try:
        return load_parameters(spec.base)
    except OSError as exc:
        raise SpecError(f"base: {spec.base}: {exc}") from None


def _results_format(spec: StudySpec) -> str:
    """``parquet`` or ``csv``: the spec's ``output.format`` (``auto``: Parquet when pyarrow works)."""
    fmt = spec.output_format
    problem = parquet_problem() if fmt in ("auto", "parquet") else None   # imports pyarrow: once
    if fmt == "auto":
        return "csv" if problem else "parquet"
    if fmt == "parquet" and problem:
        raise SpecError(f"output.format parquet needs a working pyarrow ({problem}): pip install a "
                        "pyarrow that matches this numpy (extra: dea_ros[study]; apt: python3-pyarrow where "
                        "packaged), or use format csv")
    return fmt


def _write_study_file(out: Path, spec: StudySpec, base: MembraneParameters, fingerprint: str) -> None:
    """``OUT/study.json``: the spec, the base membrane and the fingerprint that resuming checks."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "study.json").write_text(json.dumps({"fingerprint": fingerprint, "spec": spec.to_dict(),
                                                "source": spec.source, "base": base.to_dict(),
                                                "n_designs": spec.n_designs, "chunk_size": spec.chunk_size,
                                                "columns": result_columns(spec)}, indent=2, default=str))


def _compute_chunks(out: Path, todo: list, n_chunks: int, n_done: int, engine: Engine | None, progress: bool,
                    on_chunk) -> str:
    """Evaluate the chunks ``todo`` on the engine, writing each chunk file as it finishes.

    Returns the engine's description; raises :class:`StudyInterrupted` when interrupted or when
    chunks failed (the finished ones are kept).
    """
    own_engine = engine is None
    engine = engine or Engine("serial")
    bar = Progress(n_chunks, "chunks", enabled=progress, initial=n_done)
    errors = []
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
        raise StudyInterrupted(f"interrupted; {len(list((out / 'chunks').glob('chunk_*.json')))} of {n_chunks} "
                               f"chunks are kept in {out / 'chunks'}: run the same command again to resume") from None
    finally:
        bar.close()
        if own_engine:
            engine.close()
    if errors:
        raise StudyInterrupted(f"{len(errors)} chunk(s) failed on the engine ({errors[0]}); the others are kept in "
                               f"{out / 'chunks'}: run again to retry them")
    return engine_text


def _write_results_file(out: Path, spec: StudySpec, rows: list, fmt: str) -> Path:
    """``OUT/results.<fmt>`` from the rows in design order (a results file of the other format is removed)."""
    path = out / f"results.{fmt}"
    for other in ("results.parquet", "results.csv"):
        if (out / other).exists() and (out / other) != path:
            (out / other).unlink()
    return write_results(rows, result_columns(spec), path, fmt)


def _row_counts(rows: list) -> dict:
    """Designs ok and failed, failures by reason, designs with bands and with folds."""
    status = [r["status"] for r in rows]
    failures = {}
    for r in rows:
        if r["status"] != "ok":
            failures[r["failure"]] = failures.get(r["failure"], 0) + 1
    return {
        "ok": status.count("ok"), "failed": len(rows) - status.count("ok"), "failures": failures,
        "with_bands": int(sum(1 for r in rows if r["quasi_periodic_width_Hz"] > 0 or r["period_doubled_width_Hz"] > 0)),
        "with_folds": int(sum(1 for r in rows if r["n_folds"] > 0)),
    }


def _ranges_of_ok_designs(rows: list) -> dict:
    """The ranges of the resonance-peak frequency and of the stroke over the designs that succeeded."""
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return {}
    f = np.array([r["peak_frequency_Hz"] for r in ok])
    s = np.array([r["stroke_m"] for r in ok])
    return {"peak_frequency_Hz_range": [float(np.nanmin(f)), float(np.nanmax(f))],
            "stroke_m_range": [float(np.nanmin(s)), float(np.nanmax(s))]}
