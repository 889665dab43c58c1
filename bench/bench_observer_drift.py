"""model_node's drift tracking (issue 23 session 13): the voltage paired a sample late vs at the laser's stamp.

The data: the controller's ordinary operation on the core's simulated rig (bench_drift.py's
``operate_with_health``: setpoints across the range every 1.5 s, the controller on the demo's identified
parameters with tracking and retuning, the plant that membrane after a drift; laser 1 kHz, 1 um noise, ILD1320
quantisation; the amplifier's safety core). Three readers of the same samples, each with
control/health.py's default thresholds (WARN at 2 % gain / static stiffness, 15 % k1, 30 % creep time;
3 s persistence), assessed once per second:

* the controller's path (position_controller_node): AdaptiveModel in the loop (EKF + window fit + retune);
* model_node, a sample late (as merged first in session 13): DriftTracking (EKF + the controller's window fit
  every 2 s, absorbed the same way; the node runs the fit off its callbacks, here synchronously) on
  (measured d, applied voltage) with the controller's ``voltage_delay_samples=1``;
* model_node now: the same with ``voltage_delay_samples=0`` (APPLIED_VOLTAGE_DELAY_SAMPLES).

model_node sees the APPLIED voltage (the amplifier's BatteryState), the controller its command. The node
pairs each laser sample with the output in effect at its stamp (control/voltage_pairing.py), which on the
simulated rig is ``ClosedLoopResult.applied_V`` sample for sample (the amplifier's output at the sample time;
checked in test/control/test_voltage_pairing.py); the command acts one sample later, the applied voltage at once.

Run: python bench/bench_observer_drift.py [--seeds 7 8 9] [--seconds 30] [--quiet-s 600]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
from bench_drift import operate_with_health  # noqa: E402
from machine_info import machine  # noqa: E402

from dea_ros.control import (  # noqa: E402
    APPLIED_VOLTAGE_DELAY_SAMPLES,
    ControllerConfig,
    DriftTracking,
    HealthMonitor,
    SimulatedRig,
    TrackerConfig,
)
from dea_ros.control.health import LABELS  # noqa: E402
from dea_ros.model import config_dir, load_parameters  # noqa: E402

U_MAX = 3150.0


def cases(p):
    """(name, plant, the finding's label that names the drift)."""
    sc = lambda xs, f: tuple(x * f for x in xs)  # noqa: E731
    return [("eps_r -3 %", p.replace(relative_permittivity=p.relative_permittivity * 0.97),
             LABELS["electrostatic_gain"]),
            ("static stiffness +3 %", p.replace(beta_Pa=sc(p.beta_Pa, 1.03), gamma_Pa=sc(p.gamma_Pa, 1.03)),
             LABELS["static_stiffness"]),
            ("k1 +25 %, eta2 x0.5", p.replace(k1_Pa=p.k1_Pa * 1.25, eta2_Pa_s=p.eta2_Pa_s * 0.5),
             LABELS["viscoelastic_stiffness"]),
            ("eta1 x0.3", p.replace(eta1_Pa_s=p.eta1_Pa_s * 0.3), LABELS["creep_time"])]


def replay(ident, res, fits: bool, voltage_delay_samples: int = APPLIED_VOLTAGE_DELAY_SAMPLES):
    """model_node's path on a recorded run: ([(t, message)] of WARN+ reports, final ratios, fit wall times s,
    per-sample wall times ns of what the node's laser callback runs: observe (+ due with fits), the fits'
    extra loop delays s, whether each was informative)."""
    tracking = DriftTracking(ident, TrackerConfig(voltage_delay_samples=voltage_delay_samples))
    mon = HealthMonitor()
    found, cost, per_sample, delays = [], [], [], []
    clock = time.perf_counter_ns
    for j, (t, d, u) in enumerate(zip(res.time_s, res.measured_m, res.applied_V)):
        t = float(t)
        t0 = clock()
        tracking.observe(t, float(d), float(u))
        window = tracking.due(t) if fits else None
        per_sample.append(clock() - t0)
        if window is not None:
            t0 = time.perf_counter()
            plan = tracking.prepare(window)
            tracking.apply(plan, t)
            cost.append(time.perf_counter() - t0)
            if plan.fit is not None:
                delays.append((plan.fit.extra_delay_s, plan.fit.delay_informative))
        if j % 1000 == 0:
            rep = mon.assess(t, tracking.tracker.ratios)
            if rep.level >= 1:
                found.append((t, rep.message))
    return found, tracking.tracker.ratios, cost, per_sample, delays


def _delays(delays):
    """The fits' extra loop delay: median ms, informative share."""
    if not delays:
        return "-"
    return (f"{np.median([d for d, _ in delays]) * 1e3:+.2f} ms, "
            f"{sum(ok for _, ok in delays)}/{len(delays)} informative")


def _cell(found, label):
    """First WARN s (its first finding); the first report naming the drift, s."""
    if not found:
        return "none; none"
    own = [t for t, message in found if label in message]
    return f"{found[0][0]:.0f} ({found[0][1].split(':')[0]}); {f'{own[0]:.0f}' if own else 'none'}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--params", default=str(HERE / "results" / "control_params.yaml"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9])
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--quiet-s", type=float, default=600.0, help="the unchanged plant's run (0: skip)")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    ident = load_parameters(args.params)
    truth = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
    cfg = ControllerConfig(U_MAX, 1e5, loop_delay_s=0.75e-3)
    rig0 = SimulatedRig(truth, U_MAX, latency_s=0.5e-3, amplifier_phase_s=0.75e-3)
    t_start = time.perf_counter()
    lines = [f"Machine: {machine()}", "",
             f"Controller's model and model_node's: `{Path(args.params).name}` (the demo's identified parameters); "
             f"plants: that membrane after the drift; {args.seconds:g} s of ordinary operation per run, seeds "
             f"{', '.join(map(str, args.seeds))}. Per path, on the same samples: first WARN [s] (its first "
             "finding); the first report that names the drift [s]:", "",
             "| plant | seed | controller (AdaptiveModel) | model_node, a sample late | model_node, at the stamp | "
             "tracked gain / static / k1 / creep time: a sample late; at the stamp | fits' extra loop delay "
             "(median; informative): a sample late; at the stamp |",
             "|---|---|---|---|---|---|---|"]
    costs, samples = [], []
    ratio = lambda r: " / ".join(f"{v:.3f}" for v in r.values())  # noqa: E731
    runs = [(name, plant, label, seed, args.seconds) for name, plant, label in cases(ident) for seed in args.seeds]
    if args.quiet_s > 0:
        runs.append((f"unchanged, {args.quiet_s / 60:g} min", ident, None, args.seeds[0] + 1, args.quiet_s))
    for name, plant, label, seed, seconds in runs:
        ctl_found, res = operate_with_health(ident, plant, cfg, rig0, seconds, seed)
        late, r_late, _, _, d_late = replay(ident, res, True, voltage_delay_samples=1)
        now, r_now, cost, per_sample, d_now = replay(ident, res, True)
        costs += cost
        samples += per_sample
        cells = ([_cell(found, label) for found in (ctl_found, late, now)] if label is not None else
                 [f"{len(found)} WARN reports" for found in (ctl_found, late, now)])
        lines.append(f"| {name} | {seed} | " + " | ".join(cells) + f" | {ratio(r_late)}; {ratio(r_now)} | "
                     f"{_delays(d_late)}; {_delays(d_now)} |")
        print(lines[-1], flush=True)
    lines += ["", f"Window fit + absorption (DriftTracking.prepare + apply, synchronous here), per fit (at the stamp): "
              f"median {np.median(costs) * 1e3:.0f} ms, p99 {np.percentile(costs, 99) * 1e3:.0f} ms over {len(costs)} "
              f"fits ({time.perf_counter() - t_start:.0f} s wall for this benchmark). Per laser sample, what the "
              "node's callback runs (DriftTracking.observe + due; p50 / p99 / p99.9, us): "
              + " / ".join(f"{v / 1e3:.0f}" for v in np.percentile(samples, [50, 99, 99.9])) + "."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
