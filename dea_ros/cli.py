"""``dea-ros``: command line on top of the core (no ROS needed).

Subcommands: ``equilibrium``, ``simulate``, ``sweep`` (model and solvers);
``synth``, ``identify`` (identification); ``replay``, ``bag`` (MCAP logs, with
ROS 2); ``rig`` (the whole rig on mock hardware). ``dea-ros CMD --help`` for each.
Every command takes ``--membrane NAME`` (LP1, A1, A2) or ``--params FILE``,
prints readable text by default and JSON with ``--json``. Errors exit with code
2 and a message naming the file, field or option and the fix; no traceback (an
unexpected exception is reported as an internal error with exit code 1, its
traceback only with ``DEA_ROS_DEBUG=1``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import traceback
from pathlib import Path

import numpy as np
from .errors import CliError, DeaRosError

__all__ = ["main", "build_parser"]


#: ``simulate --duration`` limit, s: longer than any protocol (the paper's takes 200 s); every
#: simulated second costs up to a second of CPU near resonance.
MAX_SIMULATE_DURATION_S = 1000.0
#: ``simulate`` output samples (duration x rate) limit: 5 columns of float64 = 80 MB in memory.
MAX_SIMULATE_SAMPLES = 2_000_000
#: ``simulate --method``: scipy's solve_ivp integrators.
SOLVE_IVP_METHODS = ("DOP853", "RK45", "RK23", "Radau", "BDF", "LSODA")
#: ``sweep --points`` limit: each point is a harmonic-balance solve (and a Floquet analysis).
MAX_SWEEP_POINTS = 5000


def read_input_file(option: str, path, loader):
    """``loader(path)`` with the errors of a bad input file turned into a CliError naming it."""
    try:
        return loader(path)
    except RecursionError:
        raise CliError(f"{option} {path}: nested too deeply to be a dea_ros input (a YAML of "
                       "thousands of nested brackets?)") from None
    except UnicodeDecodeError:
        raise CliError(f"{option} {path}: not a text file (binary content); give the YAML/CSV file") from None
    except IsADirectoryError:
        raise CliError(f"{option} {path}: is a directory, a file is needed") from None
    except PermissionError:
        raise CliError(f"{option} {path}: permission denied") from None


def check_output_file(option: str, path) -> None:
    """Fail before the work when an output file cannot be written (missing folder, a directory)."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise CliError(f"{option} {path}: is a directory; give a file name")
    if not p.parent.is_dir():
        raise CliError(f"{option} {path}: folder {p.parent} does not exist; create it first")


# ------------------------------------------------------------------ helpers
def add_membrane_args(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--membrane", metavar="NAME", help="preset membrane: LP1, A1 or A2 (default A2)")
    group.add_argument("--params", metavar="FILE", help="parameters YAML (e.g. an identified params.yaml)")
    parser.add_argument("--mass", type=float, metavar="KG", help="override the mass, kg (e.g. 0.003)")


def load_membrane(args):
    from .model import load_parameters

    option = "--params" if args.params else "--membrane"
    params = read_input_file(option, args.params or args.membrane or "A2", load_parameters)
    if getattr(args, "mass", None) is not None:
        params = params.replace(mass_kg=args.mass)
    return params


def finite(name: str, value: float, positive: bool = False) -> float:
    if value is None or not math.isfinite(value) or (positive and value <= 0):
        raise CliError(f"{name}: must be a {'positive ' if positive else ''}finite number, got {value}")
    return value


def json_default(obj):
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, complex):
        return [obj.real, obj.imag]
    raise TypeError(type(obj).__name__)


def print_json(data) -> None:
    print(json.dumps(data, indent=2, default=json_default, allow_nan=True))


def matplotlib_pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ------------------------------------------------------------- equilibrium
def cmd_equilibrium(args) -> int:
    from .model import static_equilibrium

    params = load_membrane(args)
    voltages = np.asarray(args.voltage, dtype=float)
    for v in voltages:
        finite("--voltage", v)
    eq = static_equilibrium(params, voltages)
    d = np.atleast_1d(eq.displacement_m)
    k = np.atleast_1d(eq.stiffness_N_per_m)
    rows = [
        {"voltage_V": float(u), "displacement_m": float(di), "stiffness_N_per_m": float(ki)}
        for u, di, ki in zip(voltages, d, k)
    ]
    if args.json:
        print_json({"membrane": params.name, "mass_kg": params.mass_kg, "equilibria": rows})
        return 0
    print(f"Static equilibria of membrane {params.name}, mass {params.mass_kg * 1e3:g} g "
          f"(viscoelastic strain relaxed, eq. 20)")
    print(f"{'voltage [V]':>12} {'displacement [um]':>18} {'stiffness [N/m]':>16}")
    for r in rows:
        print(f"{r['voltage_V']:12.1f} {r['displacement_m'] * 1e6:18.3f} {r['stiffness_N_per_m']:16.3f}")
    return 0


