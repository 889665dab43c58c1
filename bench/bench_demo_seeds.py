"""The main job's identification quality over noise seeds, without the ROS rig (issue 22's "eps_r, k1, eta1,
eta2 within 1 % of the mock's truth"): a protocol (default: the demo's 'paper') run on the mock membrane
(``config/rig/mock_membrane.yaml``) through the rig-synthesis chain -- converged forward integration of the held
voltage at 500 Hz from rest, random start phases, 1 um laser noise, the ILD1320 quantisation, the bag
extraction (``identify.synth_rig``) -- and identified as ``dea-ros identify`` identifies a one-mass bag
(``stress_terms=1``, the slope fitted in the joint refinement). One noise seed per run; per parameter the
median and worst error, how many runs are more than 1 % off, the median 95 % half-width, coverage, mean z.

Run: python bench/bench_demo_seeds.py [--protocols paper,/path/other.yaml] [--seeds 32]
[--jsonl bench/results/demo_seeds.jsonl] (appends one JSON line per run; --table-only tabulates).
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from machine_info import machine  # noqa: E402

from dea_ros.identify.pipeline import identify  # noqa: E402
from dea_ros.identify.protocols import load_protocol  # noqa: E402
from dea_ros.identify.synth_rig import RecordedPass, passes_experiments, record_protocol  # noqa: E402
from dea_ros.model import load_parameters  # noqa: E402
from dea_ros.model.parameters import config_dir  # noqa: E402
from dea_ros.sim.plant import LASER_QUANTISATION_M  # noqa: E402

NAMES = ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
RATE_HZ = 500.0      # the demo's laser


def one_run(protocol_name: str, seed: int) -> dict:
    truth = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
    values = {"eps_r": truth.relative_permittivity, "k1_Pa": truth.k1_Pa, "eta1_Pa_s": truth.eta1_Pa_s,
              "eta2_Pa_s": truth.eta2_Pa_s}
    proto = load_protocol(protocol_name)
    rec = record_protocol(truth, proto, seed, 1e-6, LASER_QUANTISATION_M, RATE_HZ, True)
    exp = passes_experiments(truth, [RecordedPass(proto, rec)], seed, 1e-6, LASER_QUANTISATION_M, RATE_HZ)
    res = identify(exp, evaluate_fit=False, stress_terms=1, joint_slope=True)
    st = res.statistics
    out = {"protocol": protocol_name, "seed": seed, "experiment_s": proto.duration_s(),
           "shape_outcome": res.shape_test.outcome if res.shape_test is not None else None}
    for n, v in values.items():
        i = st.names.index(n)
        out[n] = {"rel_err": float(st.values[i] / v - 1), "z": float((st.values[i] - v) / st.std_error[i]),
                  "rel_width": float((st.ci_high[i] - st.ci_low[i]) / 2 / abs(st.values[i]))}
    return out


def table(records: list) -> str:
    out = [f"Machine: {machine()}; OPENBLAS_NUM_THREADS=1", ""]
    for name in dict.fromkeys(r["protocol"] for r in records):
        rejected = sum(r.get("shape_outcome") not in (None, "held") for r in records if r["protocol"] == name)
        out.append(f"{name}: the held Ogden shape rejected (held_shape_test) in {rejected} runs")
    out += ["", "| protocol (experiment s) | runs | parameter | error median / worst | runs > 1 % off | 95 % "
            "half-width (median) | covers | mean z |", "|---|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r["protocol"] for r in records):
        rs = [r for r in records if r["protocol"] == name]
        for n in NAMES:
            e = np.abs([r[n]["rel_err"] for r in rs]) * 100
            z = np.array([r[n]["z"] for r in rs])
            w = np.array([r[n]["rel_width"] for r in rs]) * 100
            out.append(f"| {name} ({rs[0]['experiment_s']:.0f}) | {len(rs)} | {n} | {np.median(e):.3g} / "
                       f"{e.max():.3g} % | {int((e > 1).sum())} | {np.median(w):.3g} % | "
                       f"{int((np.abs(z) < 1.96).sum())}/{len(rs)} | {z.mean():+.2f} |")
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--protocols", default="paper")
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--jsonl", default=str(Path(__file__).with_name("results") / "demo_seeds.jsonl"))
    ap.add_argument("--table-only", action="store_true")
    args = ap.parse_args()
    path = Path(args.jsonl)
    done = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    have = {(r["protocol"], r["seed"]) for r in done}
    for name in ([] if args.table_only else args.protocols.split(",")):
        for seed in range(1, args.seeds + 1):
            if (name, seed) not in have:
                rec = one_run(name, seed)
                done.append(rec)
                with path.open("a") as fh:
                    fh.write(json.dumps(rec) + "\n")
    print(table(done))


if __name__ == "__main__":
    main()
