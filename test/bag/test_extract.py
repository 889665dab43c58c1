"""Bag -> experiments: a bag written from the model (no ROS) is cut back into the experiments."""
import json

import numpy as np
import pytest
import yaml

from dea_ros.bag import BagError, BagWriter
from dea_ros.identify.bag_experiments import EXPERIMENT_METADATA, BagTopics, experiments_from_bag
from dea_ros.identify.protocols import load_protocol
from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers import SinePeriodic, solve_native
from dea_ros.solvers.integrate import simulate_held
from fakes.recorded_bag import T0_NS, write_rig_bag


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The 'test' protocol applied to A2 (ZOH at 500 Hz), laser at 1 kHz with 1 um noise."""
    proto = load_protocol("test")
    segs = proto.schedule()
    duration = segs[-1].end_s
    tv = np.arange(0.0, duration, 2e-3)
    seg_idx = np.searchsorted([s.end_s for s in segs], tv, side="right").clip(0, len(segs) - 1)
    uv = np.array([segs[k].voltage_at(t) for k, t in zip(seg_idx, tv)])
    td = np.arange(0.0, duration, 1e-3)
    # the ZOH input integrated hold by hold (the compiled kernel of the mock's truth), each 2 ms hold
    # as two 1 ms holds of the same voltage so that the states fall on the laser's samples
    held = simulate_held(preset("A2"), np.repeat(uv, 2), 1e-3)
    assert td.size <= held.time_s.size - 1 and np.allclose(held.time_s[:td.size], td, rtol=0.0, atol=1e-9)
    rng = np.random.default_rng(3)
    d = held.displacement_m[:td.size] + rng.normal(0, 1e-6, td.size)
    d[::97] = np.nan  # samples laser_sensor_node flagged implausible (REP 117 invalid): skipped
    path = tmp_path_factory.mktemp("bags") / "run"
    record = {"protocol": "test", "membrane": "A2", "mass_kg": "0.003", "t0_ns": str(T0_NS),
              "segments_json": json.dumps([s.to_dict() for s in segs]), "aborted": "false",
              "segments_completed": str(len(segs))}
    write_rig_bag(path, tv, uv, td, d, [(EXPERIMENT_METADATA, record)])
    return path, segs


def test_experiments_are_cut_from_the_bag(recorded):
    path, segs = recorded
    exp = experiments_from_bag(path)
    a2 = preset("A2")
    static = exp.static[0]
    levels = [s.info["voltage_V"] for s in segs if s.kind == "static"]
    np.testing.assert_allclose(static.voltage_V, levels, atol=1e-3)
    # the holds are short (2.5 s) against the 0.93 s creep: within a few um of the equilibrium
    eq = static_equilibrium(a2, static.voltage_V).displacement_m
    assert np.max(np.abs(static.displacement_m - eq)) < 5e-6
    step = exp.steps[0]
    step_seg = next(s for s in segs if s.kind == "step")
    assert step.final_V == pytest.approx(2200) and step.initial_V == 0
    # windows end 10 ms before the boundary (the identifier commands one period ahead)
    # every 97th sample is NaN (flagged) and skipped
    assert step.n_samples == pytest.approx((step_seg.end_s - step_seg.start_s - 0.01) * 1000 * 96 / 97, abs=5)
    sines = exp.sines[0]
    freqs = [s.info["frequency_Hz"] for s in segs if s.kind == "sine"]
    assert list(sines.frequency_Hz) == freqs
    d0 = static.displacement_m[0]
    rms = solve_native(a2, SinePeriodic(2500.0, freqs[0]), 10).displacement_rms(
        static_equilibrium(a2, 0).displacement_m)
    assert sines.d_rms_m[0] == pytest.approx(rms, rel=0.03)
    assert sines.series[0].frequency_Hz == freqs[0] and d0 > 0
    # each sine's measuring window is whole periods (13-15 here): all of them are kept, the window
    # moved earlier by the 10 ms guard into the same sine's settling instead of losing its last period
    for series, seg in zip(sines.series, [s for s in segs if s.kind == "sine"]):
        planned = round((seg.measure_end_s - seg.measure_start_s) * seg.info["frequency_Hz"])
        assert series.period_weights()[1] == planned
    assert exp.mass_kg == 0.003 and exp.geometry["thickness_m"] == a2.thickness_m


def test_foreign_bag_needs_a_segments_file(recorded, tmp_path):
    path, segs = recorded
    # a bag without the identifier's metadata
    plain = tmp_path / "plain"
    with BagWriter(plain) as bag:
        bag.add_topic("/rig/u", "std_msgs/msg/Float64")
        bag.add_topic("/rig/d", "std_msgs/msg/Float64")
        for k in range(3000):
            t = T0_NS + k * 1_000_000
            bag.write("/rig/u", {"data": 0.0 if k < 1000 else 2200.0}, t)
            bag.write("/rig/d", {"data": 7.3e-4 if k < 1000 else 8.4e-4}, t)
    topics = BagTopics(voltage="/rig/u", displacement="/rig/d")
    with pytest.raises(BagError, match="segments YAML"):
        experiments_from_bag(plain, topics=topics)
    seg_file = tmp_path / "segments.yaml"
    seg_file.write_text(yaml.safe_dump({"membrane": "A2", "mass_kg": 0.003, "t0_s": T0_NS * 1e-9, "segments": [
        {"kind": "static", "voltage_V": 0, "measure_start_s": 0.5, "measure_end_s": 0.9},
        {"kind": "static", "voltage_V": 2200, "measure_start_s": 2.5, "measure_end_s": 2.9},
        {"kind": "step", "start_s": 0.5, "end_s": 2.9}]}))
    exp = experiments_from_bag(plain, topics=topics, segments_file=seg_file)
    np.testing.assert_allclose(exp.static[0].displacement_m, [7.3e-4, 8.4e-4])
    assert exp.steps[0].final_V == 2200.0


def test_missing_and_mistyped_topics(recorded, tmp_path):
    path, _ = recorded
    with pytest.raises(BagError, match="no displacement topic '/dea/laser'"):
        experiments_from_bag(path, topics=BagTopics(displacement="/dea/laser"))
    odd = tmp_path / "odd"
    with BagWriter(odd) as bag:
        bag.add_topic("/dea/voltage", "std_msgs/msg/String")
        bag.add_topic("/dea/displacement", "std_msgs/msg/Float64")
        bag.write("/dea/voltage", {"data": "x"}, T0_NS)
        bag.write("/dea/displacement", {"data": 1.0}, T0_NS)
    with pytest.raises(BagError, match="type std_msgs/msg/String"):
        experiments_from_bag(odd)
