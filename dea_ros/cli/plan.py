"""``dea-ros plan --from params.yaml``: the additional experiments that shrink the widest intervals most
(:mod:`dea_ros.identify.planning`), with the expected 95 % interval widths before and after.

Exit codes: 0 a plan (possibly empty: then it says why); 2 bad input (a params.yaml without the
first fit's Fisher information, a budget or limit that is not a positive number).
"""
from __future__ import annotations

import math

from ..errors import CliError
from .common import check_output_file, finite, print_json, read_input_file

__all__ = ["register", "cmd_plan", "plan_text"]

_SHORT = {"eps_r": "eps_r", "k1_Pa": "k1", "eta1_Pa_s": "eta1", "eta2_Pa_s": "eta2", "sigma_h''(1)_Pa": "sigma_h''(1)"}
_SHOW = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s", "sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa")


def _pct(w: float) -> str:
    return "unbounded" if not math.isfinite(w) else f"+-{w * 100:.3g} %"


def plan_text(plan) -> str:
    """The plan as text: the picks in order with their cost (with the hold before the measurement and the slowest
    time constant it comes from), then the widths before/after."""
    goal = f", first |correlation| eta1/eta2 <= {plan.max_correlation:g}" \
        if plan.max_correlation is not None and plan.max_correlation < 1 else ""
    lines = [f"experiment plan from {plan.source} (criterion {plan.criterion}{goal}, targets "
             f"{', '.join(plan.targets)}): {len(plan.picks)} records, {plan.total_s:.1f} s of the "
             f"{plan.budget_s:g} s budget, chosen among {plan.n_candidates} candidates"]
    for k, p in enumerate(plan.picks, 1):
        r = p.record
        eta = [f"{_SHORT.get(n, n)} {_pct(p.widths_after[n])}" for n in plan.targets if n in p.widths_after]
        lines.append(f"  {k}. {r.label():<36} {r.duration_s:6.1f} s (held {r.settle_s:.1f} s, slowest time "
                     f"constant {r.time_constant_s:.3g} s)  -> {', '.join(eta)}")
    lines.append("expected 95 % interval half-widths (relative; log scale for k1, eta1, eta2):")
    lines.append(f"  {'parameter':<18} {'now':>12} {'after plan':>12}")
    for n in _SHOW:
        if n in plan.widths_before:
            lines.append(f"  {n:<18} {_pct(plan.widths_before[n]):>12} {_pct(plan.widths_after[n]):>12}")
    for pair, before in plan.correlation_before.items():
        lines.append(f"  correlation {pair}: {before:+.2f} -> {plan.correlation_after.get(pair, float('nan')):+.2f}")
    lines += [f"note: {n}" for n in plan.notes]
    lines.append("expected widths assume the first fit's parameters and noise (linearised Fisher information); "
                 "re-run dea-ros identify with the new records to get the realised intervals")
    return "\n".join(lines)


def cmd_plan(args) -> int:
    from ..identify.planning import PlanLimits, first_fit_from_file, plan_experiments, plan_protocol
    from ..identify.protocols import load_protocol

    budget = finite("--budget-s", args.budget_s, True)
    if args.max_records < 1:
        raise CliError(f"--max-records: at least 1, got {args.max_records}")
    check_output_file("--protocol-out", args.protocol_out)
    limits = PlanLimits(max_voltage_V=finite("--max-voltage", args.max_voltage, True),
                        slew_rate_V_per_s=finite("--slew-rate", args.slew_rate, True),
                        min_frequency_Hz=finite("--fmin", args.fmin, True),
                        max_frequency_Hz=finite("--fmax", args.fmax, True),
                        other_masses_kg=tuple(finite("--other-mass", m, True) for m in args.other_mass or ()))
    max_correlation = finite("--max-correlation", args.max_correlation, True)
    if max_correlation > 1:
        raise CliError(f"--max-correlation: a correlation bound in (0, 1] (1: no correlation goal), got "
                       f"{max_correlation:g}")
    first = read_input_file("--from", args.source, first_fit_from_file)
    targets = tuple(args.targets.split(",")) if args.targets else None
    plan = plan_experiments(first, budget, limits, targets=targets, criterion=args.criterion,
                            max_records=args.max_records, max_correlation=max_correlation)
    if args.protocol_out and plan.picks:
        base = read_input_file("--protocol", args.protocol, load_protocol)
        proto = plan_protocol(plan, base, limits)
        proto.write_yaml(args.protocol_out)
    if args.json:
        print_json(plan.to_dict())
    else:
        print(plan_text(plan))
    return 0


def register(sub) -> None:
    p = sub.add_parser("plan", help="the next experiments that shrink the widest intervals most (Fisher information)",
                       description="From a first fit (the params.yaml of dea-ros identify), pick the sine, step and "
                                   "static records within the amplifier limits that shrink the widest 95 %% "
                                   "intervals most per second of experiment time, with the expected widths.")
    p.add_argument("--from", dest="source", required=True, metavar="PARAMS_YAML",
                   help="params.yaml written by dea-ros identify (with its identification section)")
    p.add_argument("--budget-s", type=float, default=60.0, metavar="S", help="experiment time to spend (default 60 s)")
    p.add_argument("--max-records", type=int, default=12, metavar="N", help="at most this many records (default 12)")
    p.add_argument("--max-voltage", type=float, default=2500.0, metavar="V", help="amplifier limit (default 2500 V)")
    p.add_argument("--slew-rate", type=float, default=100000.0, metavar="V_PER_S",
                   help="amplifier slew limit: a sine needs U 2 pi f below it (default 1e5 V/s)")
    p.add_argument("--fmin", type=float, default=0.3, metavar="HZ", help="lowest candidate frequency (default 0.3)")
    p.add_argument("--fmax", type=float, default=40.0, metavar="HZ", help="highest candidate frequency (default 40)")
    p.add_argument("--other-mass", type=float, action="append", metavar="KG",
                   help="a mass the rig has besides the dynamic one (static points there; repeatable)")
    p.add_argument("--targets", metavar="NAMES", help="comma-separated parameters to shrink (default eps_r, k1_Pa, "
                   "eta1_Pa_s, eta2_Pa_s, sigma_h''(1)_Pa)")
    p.add_argument("--criterion", choices=("widths", "A"), default="widths",
                   help="widths: sum of ln widths (default); A: sum of squared widths (the widest dominate)")
    p.add_argument("--max-correlation", type=float, default=0.9, metavar="R",
                   help="first bring the expected eta1/eta2 |correlation| to at most R, then shrink the widths "
                        "(default 0.9; 1: no correlation goal)")
    p.add_argument("--protocol", default="paper", metavar="NAME_OR_YAML",
                   help="the first pass's protocol (mass, membrane) for --protocol-out (default paper)")
    p.add_argument("--protocol-out", metavar="YAML", help="write the picks as a protocol the identifier node runs")
    p.add_argument("--json", action="store_true", help="print the plan as JSON")
    p.set_defaults(func=cmd_plan)
