"""``dea-ros equilibrium`` and ``dea-ros simulate``: the model's static equilibria (eq. 20) and
forward integration of a step, a sine or a recorded voltage (eqs. 1-12)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import CliError, VoltageRecordError
from .common import add_membrane_args, check_output_file, finite, load_membrane, matplotlib_pyplot, print_json

__all__ = ["register", "cmd_equilibrium", "cmd_simulate", "load_voltage_csv", "MAX_SIMULATE_DURATION_S",
           "MAX_SIMULATE_SAMPLES", "SOLVE_IVP_METHODS"]

#: ``simulate --duration`` limit, s: longer than any protocol (the paper's takes 200 s); every
#: simulated second costs up to a second of CPU near resonance.
MAX_SIMULATE_DURATION_S = 1000.0
#: ``simulate`` output samples (duration x rate) limit: 5 columns of float64 = 80 MB in memory.
MAX_SIMULATE_SAMPLES = 2_000_000
#: ``simulate --method``: scipy's solve_ivp integrators.
SOLVE_IVP_METHODS = ("DOP853", "RK45", "RK23", "Radau", "BDF", "LSODA")


# ------------------------------------------------------------- equilibrium
def cmd_equilibrium(args) -> int:
    from ..model import static_equilibrium

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
    from ..solvers import SampledVoltage, SineVoltage, StepVoltage, simulate

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
    from ..solvers.inputs import check_recorded_voltage

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
    if t.size < 2:
        raise VoltageRecordError(
            f"--input-csv {path}: {t.size} data row(s); a voltage record needs at least two rows (time_s, "
            "voltage_V) spanning a time: one row is an instant, and simulating it would hold that value "
            "for --duration as if it had been recorded")
    return t, u


def register(sub) -> None:
    """Add ``equilibrium`` and ``simulate`` to ``sub`` (from ``add_subparsers()``)."""
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