# ---------------------------------------------------------------- simulate
def cmd_simulate(args) -> int:
    from .solvers.inputs import SampledVoltage, SineVoltage, StepVoltage
    from .solvers.integrate import simulate

    params = load_membrane(args)
    duration = finite("--duration", args.duration, positive=True)
    rate = finite("--rate", args.rate, positive=True)
    if duration > MAX_SIMULATE_DURATION_S:
        raise CliError(f"--duration: {duration:g} s is beyond the {MAX_SIMULATE_DURATION_S:g} s limit (longer than "
                       "any protocol; a simulated second can cost a second of CPU): simulate in pieces")
    if duration * rate > MAX_SIMULATE_SAMPLES:
        raise CliError(f"--duration x --rate: {duration * rate:.3g} output samples exceed the limit of "
                       f"{MAX_SIMULATE_SAMPLES:.0e} (80 MB of results in memory); lower --rate")
    if args.method not in SOLVE_IVP_METHODS:
        raise CliError(f"--method: {args.method!r} is not a solve_ivp method; choose one of {SOLVE_IVP_METHODS}")
    check_output_file("--out", args.out)
    check_output_file("--plot", args.plot)
    if args.input_csv:
        data = load_voltage_csv(args.input_csv)
        try:
            signal = SampledVoltage(data[0], data[1], hold=args.hold)
        except ValueError as exc:
            raise CliError(f"--input-csv {args.input_csv}: {exc}") from None
        label = f"voltage from {args.input_csv}"
    elif args.sine is not None:
        signal = SineVoltage(finite("--sine", args.sine), finite("--frequency", args.frequency, True),
                             offset_V=finite("--offset", args.offset))
        label = f"sine {args.sine:g} V at {args.frequency:g} Hz, offset {args.offset:g} V"
    else:
        step = 2200.0 if args.step is None else finite("--step", args.step)
        signal = StepVoltage(step, finite("--step-time", args.step_time), initial_V=finite("--initial", args.initial))
        label = f"step {args.initial:g} -> {step:g} V at t = {args.step_time:g} s"
    resp = simulate(params, signal, duration, sample_rate_Hz=rate, method=args.method)
    d = resp.displacement_m
    summary = {
        "membrane": params.name,
        "input": label,
        "method": args.method,
        "samples": int(d.size),
        "initial_displacement_m": float(d[0]),
        "final_displacement_m": float(d[-1]),
        "min_displacement_m": float(d.min()),
        "max_displacement_m": float(d.max()),
        "wall_time_s": resp.wall_time_s,
    }
    if args.out:
        header = "time_s,voltage_V,displacement_m,viscoelastic_strain,velocity_m_per_s"
        np.savetxt(args.out, np.column_stack([resp.time_s, resp.voltage_V, resp.state.T]),
                   delimiter=",", header=header, comments="")
        summary["csv"] = str(args.out)
    if args.plot:
        plt = matplotlib_pyplot()
        fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
        ax1.plot(resp.time_s, resp.voltage_V / 1e3, color="tab:orange")
        ax1.set_ylabel("voltage [kV]")
        ax2.plot(resp.time_s, d * 1e3)
        ax2.set_ylabel("displacement d [mm]")
        ax2.set_xlabel("time [s]")
        ax1.set_title(f"Membrane {params.name}: {label}")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        plt.close(fig)
        summary["plot"] = str(args.plot)
    if args.json:
        print_json(summary)
        return 0
    print(f"Simulated membrane {params.name}: {label}, {duration:g} s at {rate:g} Hz ({args.method})")
    print(f"  displacement: start {d[0] * 1e6:.3f} um, end {d[-1] * 1e6:.3f} um, "
          f"range [{d.min() * 1e6:.3f}, {d.max() * 1e6:.3f}] um")
    print(f"  wall time {resp.wall_time_s:.3f} s")
    for key in ("csv", "plot"):
        if key in summary:
            print(f"  {key}: {summary[key]}")
    return 0


