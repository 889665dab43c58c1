"""Command-line front end of the identification: ``synth`` and ``identify`` subcommands.

``register(subparsers)`` adds both to the ``dea-ros`` parser; each sets ``func`` to a handler
``func(args) -> int`` (exit code)::

    dea-ros synth --membrane A1 --noise 1e-6 --out /tmp/a1
    dea-ros identify /tmp/a1 --out /tmp/a1_fit --json

``identify`` also accepts a rosbag2 MCAP bag (dispatched to :mod:`dea_ros.identify.from_bag`,
which writes OUT/params.yaml and OUT/report/), and several inputs (:mod:`dea_ros.identify.many`,
on the study's engine: ``--engine``, ``--workers``, ``--scheduler``).

Exit codes: 0 success; 2 bad data or arguments (the message names the file, column or option
and the fix: unreadable, binary or corrupt inputs, an existing file as ``--out``, out-of-range
options); 1 a fit or solver failure.
"""
from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

from ..bag import BagReader
from ..errors import BagError, CliError, EngineError, ExperimentError, ParameterError
from ..model.parameters import MembraneParameters, load_parameters
from ..solvers.inputs import check_harmonics
from ..study.engine import Progress
from ..identify.bag_experiments import BagTopics
from ..identify.experiments import load_experiment_set
from ..identify.from_bag import identify_bag, is_bag
from ..identify.many import identify_many
from ..identify.pipeline import IdentificationOptions, identify
from ..identify.report import write_report
from ..identify.synth import DEFAULT_SINE_FREQUENCIES_HZ, synthesize
from ..identify.uncertainty import DEFAULT_SAMPLES
from .study import add_engine_args, engine_from_args

__all__ = ["register", "cmd_synth", "cmd_identify", "cmd_identify_many"]


def _progress_printer(stream):
    """A progress callback printing one short line per event."""
    def show(event: dict) -> None:
        stage = event.get("stage", "?")
        if stage == "dynamic":
            msg = (f"[dynamic] evaluation {event['evaluation']:3d}: J = {event['cost']:.6g}  k1 = "
                   f"{event['k1_Pa']:.4g} Pa  eta1 = {event['eta1_Pa_s']:.4g} Pa s  "
                   f"eta2 = {event['eta2_Pa_s']:.4g} Pa s")
        elif stage == "static":
            extra = f" start {event['start']}" if "start" in event else ""
            rms = f", RMS {event['rms_um']:.3g} um" if "rms_um" in event else ""
            msg = (f"[static] {event.get('method')}{extra}: cost {event.get('cost', float('nan')):.6g}{rms} "
                   f"({event.get('evaluations')} evaluations)")
        elif stage == "synth":
            what = event.get("what")
            msg = f"[synth] {what}" + \
                (f" {event['frequency_Hz']:g} Hz: RMS {event['rms_um']:.4g} um" if what == "sine" else "")
        else:
            msg = str(event)
        print(msg, file=stream, flush=True)

    return show


def _error(command: str, exc) -> int:
    print(f"dea-ros {command}: error: {exc}", file=sys.stderr)
    return 2


def _input_problem(option: str, path, exc: BaseException) -> str | None:
    """A message naming the input for errors a malformed file raises from deep inside a loader."""
    if isinstance(exc, RecursionError):
        return f"{option} {path}: a YAML file nested too deeply (thousands of nested brackets?)"
    if isinstance(exc, UnicodeDecodeError):
        bad = _binary_files(Path(path))
        return f"{option} {path}: {', '.join(map(str, bad)) or 'a file'} is not text (binary content)"
    if isinstance(exc, OSError):
        return f"{option} {getattr(exc, 'filename', None) or path}: {exc.strerror or exc}"
    return None


def _binary_files(path: Path) -> list:
    """The files at ``path`` (a file or the files of a folder) that are not UTF-8 text."""
    files = [path] if path.is_file() else sorted(p for p in path.glob("*") if p.is_file()) if path.is_dir() else []
    bad = []
    for file in files[:200]:
        try:
            file.read_bytes().decode("utf-8")
        except UnicodeDecodeError:
            bad.append(file)
        except OSError:
            pass
    return bad


