"""The main job on a short protocol: mock rig -> protocol -> bag -> identification -> report.

The mock simulates config/rig/mock_membrane.yaml (A2 with other material parameters); the
identification starts from the nominal A2. The identified model must reproduce the mock: the step
within the laser noise and the resonance frequency within 2 %. The run records a Humble-format bag
(``--rosbag2-format humble``), checked against Humble's and Jazzy's rosbag2 parsing rules, with the
QoS of the discovered publishers and monotonic header stamps on every stream.
"""
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")  # the rig runs ROS 2 nodes

from dea_ros.cli.rig import DEFAULT_COMMAND_BATCH  # noqa: E402 (after the skip without rclpy)

ROOT = Path(__file__).resolve().parents[1]
COMMAND_BATCH = DEFAULT_COMMAND_BATCH   # the demo's (batches of 25; the same voltages: test_command_batch_rig.py)


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(60 + os.getpid() % 40)
    cmd = [sys.executable, "-m", "dea_ros.cli", "rig", "demo", "--protocol", "test",
           "--out", str(out), "--run-name", "e2e", "--json", "--rosbag2-format", "humble",
           "--model-node",  # model_node is opt-in (issue 22): its predicted stream is checked below too
           "--command-batch", str(COMMAND_BATCH)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{\n"):])
    return out / "e2e", summary


def test_demo_writes_bag_parameters_and_report(demo_run):
    run, summary = demo_run
    assert summary["state"] == "done" and not summary["error"]
    for key in ("params_file", "report_file"):
        assert Path(summary[key]).is_file()
    assert len(summary["figures"]) >= 3 and all(Path(f).stat().st_size > 10_000 for f in summary["figures"])
    counts = summary["messages"]
    from dea_ros.identify.protocols import load_protocol

    duration = load_protocol("test").duration_s()
    # demo defaults: laser at 500 Hz, amplifier and commands at 250 Hz (simulated time), no gaps
    assert counts["/dea/displacement"] > 0.98 * duration * 500
    assert counts["/dea/voltage"] > 0.98 * duration * 250
    commands = counts.get("/dea/voltage_cmd", 0) + COMMAND_BATCH * counts.get("/dea/voltage_cmd_batch", 0)
    assert commands > 0.98 * duration * 250


def test_bag_opens_in_the_independent_reader(demo_run):
    from rosbags.highlevel import AnyReader

    run, _ = demo_run
    with AnyReader([run / "bag"]) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        assert topics["/dea/displacement"] == "sensor_msgs/msg/Range"
        assert topics["/dea/voltage"] == "sensor_msgs/msg/BatteryState"
        conn = [c for c in reader.connections if c.topic == "/dea/voltage"]
        n = 0
        for c, t, raw in reader.messages(connections=conn):
            msg = reader.deserialize(raw, c.msgtype)
            assert 0.0 <= msg.voltage <= 2500.0 + 1e-3
            n += 1
        assert n > 10_000


def test_identified_model_reproduces_the_mock(demo_run):
    from dea_ros.model import load_parameters
    from dea_ros.model.parameters import config_dir
    from dea_ros.solvers import SinePeriodic, frequency_sweep

    run, summary = demo_run
    fitted = load_parameters(summary["params_file"])
    truth = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
    nominal = load_parameters("A2")
    freqs = np.linspace(8.5, 11.0, 51)
    peak = {name: frequency_sweep(p, SinePeriodic(2500.0, 1.0), freqs, n_harmonics=8).resonance_peak()["frequency_Hz"]
            for name, p in (("fitted", fitted), ("truth", truth), ("nominal", nominal))}
    assert abs(peak["fitted"] - peak["truth"]) / peak["truth"] < 0.02, peak
    assert abs(peak["nominal"] - peak["truth"]) / peak["truth"] > 0.02  # the check is not trivially met
    step = summary["metrics"]["steps"][0]
    assert step["rms_error_um"] < 2.0, step  # laser noise 1 um: the model error is below the noise
    assert abs(fitted.relative_permittivity - truth.relative_permittivity) / truth.relative_permittivity < 0.05


def test_sine_commands_are_applied_one_update_later_without_jitter(demo_run):
    """The recorded amplifier output at each update t_k is the protocol's |U sin| at t_k: the command
    computed one update earlier, never at once (the jittered staircase the clock-tick race gave:
    10-15 % of the updates a step early, which excited the resonance and made the 15/20 Hz records
    irregular)."""
    import json as json_
    from dea_ros.identify.bag_experiments import EXPERIMENT_METADATA, read_signals
    from dea_ros.identify.protocols import load_protocol

    signals = read_signals(demo_run[0] / "bag")
    record = signals.metadata[EXPERIMENT_METADATA]
    t0 = int(record["t0_ns"]) * 1e-9
    schedule = {seg.index: seg for seg in load_protocol("test").schedule()}
    t, u = signals.voltage_t_s - t0, signals.voltage_V
    checked = 0
    for seg in json_.loads(record["segments_json"]):
        if seg["kind"] != "sine":
            continue
        inside = (t >= seg["measure_start_s"]) & (t < seg["measure_end_s"])
        expected = np.array([schedule[seg["index"]].voltage_at(x) for x in t[inside]])
        assert np.max(np.abs(u[inside] - expected)) < 2.0, seg["frequency_Hz"]
        checked += int(inside.sum())
    assert checked > 1000


def _rules():
    spec = importlib.util.spec_from_file_location("rosbag2_rules", ROOT / "test" / "bag" / "rosbag2_rules.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bag_is_read_by_humble_and_jazzy_and_converts(demo_run, tmp_path):
    from dea_ros.bag import BagReader, convert_bag

    rules = _rules()
    bag = demo_run[0] / "bag"
    for distro in ("humble", "jazzy"):
        info = rules.check_bag(bag, distro)
        assert info["version"] == 5
        # one profile per discovered publisher, as ros2 bag record: the mock's best-effort laser
        (laser,) = info["topics"]["/dea/displacement"]["qos"]
        assert laser["reliability"] == "best_effort" and laser["durability"] == "volatile"
        (cmd,) = info["topics"]["/dea/voltage_cmd"]["qos"]
        assert cmd["reliability"] == "reliable"
    jazzy = convert_bag(bag, "jazzy", out=tmp_path / "jazzy")
    assert rules.check_bag(jazzy, "jazzy")["version"] == 9
    with BagReader(bag) as original, BagReader(jazzy) as converted:
        assert converted.topics() == original.topics()


def test_header_stamps_never_go_backwards_on_any_stream(demo_run):
    """In publication order (the recorder's per-topic sequence), each stamp >= the previous one."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    (mcap_file,) = sorted((demo_run[0] / "bag").glob("*.mcap"))
    stamps = {}
    with open(mcap_file, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            header = getattr(decoded, "header", None)
            if header is not None:
                stamp = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
                stamps.setdefault(channel.topic, []).append((message.sequence, stamp))
    assert {"/dea/voltage", "/dea/displacement", "/dea/displacement_predicted"} <= set(stamps)
    for topic, pairs in stamps.items():
        values = np.array([stamp for _seq, stamp in sorted(pairs)], dtype=np.int64)
        steps = np.diff(values)
        backwards = np.flatnonzero(steps < 0)
        assert backwards.size == 0, (
            f"{topic}: {backwards.size} of {values.size} stamps go backwards, "
            f"by up to {-steps.min() * 1e-6:.3f} ms")