def load_voltage_csv(path: str):
    """``time_s, voltage_V`` columns of a CSV, checked: numbers, volts (not kV), not negative."""
    from .solvers.inputs import check_recorded_voltage

    p = Path(path)
    if not p.is_file():
        raise CliError(f"--input-csv: no such file {path}")
    try:
        data = np.atleast_1d(np.genfromtxt(p, delimiter=",", names=True))  # (ndmin=: numpy >= 1.23 only)
    except Exception as exc:  # noqa: BLE001 - any parse failure (binary, ragged rows, ...)
        raise CliError(f"--input-csv {path}: not a CSV with a header row ({type(exc).__name__}: {exc})") from None
    names = data.dtype.names or ()
    for col in ("time_s", "voltage_V"):
        if col not in names:
            raise CliError(f"--input-csv {path}: needs columns time_s and voltage_V (SI units: s and V), "
                           f"found {list(names)}")
    t, u = np.atleast_1d(np.asarray(data["time_s"], float)), np.atleast_1d(np.asarray(data["voltage_V"], float))
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(u))):
        bad = int(np.nonzero(~(np.isfinite(t) & np.isfinite(u)))[0][0]) + 2
        raise CliError(f"--input-csv {path}: line {bad}: time_s/voltage_V is not a number (or is empty)")
    try:
        check_recorded_voltage(u, f"--input-csv {path}: column voltage_V")
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return t, u


# ------------------------------------------------------------------ sweep
def cmd_sweep(args) -> int:
    from .solvers.continuation import frequency_sweep, sweep_independent
    from .solvers.inputs import SinePeriodic

    params = load_membrane(args)
    fmin = finite("--fmin", args.fmin, True)
    fmax = finite("--fmax", args.fmax, True)
    if fmax <= fmin:
        raise CliError(f"--fmax ({fmax}) must be larger than --fmin ({fmin})")
    if not 1 <= args.points <= MAX_SWEEP_POINTS:
        raise CliError(f"--points: must be from 1 to {MAX_SWEEP_POINTS} (each point is a harmonic-balance "
                       f"solve), got {args.points}")
    from .solvers.inputs import check_harmonics

    try:
        check_harmonics(args.harmonics, "--harmonics")
    except ValueError as exc:
        raise CliError(str(exc)) from None
    check_output_file("--plot", args.plot)
    freqs = (np.geomspace(fmin, fmax, args.points) if args.spacing == "log"
             else np.linspace(fmin, fmax, args.points))
    inp = SinePeriodic(finite("--amplitude", args.amplitude), fmin, offset_V=finite("--offset", args.offset))
    if args.method == "native":
        result = frequency_sweep(params, inp, freqs, n_harmonics=args.harmonics, d0=args.d0,
                                 stability=not args.no_stability)
    else:
        result = sweep_independent(params, inp, freqs, method=args.method, n_harmonics=args.harmonics,
                                   d0=args.d0, stability=not args.no_stability)
    out = result.to_dict()
    out.update({"membrane": params.name, "amplitude_V": args.amplitude, "offset_V": args.offset})
    if args.plot:
        plot_sweep(result, params.name, args)
        out["plot"] = str(args.plot)
    if args.json:
        print_json(out)
        return 0
    print_sweep_text(result, params.name, args, fmin, fmax)
    return 0


