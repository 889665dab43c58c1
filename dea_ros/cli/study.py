"""``dea-ros study SPEC.yaml --out DIR``: run or resume a design study (spec: ``docs/study.md``).

Exit codes: 0 done; 2 bad spec or options (the message names the field and the fix, e.g. Dask
missing for ``--scheduler``); 1 chunks failed on the engine (the finished ones are kept: run
again to resume); 130 interrupted (the same: run again to resume).
"""
from __future__ import annotations

import json
import sys

from ..study.engine import ENGINE_KINDS, Engine, EngineError
from ..study.runner import StudyInterrupted, run_study
from ..study.spec import SpecError, load_spec

__all__ = ["register", "cmd_study", "add_engine_args", "engine_from_args"]


def add_engine_args(parser) -> None:
    """``--engine``, ``--workers``, ``--scheduler`` (shared by ``study`` and ``identify``)."""
    parser.add_argument("--engine", choices=ENGINE_KINDS, default="auto",
                        help="where the batches run: auto (default: a local Dask cluster with one worker process "
                             "per core when dask is installed, else local processes), serial, processes, dask")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="local worker processes (default: all cores)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="run on an existing Dask cluster, e.g. tcp://10.0.0.5:8786 (needs dask[distributed])")


def engine_from_args(args):
    """An :class:`~dea_ros.study.engine.Engine` from the options (EngineError with the fix when impossible)."""
    return Engine(args.engine, workers=args.workers, scheduler=args.scheduler)


def cmd_study(args) -> int:
    """``dea-ros study``: run or resume the study; the exit code (module docstring)."""
    try:
        spec = load_spec(args.spec)
        if args.workers is not None and args.workers < 1:
            raise SpecError(f"--workers: a positive number of worker processes is needed, got {args.workers}")
        engine = engine_from_args(args)
    except (SpecError, EngineError) as exc:
        print(f"dea-ros study: error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(f"[study] {spec.name}: {spec.n_designs} designs ({spec.method}) in chunks of {spec.chunk_size}, "
              f"{spec.sweep['points']} frequencies {spec.excitation['f_min_Hz']:g}-{spec.excitation['f_max_Hz']:g} Hz "
              f"per design; engine {args.scheduler or args.engine}", file=sys.stderr, flush=True)
    try:
        with engine:
            summary = run_study(spec, args.out, engine=engine, progress=not args.quiet, restart=args.restart,
                                plots=not args.no_plots)
    except (SpecError, EngineError) as exc:
        print(f"dea-ros study: error: {exc}", file=sys.stderr)
        return 2
    except StudyInterrupted as exc:
        print(f"dea-ros study: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("dea-ros study: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    elif not args.quiet:
        print(f"[study] {summary['designs']} designs: {summary['ok']} ok, {summary['failed']} failed "
              f"{summary['failures'] or ''}; {summary['chunks_computed']} chunks computed, {summary['chunks_resumed']} "
              f"resumed, {summary['compute_s']:.1f} s on {summary['engine']}", file=sys.stderr)
        if "peak_frequency_Hz_range" in summary:
            lo, hi = summary["peak_frequency_Hz_range"]
            s_lo, s_hi = summary["stroke_m_range"]
            print(f"[study] resonance peak {lo:.3f}-{hi:.3f} Hz, stroke {s_lo * 1e6:.1f}-{s_hi * 1e6:.1f} um; "
                  f"{summary['with_folds']} designs with folds, {summary['with_bands']} with torus or "
                  "period-doubled bands", file=sys.stderr)
        print(f"[study] results: {summary['results']}" + "".join(f"\n[study] map: {f}" for f in summary["figures"]),
              file=sys.stderr)
    return 0


def register(subparsers) -> dict:
    """Add the ``study`` subcommand."""
    p = subparsers.add_parser(
        "study", help="design study: many membranes/excitations, each swept by harmonic balance (resumable)",
        description="Grid, Latin hypercube or Sobol sample over membrane, geometry, mass and excitation parameters; "
                    "per design the static stroke, the resonance peak, folds and bands, or the failure reason. "
                    "Writes OUT/results.parquet (or .csv), OUT/map_*.png; run again to resume (docs/study.md).")
    p.add_argument("spec", help="study spec YAML (docs/study.md)")
    p.add_argument("--out", required=True, help="output folder (resumed when it holds the same study)")
    add_engine_args(p)
    p.add_argument("--restart", action="store_true", help="discard finished chunks in --out and start again")
    p.add_argument("--no-plots", action="store_true", help="skip the maps")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_study)
    return {"study": p}
