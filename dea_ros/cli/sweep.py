"""``dea-ros sweep``: the frequency response (eq. 21 RMS) by harmonic balance with continuation
through folds and Floquet stability, as text, JSON or a plot of the realised response."""
from __future__ import annotations

import numpy as np

from ..errors import CliError
from .common import add_membrane_args, check_output_file, finite, load_membrane, matplotlib_pyplot, print_json

__all__ = ["register", "cmd_sweep", "print_sweep_text", "plot_sweep", "MAX_SWEEP_POINTS"]

#: ``sweep --points`` limit: each point is a harmonic-balance solve (and a Floquet analysis).
MAX_SWEEP_POINTS = 5000


def cmd_sweep(args) -> int:
    from ..solvers import SinePeriodic, frequency_sweep, sweep_independent
    from ..solvers.inputs import check_harmonics

    params = load_membrane(args)
    fmin = finite("--fmin", args.fmin, True)
    fmax = finite("--fmax", args.fmax, True)
    if fmax <= fmin:
        raise CliError(f"--fmax ({fmax}) must be larger than --fmin ({fmin})")
    if not 1 <= args.points <= MAX_SWEEP_POINTS:
        raise CliError(f"--points: must be from 1 to {MAX_SWEEP_POINTS} (each point is a harmonic-balance "
                       f"solve), got {args.points}")
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
    from ..solvers.sweep_results import stability_segments

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


def register(sub) -> None:
    """Add ``sweep`` to ``sub`` (from ``add_subparsers()``)."""
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