def print_sweep_text(result, name: str, args, fmin: float, fmax: float) -> None:
    """The sweep as text: band summary, then the realised response per frequency."""
    print(f"Frequency sweep of membrane {name}: {args.amplitude:g} V sine"
          f"{'' if not args.offset else f' + {args.offset:g} V offset'}, {fmin:g}-{fmax:g} Hz, "
          f"{args.points} frequencies, N = {args.harmonics} harmonics, method {args.method}")
    print(f"d_rms per eq. 21 with d0 = {args.d0}"
          f"{f' ({result.d0_m * 1e6:.3f} um)' if args.d0 == 'static' else ''}")
    if result.bands:
        print("Bands (what a measurement sees; edges at the located bifurcations):")
        for b in result.bands:
            print(f"  {b.describe()}  [{b.start_edge} .. {b.end_edge}]")
    print("Realised response per frequency (kind; a slow upward sweep; T/2 = the orbit with the period of u^2):")
    t2 = {round(p.frequency_Hz, 9): p for p in result.points}
    print(f"{'f [Hz]':>9} {'d_rms [um]':>11} {'kind':>15} {'branch':>11} {'min..max [um]':>19} "
          f"{'T/2 orbit [um]':>15} {'T/2 stability':>28}")
    for r in result.responses:
        p = t2.get(round(r.frequency_Hz, 9))
        env = (f"{r.d_rms_min_m * 1e6:8.2f}..{r.d_rms_max_m * 1e6:<8.2f}"
               if r.d_rms_max_m - r.d_rms_min_m > 1e-3 * max(abs(r.d_rms_m), 1e-12) else "")
        t2_val = f"{p.d_rms_m * 1e6:15.3f}" if p is not None else f"{'-':>15}"
        t2_stab = p.stability if p is not None else "-"
        print(f"{r.frequency_Hz:9.3f} {r.d_rms_m * 1e6:11.3f} {r.kind:>15} {r.branch:>11} {env:>19} "
              f"{t2_val} {t2_stab:>28}")
    for b in result.bifurcations:
        print(f"{b.kind} of the {b.branch} branch at {b.frequency_Hz:.4f} Hz, d_rms {b.d_rms_m * 1e6:.2f} um")
    qp = [r for r in result.responses if r.branch == "integration"]
    if qp:
        w = qp[0].integration or {}
        print(f"quasi-periodic responses: forward integration, mean RMS (eq. 21) over {w.get('window_periods')} "
              f"periods after {w.get('settle_periods')}, min..max = RMS of single periods")
    peak, tip = result.resonance_peak(True), result.resonance_peak(False)
    big = result.largest_response()
    print(f"resonance peak (stable T/2 branch, located on the branch): {peak['frequency_Hz']:.4f} Hz, "
          f"d_rms {peak['d_rms_m'] * 1e6:.2f} um")
    if tip["d_rms_m"] > peak["d_rms_m"]:
        print(f"branch maximum (unstable): {tip['frequency_Hz']:.4f} Hz, d_rms {tip['d_rms_m'] * 1e6:.2f} um")
    if result.responses:
        print(f"largest realised response: {big['frequency_Hz']:.3f} Hz, d_rms {big['d_rms_m'] * 1e6:.2f} um "
              f"({big['kind']}, {big['branch']})")
    ratio = result.max_truncation_ratio
    if ratio > 1e-2:
        print(f"WARNING: the highest harmonic reaches {ratio:.2g} of the dominant one: N = {args.harmonics} "
              "is too small here and parts of this curve may be spurious; raise --harmonics")
    print(f"total wall time {result.wall_time_s:.3f} s")
    if args.plot:
        print(f"plot: {args.plot}")


BAND_COLOURS = {"period-doubled": "tab:orange", "quasi-periodic": "tab:red", "coexisting": "tab:purple"}