def _check_out_dir(path) -> None:
    """``--out`` must be a folder (new or existing), not a file: checked before any work."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise CliError(f"--out {path}: exists and is not a folder; give a new or existing folder")
    parent = out if out.exists() else next((p for p in out.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise CliError(f"--out {path}: {parent} is not a folder")


def _check_harmonics(value) -> None:
    try:
        check_harmonics(value, "--harmonics")
    except ValueError as exc:
        raise CliError(str(exc)) from None


def _check_membrane(name_or_path) -> None:
    """``--membrane``: a preset or a parameters YAML that loads (plausibility included), before any work."""
    try:
        load_parameters(name_or_path)
    except (RecursionError, UnicodeDecodeError, OSError) as exc:
        raise CliError(_input_problem("--membrane", name_or_path, exc)) from None
    except ValueError as exc:  # ParameterError and the plausibility checks
        raise CliError(f"--membrane {name_or_path}: {exc}") from None


def _parse_floats(option: str, text: str) -> list:
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise CliError(f"{option}: comma-separated numbers in Hz expected, got {text!r}") from None
    if not all(v > 0 and v < float("inf") for v in values):
        raise CliError(f"{option}: frequencies must be positive and finite, got {text!r}")
    return values


def cmd_synth(args) -> int:
    """``dea-ros synth``: write a synthetic experiment set."""
    try:
        _check_out_dir(args.out)
        try:
            if args.params:
                params = MembraneParameters.from_yaml(args.params)
            else:
                params = load_parameters(args.membrane)
        except (RecursionError, UnicodeDecodeError, OSError) as exc:
            raise CliError(_input_problem("--params" if args.params else "--membrane",
                                          args.params or args.membrane, exc)) from None
        freqs = DEFAULT_SINE_FREQUENCIES_HZ
        if args.frequencies:
            freqs = tuple(_parse_floats("--frequencies", args.frequencies))
        progress = None if args.quiet else _progress_printer(sys.stderr)
        t0 = time.perf_counter()
        exp = synthesize(params, float(args.noise), args.out, seed=int(args.seed), sine_frequencies_Hz=freqs,
                         progress=progress)
    except (CliError, ParameterError, ValueError) as exc:
        return _error("synth", exc)
    except OSError as exc:
        return _error("synth", f"--out {getattr(exc, 'filename', None) or args.out}: {exc.strerror or exc}")
    if not args.quiet:
        print(f"wrote {args.out}/manifest.yaml ({exp.summary()}) in {time.perf_counter() - t0:.1f} s",
              file=sys.stderr)
    return 0


def _checked_options(args):
    """Check the options of ``identify`` shared by one and many inputs (raises CliError naming the
    option); returns the fit frequencies (None, "all" or a list of Hz)."""
    _check_out_dir(args.out)
    _check_harmonics(args.harmonics)
    _check_samples(args)
    if args.membrane:
        _check_membrane(args.membrane)
    if not args.fit_frequencies:
        return None
    return "all" if args.fit_frequencies == "all" else _parse_floats("--fit-frequencies", args.fit_frequencies)


def cmd_identify(args) -> int:
    """``dea-ros identify``: fit all parameters of an experiment folder, write params and report."""
    stream = sys.stderr
    progress = None if args.quiet else _progress_printer(stream)
    t0 = time.perf_counter()
    if isinstance(args.data, list):
        if len(args.data) > 1:
            return cmd_identify_many(args)
        args.data = args.data[0]
    try:
        fit_freqs = _checked_options(args)
    except CliError as exc:
        return _error("identify", exc)
    data_path = Path(args.data)
    if not (data_path / "manifest.yaml").is_file() and not data_path.name.endswith((".yaml", ".yml")):
        bag_rc = _identify_bag_if_bag(args, data_path, progress, fit_freqs, t0)
        if bag_rc is not None:
            return bag_rc
    try:
        experiments = load_experiment_set(args.data)
    except (ExperimentError, ParameterError) as exc:
        return _error("identify", exc)
    except (RecursionError, UnicodeDecodeError, OSError) as exc:
        return _error("identify", _input_problem("DATA", args.data, exc))
    except ValueError as exc:  # a malformed value the loader did not name
        return _error("identify", f"DATA {args.data}: {exc}")
    try:
        t_load = time.perf_counter() - t0
        if not args.quiet:
            print(f"[data] {experiments.summary()} ({t_load:.2f} s)", file=stream, flush=True)
        result = identify(experiments, IdentificationOptions(**_identify_options(args, fit_freqs)), progress=progress)
        result.timings_s = {"load": t_load, **result.timings_s}
    except (ExperimentError, ParameterError) as exc:
        return _error("identify", exc)
    except (RuntimeError, ArithmeticError, ValueError) as exc:
        print(f"dea-ros identify: the fit failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    try:
        paths = write_report(result, args.out, plots=not args.no_plots)
    except OSError as exc:
        return _error("identify", f"--out {getattr(exc, 'filename', None) or args.out}: cannot write the "
                                  f"report ({exc.strerror or exc})")
    total = time.perf_counter() - t0
    if args.json:
        data = result.to_dict()
        data["timings_s"]["report"] = paths["report_s"]
        data["timings_s"]["total"] = total
        data["outputs"] = {k: str(v) for k, v in paths.items() if k != "report_s"}
        print(json.dumps(data, indent=2))
    if not args.quiet:
        for w in result.warnings:
            print(f"warning: {w}", file=stream)
        p = result.parameters
        print(f"[done] eps_r = {p.relative_permittivity:.4g}, k1 = {p.k1_Pa:.4g} Pa, eta1 = {p.eta1_Pa_s:.4g} Pa s, "
              f"eta2 = {p.eta2_Pa_s:.4g} Pa s; wrote {Path(args.out) / 'params.yaml'} and report.md "
              f"in {total:.2f} s", file=stream)
    return 0


def _identify_options(args, fit_freqs) -> dict:
    return dict(static_method=args.static_method, frequency_method=args.frequency_method,
                dynamic_method=args.dynamic_method, fit_frequencies_Hz=fit_freqs, n_harmonics=args.harmonics,
                weights=args.weights, fit_curvature={"auto": "auto", "yes": True, "no": False}[args.fit_curvature],
                refine=getattr(args, "refine", "joint"),
                uncertainty_samples=getattr(args, "uncertainty_samples", 0))


#: ``--uncertainty-samples`` limit: each sample is a batched solve and a short continuation sweep.
MAX_UNCERTAINTY_SAMPLES = 10000


def _check_samples(args) -> None:
    n = getattr(args, "uncertainty_samples", 0)
    if n != 0 and not 2 <= n <= MAX_UNCERTAINTY_SAMPLES:
        raise CliError(f"--uncertainty-samples: 0 (no band) or 2 to {MAX_UNCERTAINTY_SAMPLES} Monte Carlo "
                       f"samples, got {n}")


def _check_input(data) -> None:
    """An experiment folder (manifest.yaml), a manifest YAML or a bag; else a usage error naming it."""
    p = Path(data)
    if not p.exists():
        raise CliError(f"DATA {data}: no such file or folder")
    if (p / "manifest.yaml").is_file() or (p.is_file() and p.name.endswith((".yaml", ".yml"))) or is_bag(p):
        return
    raise CliError(f"DATA {data}: neither an experiment folder (with manifest.yaml) nor a rosbag2 MCAP bag")


def cmd_identify_many(args) -> int:
    """``dea-ros identify IN1 IN2 ... --out OUT``: every input in parallel, a summary table and the spread
    (:mod:`dea_ros.identify.many`). Exit 0 all identified; 2 an input is unreadable or not identifiable
    data (named in the summary); 1 a fit failed."""
    try:
        fit_freqs = _checked_options(args)
        for d in args.data:   # before any engine starts: each input must look like one
            _check_input(d)
        if args.workers is not None and args.workers < 1:
            raise CliError(f"--workers: a positive number of worker processes is needed, got {args.workers}")
        engine = engine_from_args(args)
    except (CliError, EngineError) as exc:
        return _error("identify", exc)
    options = _identify_options(args, fit_freqs)
    with engine:
        if not args.quiet:
            print(f"[identify] {len(args.data)} inputs on {engine.describe()}", file=sys.stderr, flush=True)
        bar = Progress(len(args.data), "inputs", enabled=not args.quiet)
        try:
            summary = identify_many(args.data, args.out, engine=engine, membrane=args.membrane,
                                    segments_file=args.segments, plots=not args.no_plots,
                                    progress=lambda name: bar.update(1, name), **options)
        finally:
            bar.close()
    rows = summary["rows"]
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    elif not args.quiet:
        for r in rows:
            if r["status"] == "ok":
                print(f"[{r['name']}] eps_r {r['eps_r']:.4g}, k1 {r['k1_Pa']:.4g} Pa, eta1 {r['eta1_Pa_s']:.4g} Pa s, "
                      f"eta2 {r['eta2_Pa_s']:.4g} Pa s, peak {r['peak_frequency_Hz']:.4f} Hz, "
                      f"{r['n_warnings']} warning(s)", file=sys.stderr)
            else:
                print(f"[{r['name']}] {r['status']}: {r['error']}", file=sys.stderr)
        n_ok = sum(r["status"] == "ok" for r in rows)
        print(f"[done] {n_ok}/{len(rows)} identified in {summary['wall_time_s']:.1f} s; "
              f"wrote {summary['summary_md']}, {summary['summary_csv']}"
              + (f", {summary['spread']}" if summary["spread"] else ""), file=sys.stderr)
    if any(r["status"] == "bad input" for r in rows):
        return 2
    return 1 if any(r["status"] != "ok" for r in rows) else 0


def _identify_bag_if_bag(args, path: Path, progress, fit_freqs, t0) -> int | None:
    """``dea-ros identify BAG``: a rosbag2 MCAP recording instead of an experiment folder
    (via :mod:`dea_ros.identify.from_bag`). None when ``path`` is not a bag."""
    if not is_bag(path):
        return None
    say = None if args.quiet else (lambda msg: print(f"[bag] {msg}", file=sys.stderr, flush=True))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # listed in the corruption report below if it matters
            with BagReader(path) as bag:
                corruption = bag.verify(decode=False)  # CRCs, indexes, summary; decoding is checked when read
        if corruption:
            raise BagError(f"bag {path} is corrupt: {corruption[0]}"
                           + (f" (and {len(corruption) - 1} more problems)" if len(corruption) > 1 else "")
                           + f"; 'dea-ros bag info {path}' lists them, 'dea-ros bag recover --salvage' keeps "
                             "the readable records")
        topics = BagTopics(voltage=args.voltage_topic, displacement=args.displacement_topic)
        summary = identify_bag(path, args.out, membrane=args.membrane, progress=say, plots=not args.no_plots,
                               topics=topics, segments_file=args.segments,
                               **_identify_options(args, fit_freqs))
    except (ExperimentError, ParameterError, BagError) as exc:
        return _error("identify", exc)
    except (RecursionError, UnicodeDecodeError) as exc:
        return _error("identify", _input_problem("--segments/--membrane", args.segments or args.membrane, exc))
    except OSError as exc:
        return _error("identify", f"{getattr(exc, 'filename', None) or path}: {exc.strerror or exc}")
    except (RuntimeError, ArithmeticError, ValueError) as exc:
        print(f"dea-ros identify: the fit failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    summary.setdefault("timings_s", {})["total"] = time.perf_counter() - t0
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    if not args.quiet:
        for w in summary.get("warnings", []):
            print(f"warning: {w}", file=sys.stderr)
        print(f"[done] wrote {summary.get('params_file')} and {summary.get('report_file')}", file=sys.stderr)
    return 0


def register(subparsers) -> dict:
    """Add the ``synth`` and ``identify`` subcommands to ``subparsers`` (from ``add_subparsers()``).

    Each parser gets ``func`` = its handler; call ``args.func(args)`` for the exit code.
    """
    synth = subparsers.add_parser(
        "synth", help="write a synthetic experiment set (static, step, sines) with laser noise",
        description="Simulate the paper's protocol for a parameter set and write an experiment folder "
                    "(manifest.yaml + CSV, SI units) with Gaussian laser noise; truth.yaml holds the parameters.")
    src = synth.add_mutually_exclusive_group(required=True)
    src.add_argument("--membrane", help="preset membrane name (LP1, A1, A2)")
    src.add_argument("--params", help="parameters YAML file")
    synth.add_argument("--noise", required=True, type=float, metavar="SIGMA_M",
                       help="laser noise standard deviation in metres (1 um -> 1e-6)")
    synth.add_argument("--out", required=True, help="output folder")
    synth.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    synth.add_argument("--frequencies", default=None,
                       help="comma-separated sine frequencies in Hz (default 0.2-40 Hz, 26 values)")
    synth.add_argument("--quiet", action="store_true", help="no progress output")
    synth.set_defaults(func=cmd_synth)

    ident = subparsers.add_parser(
        "identify", help="fit the model parameters to an experiment folder and write a report",
        description="Static fit (eqs. 19-20), then dynamic fit (eqs. 22-24) accelerated by harmonic balance; "
                    "writes OUT/params.yaml, OUT/report.md, figures and result.json.")
    ident.add_argument("data", nargs="+",
                       help="experiment folder with manifest.yaml (or a rosbag2 MCAP bag recorded by identifier_node, "
                            "via dea_ros.identify.from_bag); several: each into OUT/<name>/ in parallel, with "
                            "OUT/summary.md, summary.csv and spread.png")
    ident.add_argument("--membrane", default=None,
                       help="bags only: preset name or parameters YAML for the geometry (default: the bag's)")
    ident.add_argument("--out", required=True, help="output folder for params.yaml and the report")
    ident.add_argument("--json", action="store_true", help="print parameters, metrics and timings as JSON")
    ident.add_argument("--quiet", action="store_true", help="no progress output or warnings on stderr")
    ident.add_argument("--static-method", choices=("lsq", "paper"), default="lsq",
                       help="lsq: bounded least squares on identifiable combinations (default); "
                            "paper: Nelder-Mead on eq. 19")
    ident.add_argument("--frequency-method", choices=("hbm", "integration"), default="hbm",
                       help="frequency response in the dynamic fit: harmonic balance (default) or forward "
                            "integration to steady state (slow; for comparison)")
    ident.add_argument("--dynamic-method", choices=("lsq", "paper"), default="lsq",
                       help="lsq: least squares with exact sensitivities (default); paper: Nelder-Mead")
    ident.add_argument("--harmonics", type=int, default=8, help="harmonic-balance harmonics (default 8)")
    ident.add_argument("--fit-frequencies", default=None,
                       help="comma-separated Hz, or 'all' (default: the paper's 0.2, 8.3, 11.2, 40 Hz in the data)")
    ident.add_argument("--weights", choices=("paper", "noise"), default="paper",
                       help="weights of the paper's dynamic fit (stage 1): paper: eq. 22 with w_step = 6.6e6, "
                            "w_hbm = 0.1e6 (default); noise: 1/sigma^2 (laser noise, d_rms_std_m column)")
    ident.add_argument("--fit-curvature", choices=("auto", "yes", "no"), default="auto",
                       help="identify sigma_h''(1): auto (default) in the joint refinement when there are sine "
                            "records, written only when the data determine it; yes: also in stage 1; no: never")
    ident.add_argument("--refine", choices=("joint", "none"), default="joint",
                       help="joint (default): refine all identifiable parameters together with statistical weights "
                            "on every classified sine record (honest 95 %% intervals); none: the paper's two stages")
    ident.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    ident.add_argument("--uncertainty-samples", type=int, default=DEFAULT_SAMPLES, metavar="N",
                       help=f"Monte Carlo samples of the fit's covariance for the 95 %% band of the frequency "
                            f"response and the resonance peak in the report (default {DEFAULT_SAMPLES}; 0: none)")
    add_engine_args(ident)
    ident.add_argument("--voltage-topic", default="/dea/voltage",
                       help="bags: applied-voltage topic (BatteryState or Float64; default /dea/voltage)")
    ident.add_argument("--displacement-topic", default="/dea/displacement",
                       help="bags: displacement topic (Range or Float64; default /dea/displacement)")
    ident.add_argument("--segments", default=None, metavar="YAML",
                       help="bags not recorded by identifier_node: the experiments' time windows "
                            "(format in dea_ros.identify.bag_experiments)")
    ident.set_defaults(func=cmd_identify)
    return {"synth": synth, "identify": ident}
