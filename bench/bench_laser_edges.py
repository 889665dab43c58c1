"""Issue 20: fabricated laser values that reach a consumer, from corrupted ILD1320 streams.

The true displacement is the A2 model's forward-integrated response to a sine (1500 +- 1200 V at
8-12 Hz, 2 kHz samples); its frames are corrupted (1 % of the bytes dropped, 1 % preceded by a
random byte, 1 % with a bit flipped), decoded by the product's FrameDecoder and judged by the
PlausibilityFilter (test/fakes/stream_fuzz.py). Side by side, on the same corrupted bytes: the
decoder alone, the filter with the old fixed speed limit (0.5 m/s, no acceleration check) and the
filter with the limits derived from the membrane model (hardware/laser/plausibility.py).
A "fabricated jump" is an accepted value off its true value by more than the filter's one-sample
jump allowance; "fabricated" any accepted value off by more than one quantum (0.16 um).

    python bench/bench_laser_edges.py [--seeds 10] [--seconds 10]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from fakes import load_fake  # noqa: E402

from dea_ros.hardware.laser.plausibility import motion_limits  # noqa: E402
from dea_ros.model import preset  # noqa: E402
from dea_ros.solvers.inputs import SineVoltage  # noqa: E402
from dea_ros.solvers.integrate import simulate  # noqa: E402

fuzz_stream = load_fake("stream_fuzz").fuzz_stream


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args(argv)
    params = preset("A2")
    limits = motion_limits(params, params.breakdown_voltage_V())
    configs = {
        "decoder alone": None,
        "fixed 0.5 m/s": dict(max_speed_m_per_s=0.5),
        "model limits": dict(max_speed_m_per_s=limits.max_speed_m_per_s,
                             max_acceleration_m_per_s2=limits.max_acceleration_m_per_s2),
    }
    print(f"model limits (A2 up to {limits.max_voltage_V:.0f} V, margin {limits.margin:g}): "
          f"{limits.max_speed_m_per_s:.3f} m/s, {limits.max_acceleration_m_per_s2:.1f} m/s^2")
    totals = {name: [0] * 6 for name in configs}
    for seed in range(1, args.seeds + 1):
        r = simulate(params, SineVoltage(1200.0, 8.0 + seed % 5, offset_V=1500.0), args.seconds,
                     sample_rate_Hz=2000.0)
        truth = r.displacement_m + 0.004
        for name, kwargs in configs.items():
            no_filter = dict(max_speed_m_per_s=1e3, jump_tolerance_m=1.0, confirm_samples=1)
            res = fuzz_stream(truth, 2000.0, seed, **(kwargs or no_filter))
            t = totals[name]
            t[0] += res.frames
            t[1] += res.accepted
            t[2] += res.fabricated
            t[3] += res.fabricated_jumps
            t[4] = max(t[4], res.max_error_m)
            t[5] += res.flagged
    print("| filter | frames | values reaching a consumer | fabricated (> 1 quantum) | fabricated jumps | "
          "largest error | flagged |")
    print("|---|---|---|---|---|---|---|")
    for name, (frames, accepted, fab, jumps, max_err, flagged) in totals.items():
        jumps_text = "n/a" if name == "decoder alone" else str(jumps)
        print(f"| {name} | {frames} | {accepted} | {fab} | {jumps_text} | {max_err * 1e6:.1f} um | {flagged} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