def plot_sweep(result, name: str, args) -> None:
    """Realised response (markers), branches (lines: solid stable, dotted unstable), shaded bands."""
    from .solvers.continuation import stability_segments

    plt = matplotlib_pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    for b in result.bands:
        if b.kind in BAND_COLOURS:
            ax.axvspan(b.f_start_Hz, b.f_end_Hz, color=BAND_COLOURS[b.kind], alpha=0.12, lw=0)
            ax.plot([], [], "s", color=BAND_COLOURS[b.kind], alpha=0.3, label=f"band: {b.kind}")
    styles = {"T/2": "tab:blue", "T": "tab:orange"}
    for br in result.branches:
        col = styles.get(br.name, "tab:green")
        (fs, ds), (fu, du) = stability_segments(br, result.bifurcations)
        ax.plot(fs, ds * 1e6, "-", color=col, lw=1.2, label=f"{br.name} branch ({br.kind}), stable")
        ax.plot(fu, du * 1e6, ":", color=col, lw=1.0, label=f"{br.name} branch, unstable")
    if not result.branches:  # independent sweeps: the solved points only
        f = result.frequencies_Hz
        ax.plot(f, result.d_rms_m * 1e6, ".-", color="tab:blue", label="periodic solution")
    if result.responses:
        rf = result.response_frequencies_Hz
        rd = result.realised_d_rms_m * 1e6
        ax.plot(rf, rd, ".", color="k", ms=3, label="realised response")
        qp = [r for r in result.responses if r.branch == "integration"]
        if qp:
            ax.errorbar([r.frequency_Hz for r in qp], [r.d_rms_m * 1e6 for r in qp],
                        yerr=[[(r.d_rms_m - r.d_rms_min_m) * 1e6 for r in qp],
                              [(r.d_rms_max_m - r.d_rms_m) * 1e6 for r in qp]],
                        fmt="o", color="tab:red", ms=4, capsize=3, label="quasi-periodic (mean, min/max)")
    for fold in result.folds:
        ax.plot(fold.frequency_Hz, fold.d_rms_m * 1e6, "o", mfc="none", color="k")
    if result.folds:
        ax.plot([], [], "o", mfc="none", color="k", label="fold")
    ax.set_xlabel("excitation frequency [Hz]")
    ax.set_ylabel("d_rms (eq. 21) [um]")
    ax.set_title(f"Membrane {name}: {args.amplitude:g} V sine, N = {args.harmonics} ({args.method})")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.plot, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dea-ros",
        description="DEA model, harmonic-balance solver and identification (SI units: V, m, s, kg).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("equilibrium", help="static displacement for given voltages (eq. 20)")
    add_membrane_args(p)
    p.add_argument("--voltage", type=float, nargs="+", default=[0.0, 2000.0, 2200.0, 2500.0],
                   metavar="V", help="voltages in V (default: 0 2000 2200 2500)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_equilibrium)

    p = sub.add_parser("simulate", help="forward integration of a step, a sine or a voltage CSV")
    add_membrane_args(p)
    p.add_argument("--step", type=float, metavar="V", help="step to this voltage (default 2200 V)")
    p.add_argument("--initial", type=float, default=0.0, metavar="V", help="voltage before the step")
    p.add_argument("--step-time", type=float, default=0.1, metavar="S", help="time of the step, s")
    p.add_argument("--sine", type=float, metavar="V", help="sine amplitude in V (instead of a step)")
    p.add_argument("--frequency", type=float, default=5.0, metavar="HZ", help="sine frequency")
    p.add_argument("--offset", type=float, default=0.0, metavar="V", help="sine offset")
    p.add_argument("--input-csv", metavar="FILE", help="CSV with columns time_s,voltage_V")
    p.add_argument("--hold", choices=("linear", "zoh"), default="linear", help="interpolation of --input-csv")
    p.add_argument("--duration", type=float, default=3.0, metavar="S", help="simulated time, s")
    p.add_argument("--rate", type=float, default=1000.0, metavar="HZ", help="output sample rate")
    p.add_argument("--method", default="DOP853", help="solve_ivp method (DOP853, RK45, Radau, LSODA)")
    p.add_argument("--out", metavar="CSV", help="write the time series")
    p.add_argument("--plot", metavar="PNG", help="write a plot of u(t) and d(t)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("sweep", help="frequency response by harmonic balance (continuation, stability)")
    add_membrane_args(p)
    p.add_argument("--amplitude", type=float, default=2500.0, metavar="V", help="sine amplitude, V")
    p.add_argument("--offset", type=float, default=0.0, metavar="V", help="sine offset, V")
    p.add_argument("--fmin", type=float, default=0.1, metavar="HZ")
    p.add_argument("--fmax", type=float, default=20.0, metavar="HZ")
    p.add_argument("--points", type=int, default=200, help="number of frequencies")
    p.add_argument("--spacing", choices=("lin", "log"), default="lin")
    p.add_argument("--harmonics", type=int, default=8, metavar="N",
                   help="harmonics of the response frequency (2N+1 collocation points per period)")
    p.add_argument("--method", choices=("native", "mousai", "integration"), default="native")
    p.add_argument("--d0", choices=("static", "mean"), default="static",
                   help="reference of eq. 21: static equilibrium at u=0 (paper) or the mean response")
    p.add_argument("--no-stability", action="store_true", help="skip Floquet multipliers")
    p.add_argument("--plot", metavar="PNG", help="write the frequency response (unstable parts marked)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_sweep)

    for module in ("dea_ros.identify.commands", "dea_ros.study.commands", "dea_ros.bag.commands", "dea_ros.replay",
                   "dea_ros.rig"):
        try:
            mod = __import__(module, fromlist=["register"])
        except ImportError:
            continue
        register = getattr(mod, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (DeaRosError, ValueError) as exc:  # the package's errors and bad values: a message, exit 2
        print(f"dea-ros {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file that cannot be read or written: name it
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"dea-ros {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except RecursionError:
        print(f"dea-ros {args.command}: error: an input file is nested too deeply (a YAML of thousands of "
              "nested brackets?)", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"dea-ros {args.command}: error: out of memory; lower the sizes given (--points, --rate, "
              "--duration, --harmonics)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dea-ros {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - a bug: no traceback for the user unless asked
        if os.environ.get("DEA_ROS_DEBUG"):
            traceback.print_exc()
        print(f"dea-ros {args.command}: internal error ({type(exc).__name__}: {exc}); this is a bug, please "
              "report it with the command line (DEA_ROS_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
