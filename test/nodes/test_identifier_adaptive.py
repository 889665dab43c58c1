"""The adaptive second pass on the demo's rig (issue 21, item 3).

mock_hardware_node (the mock membrane, 1 um laser noise), amplifier_node and identifier_node, each in its own
process as ``ros2 run`` starts them, in simulated time with the lockstep and batched commands of
``dea-ros rig demo``. A short protocol with ``adaptive: true``: pass 1 (a staircase, a step, two sines); at its
end the node commands 0 V, fits what the bag holds and plans; the planned records run as pass 2 from the clock
of that moment, in the same bag; the identification uses both passes. Checked from the files a user gets:
both passes' schedules in the bag, each with its own t0 (pass 2 after pass 1 and the fit); pass 2's segments are
the records of the plan it carries; the applied voltage during pass 2 is its schedule's; the identification's
experiments contain pass 2's records, and summary.json/report.md say there were two passes; ``dea-ros identify``
of the bag alone gives the same two-pass result.
"""
import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from dea_ros.cli.rig import RigProcesses, start_rig
from dea_ros.identify.bag_experiments import experiment_passes, experiments_from_bag, read_signals
from dea_ros.identify.from_bag import identify_bag
from dea_ros.model import config_dir

PROTOCOL = """
protocol:
  name: adaptive_check
  membrane: A2
  mass_kg: 0.003
  adaptive: true
  adaptive_budget_s: 3.0
  adaptive_max_settle_s: 0.3    # the holds of pass 1 (settled holds would need ~15 s each: the plan warns)
  segments:
    - kind: static
      voltages_V: [0, 1500, 2000, 2300]
      hold_s: 0.5
      measure_s: 0.2
    - kind: step
      initial_V: 0
      final_V: 2200
      pre_s: 0.2
      hold_s: 1.2
    - kind: sine
      amplitude_V: 2500
      frequencies_Hz: [8.0, 9.5]
      settle_s: 0.6
      measure_s: 0.5
    - kind: rest
      hold_s: 0.2
"""
RATE = 250.0


def test_an_adaptive_protocol_runs_the_planned_second_pass_and_identifies_from_both(tmp_path):
    protocol = tmp_path / "adaptive_check.yaml"
    protocol.write_text(PROTOCOL)
    rig = RigProcesses(namespace=f"/adaptive{os.getpid()}", quiet=True, log_dir=tmp_path)
    try:
        start_rig(rig, "A2", sim_time=True, speed=3.0, laser_rate_hz=500.0, update_rate_hz=RATE,
                  true_params=str(config_dir() / "rig" / "mock_membrane.yaml"), model=False)
        ident = rig.start("identifier_node", {
            "use_sim_time": True, "protocol": str(protocol), "output_dir": str(tmp_path), "run_name": "run",
            "exit_when_done": True, "command_rate_hz": RATE, "command_trigger": "applied_voltage",
            "command_batch": 25, "membrane": "A2"})
        t_end = time.monotonic() + 300.0
        while ident.poll() is None and time.monotonic() < t_end:
            assert rig.check_alive() is None, rig.check_alive()
            time.sleep(0.2)
        log = (tmp_path / "identifier_node.log").read_text()
        assert ident.returncode == 0, log
    finally:
        rig.stop()
    check_adaptive_run(tmp_path / "run", log)


