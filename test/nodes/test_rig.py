"""The rig on mock hardware over real rclpy: amplifier -> mock membrane -> displacement vs model."""
import time

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState, Range
from std_msgs.msg import Float64

from dea_ros.model import preset, static_equilibrium
from dea_ros.sim import free_udp_port
from dea_ros.nodes.amplifier_node import AmplifierNode
from dea_ros.nodes.common import COMMAND_QOS, SENSOR_QOS, stamp_to_s
from dea_ros.nodes.mock_hardware_node import MockHardwareNode
from dea_ros.nodes.model_node import ModelNode


#: laser, amplifier and model rate: 200 Hz keeps four nodes on one executor up to rate on a loaded
#: 2-core machine (at 500 Hz and load 6 the amplifier reached ~100 Hz and few predictions were close)
RATE_HZ = 200.0


def test_voltage_step_on_the_mock_rig_matches_the_model(ros_context, spin_until):
    port = free_udp_port()
    P = Parameter
    mock = MockHardwareNode(context=ros_context, parameter_overrides=[
        P("params_file", value="A1"), P("amplifier_port", value=port), P("noise_m", value=1e-6),
        P("sample_rate_hz", value=RATE_HZ)])
    amp = AmplifierNode(context=ros_context, parameter_overrides=[
        P("params_file", value="A1"), P("mock_port", value=port), P("update_rate_hz", value=RATE_HZ),
        P("watchdog_timeout_s", value=1.0)])
    model = ModelNode(context=ros_context,
                      parameter_overrides=[P("params_file", value="A1"), P("rate_hz", value=RATE_HZ),
                                           P("dt_s", value=0.5e-3)])  # RK4 step as the mock's
    peer = Node("experimenter", context=ros_context)
    cmd = peer.create_publisher(Float64, "voltage_cmd", COMMAND_QOS)
    meas, pred, volt = [], [], []
    peer.create_subscription(Range, "displacement", meas.append, SENSOR_QOS)
    peer.create_subscription(Range, "displacement_predicted", pred.append, SENSOR_QOS)
    peer.create_subscription(BatteryState, "voltage", volt.append, SENSOR_QOS)
    ex = SingleThreadedExecutor(context=ros_context)
    for n in (mock, amp, model, peer):
        ex.add_node(n)
    amp.trigger_configure()
    amp.trigger_activate()
    t_start = time.monotonic()

    def aligned(t_end_ros=float("inf")):
        """(measured stamps, displacements, predicted stamps, displacements, mask of the measurements
        between two close predictions). Compared only there: a dropped best-effort prediction would
        otherwise be interpolated across the fast transient."""
        tm = np.array([stamp_to_s(m.header.stamp) for m in meas])
        dm = np.array([m.range for m in meas])
        tp = np.array([stamp_to_s(m.header.stamp) for m in pred])
        dp = np.array([m.range for m in pred])
        if tp.size < 2 or tm.size == 0:
            return tm, dm, tp, dp, np.zeros(tm.size, bool)
        order = np.argsort(tp)
        tp, dp = tp[order], dp[order]
        k = np.clip(np.searchsorted(tp, tm), 1, tp.size - 1)
        window = (tm > tp[0] + 0.05) & (tm < t_end_ros) & ((tp[k] - tp[k - 1]) < 1.25 / RATE_HZ)
        return tm, dm, tp, dp, window

    def command_until(u, duration_s, enough=lambda: True, max_s=20.0):
        """Command u for duration_s of wall time, longer (up to max_s) until enough() holds: on a loaded
        machine the four nodes of this executor fall behind their rate and fewer predictions are close."""
        t0 = time.monotonic()
        next_cmd = next_check = 0.0
        while True:
            now = time.monotonic()
            if now >= t0 + max_s:
                break
            if now >= t0 + duration_s and now >= next_check:
                if enough():
                    break
                next_check = now + 0.25
            if now >= next_cmd:
                cmd.publish(Float64(data=u))
                next_cmd = now + 0.02
            ex.spin_once(timeout_sec=0.002)

    command_until(0.0, 0.5)
    t_step = time.monotonic()
    command_until(2200.0, 1.5, enough=lambda: aligned()[4].sum() >= 200)
    t_deactivate_ros = amp.now_s()
    amp.trigger_deactivate()
    spin_until(ex, lambda: volt and volt[-1].voltage == 0.0, timeout_s=3.0)
    assert volt[-1].voltage == 0.0
    assert max(m.voltage for m in volt) == pytest.approx(2200.0, abs=1e-6)
    # measured vs predicted, aligned on the stamps (predictions interpolated)
    tm, dm, tp, dp, window = aligned(t_deactivate_ros)
    assert window.sum() >= 40, f"only {window.sum()} measurements between two close predictions in 20 s"
    # cubic spline through the predictions (5 ms apart at 200 Hz: linear interpolation would add up to
    # ~3 um on the ringing at ~18 Hz, the spline ~0.03 um)
    keep = np.concatenate(([True], np.diff(tp) > 0))
    err = dm[window] - CubicSpline(tp[keep], dp[keep])(tm[window])
    rest = static_equilibrium(preset("A1"), 0.0).displacement_m
    assert dm.max() > rest + 50e-6  # the step moved the mass
    # the mock applies each voltage at its send time: only the 1 um laser noise should remain
    assert np.sqrt(np.mean(err**2)) < 2e-6, f"rms error {np.sqrt(np.mean(err**2)) * 1e6:.2f} um"
    print(f"samples {len(meas)}, rms error {np.sqrt(np.mean(err**2)) * 1e6:.2f} um, "
          f"max {np.abs(err).max() * 1e6:.2f} um, wall {time.monotonic() - t_start:.1f} s, "
          f"step at {t_step - t_start:.1f}")
    ex.shutdown()
    for n in (mock, amp, model, peer):
        n.destroy_node()