def check_adaptive_run(run: Path, log: str) -> None:
    """What the user gets of an adaptive run (module docstring)."""
    summary = json.loads((run / "summary.json").read_text())
    assert summary["state"] == "done", summary.get("error")
    adaptive = summary["adaptive"]
    assert adaptive["passes"] == 2, adaptive
    bag = run / "bag"
    signals = read_signals(bag)
    passes = experiment_passes(signals.metadata, bag)
    assert len(passes) == 2
    (info1, t1, segs1), (info2, t2, segs2) = passes
    assert info1["aborted"] == "false" and info2["aborted"] == "false"
    assert (info1["protocol"], info2["protocol"]) == ("adaptive_check", "adaptive_check-planned")
    assert int(info2["segments_completed"]) == len(segs2)
    assert t2 >= t1 + segs1[-1]["end_s"]                # pass 2 after pass 1 (and the first fit at 0 V)
    # pass 2 runs the planner's picks: every sine and static level of the plan, and nothing else
    plan = json.loads(info2["plan_json"])
    assert plan["picks"] and plan["total_s"] <= 3.0 + 1e-9
    picked = sorted((p["frequency_Hz"], p["amplitude_V"], p["offset_V"]) for p in plan["picks"] if p["kind"] == "sine")
    ran = sorted((s["frequency_Hz"], s["amplitude_V"], s["offset_V"]) for s in segs2 if s["kind"] == "sine")
    assert ran == picked
    assert sorted(p["voltage_V"] for p in plan["picks"] if p["kind"] == "static") == \
        sorted(s["voltage_V"] for s in segs2 if s["kind"] == "static")
    assert [p["label"] for p in adaptive["plan"]["picks"]] == [p["label"] for p in plan["picks"]]
    # the applied voltage of pass 2 is its schedule's (each command for the update after its tick)
    t_rel = signals.voltage_t_s - t2
    inside = (t_rel > 0.05) & (t_rel < segs2[-1]["end_s"] - 2.0 / RATE)
    assert inside.sum() >= (segs2[-1]["end_s"] - 0.1) * RATE - 3
    k = np.searchsorted([s["end_s"] for s in segs2], t_rel[inside] - 1.0 / RATE, side="right")  # the tick's
    # (a jump between segments takes up to 25 ms at the amplifier's 1e5 V/s slew limit)
    bounds = np.array([s["start_s"] for s in segs2])
    off_boundary = np.min(np.abs(t_rel[inside][:, None] - bounds[None, :]), axis=1) > 0.03
    assert max(s.get("offset_V", 0.0) + s.get("amplitude_V", 0.0) + s.get("voltage_V", 0.0) for s in segs2) > 0
    expected = np.array([_voltage(segs2[j], t) for t, j in zip(t_rel[inside], k)])
    np.testing.assert_allclose(signals.voltage_V[inside][off_boundary], expected[off_boundary], atol=1.0)
    # the identification used both passes: the experiments it was given hold pass 2's records
    exp = experiments_from_bag(bag)
    n_sines = sum(len(s.frequency_Hz) for s in exp.sines)
    assert n_sines == sum(s["kind"] == "sine" for s in segs1) + len(ran)
    assert len(exp.static[0].voltage_V) == sum(s["kind"] == "static" for s in segs1 + segs2)
    report = Path(summary["report_file"]).read_text()
    assert "## Adaptive second pass" in report and plan["picks"][0]["label"] in report
    assert set(adaptive["realised_relative_ci95"]) >= {"eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"}
    assert "second pass planned" in log
    # offline, `dea-ros identify BAG` gets the same two-pass result from the bag alone
    offline = identify_bag(bag, run.parent / "offline", plots=False)
    assert offline["adaptive"]["plan"] == adaptive["plan"] and offline["adaptive"]["passes"] == 2
    for name, value in summary["parameters"].items():
        if isinstance(value, float):
            assert offline["parameters"][name] == pytest.approx(value, rel=1e-9, abs=0.0), name


def _voltage(seg: dict, t: float) -> float:
    """The protocol's voltage of a recorded segment (its JSON) at pass time t (s)."""
    if seg["kind"] == "sine":
        w = 2 * np.pi * seg["frequency_Hz"] * (t - seg["start_s"])
        off, amp = seg["offset_V"], seg["amplitude_V"]
        return abs(amp * np.sin(w)) if off == 0.0 else off + amp * np.sin(w)
    if seg["kind"] == "step":
        return seg["final_V"] if t >= seg["step_time_s"] else seg["initial_V"]
    return seg.get("voltage_V", 0.0)
