"""Membrane health on /diagnostics over real rclpy: model_node (prediction error + tracked drift) and
position_controller_node (tracked drift, reachable range), each against a plant that is not its model."""
import importlib.util
import os
import re
import signal
import time
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import BatteryState, Range
from std_msgs.msg import Float64

from dea_ros.control import ModelInverse
from dea_ros.model import load_parameters, preset
from dea_ros.nodes.common import COMMAND_QOS, SENSOR_QOS, make_range, make_voltage_state
from dea_ros.nodes.model_node import ModelNode
from dea_ros.solvers.integrate import RealTimeStepper

_spec = importlib.util.spec_from_file_location("pc_test", Path(__file__).parent / "test_position_controller_node.py")
PC = importlib.util.module_from_spec(_spec)   # start_controller, stop, Plant: the lockstep harness
_spec.loader.exec_module(PC)


def _health(diags, suffix):
    return [s for a in diags for s in a.status if s.name.endswith(suffix)]


def test_model_node_reports_the_prediction_error_and_the_drift_in_words(ros_context, spin_until):
    a2 = preset("A2")
    truth = a2.replace(name="aged", relative_permittivity=a2.relative_permittivity * 0.94)   # electrode ageing
    node = ModelNode(context=ros_context, parameter_overrides=[
        Parameter("params_file", value="A2"), Parameter("rate_hz", value=1000.0),
        Parameter("health_persistence_s", value=0.0), Parameter("window_fit_period_s", value=1.0)])
    peer = Node("rig", context=ros_context)
    volt_pub = peer.create_publisher(BatteryState, "voltage", SENSOR_QOS)
    disp_pub = peer.create_publisher(Range, "displacement", SENSOR_QOS)
    diags = []
    peer.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(peer)
    assert spin_until(ex, lambda: volt_pub.get_subscription_count() > 0 and disp_pub.get_subscription_count() > 0)
    inv = ModelInverse(truth, 3150.0)
    lo, hi = inv.reachable_range_m
    levels = [inv.static_voltage(lo + f * (hi - lo)) for f in (0.3, 0.6, 0.45, 0.75)]
    plant = RealTimeStepper(truth, dt_s=2.5e-4, initial_voltage_V=levels[0])
    t0_ns = (node.now_ns() // 1_000_000_000 + 1_000_000) * 1_000_000_000     # far future: no timer path
    for k in range(4000):
        u = levels[(k // 800) % len(levels)]
        n_in, n_pub = node.health.samples_observed, node.published   # monotonic (a report clears errors)
        for _ in range(3):        # best effort: a message may be dropped; send it again
            volt_pub.publish(make_voltage_state(u, t0_ns + k * 1_000_000, True))
            if spin_until(ex, lambda: node.published > n_pub, timeout_s=0.5):
                break
        for _ in range(3):
            disp_pub.publish(make_range(plant.displacement_m, t0_ns + k * 1_000_000, "dea_laser"))
            if spin_until(ex, lambda: node.health.samples_observed > n_in, timeout_s=0.5):
                break
        for _ in range(4):
            plant.step(u)
    n_observed = node.health.samples_observed
    node.publish_diagnostics()

    def final_reports():   # the report just published, not a periodic one from before the last samples
        return [st for st in _health(diags, "membrane health")
                if int({kv.key: kv.value for kv in st.values}["laser_samples"]) == n_observed]
    assert spin_until(ex, final_reports, timeout_s=5.0)
    status = final_reports()[-1]
    values = {kv.key: kv.value for kv in status.values}
    assert status.level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
    assert "electrostatic gain" in status.message and "below the identified model" in status.message
    assert "electrode ageing" in status.message
    assert 0.90 < float(values["tracked_electrostatic_gain_ratio"]) < 0.985
    assert values["window_fit_worker"] == "thread" and values["window_fit_failures"] == "0"
    assert int(values["window_fits"]) >= 1          # the controller's window fit ran off the callbacks
    # every laser sample paired by stamps with its voltage (a resent duplicate is dropped as stale)
    assert int(values["laser_samples"]) > 3000
    assert int(values["laser_samples_tracked"]) >= 0.99 * int(values["laser_samples"])
    windows = [{kv.key: kv.value for kv in st.values} for st in _health(diags, "membrane health")]
    windows = [w for w in windows if int(w.get("prediction_samples", "0")) > 20]
    assert windows                                                     # the error statistics of each report
    assert max(abs(float(w["prediction_error_mean_m"])) for w in windows) > 1e-6   # the fixed model is off
    ex.shutdown()
    node.destroy_node()
    peer.destroy_node()


def test_position_controller_node_reports_drift_and_the_current_range(ros_context, spin_until):
    """The controller's model (A2) is not the mock rig's membrane (eps_r 2.45, not 2.63; k1 +15 %...)."""
    ns = "/pc_health"
    inv = ModelInverse(load_parameters(PC.TRUTH), PC.U_MAX)
    lo, hi = inv.reachable_range_m
    d_start = lo + 60e-6
    proc = PC.start_controller(ns, "sensor_timeout_s:=2.0", "health_persistence_s:=0.5", "diagnostics_rate_hz:=5.0")
    node = Node("plant_health", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        plant = PC.Plant(node, ns, inv.static_voltage(d_start))
        set_pub = node.create_publisher(Float64, f"{ns}/displacement_setpoint", COMMAND_QOS)
        diags = []
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        assert spin_until(ex, lambda: plant.pub.get_subscription_count() > 0, timeout_s=30.0), PC.H.stderr_of(proc)
        assert spin_until(ex, lambda: plant.sample(ex, spin_until, timeout_s=0.2), timeout_s=20.0)
        targets = [lo + f * (hi - lo) for f in (0.35, 0.65, 0.45, 0.75, 0.3, 0.6)]
        for k in range(4200):
            if k % 700 == 0:
                set_pub.publish(Float64(data=targets[(k // 700) % len(targets)]))
            assert plant.sample(ex, spin_until)
        spin_until(ex, lambda: False, timeout_s=0.5)
        health = _health(diags, "membrane health")
        assert health
        status = health[-1]
        values = {kv.key: kv.value for kv in status.values}
        print(status.level, status.message, values)
        assert status.level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
        assert "electrostatic gain" in status.message and "below" in status.message
        assert float(values["tracked_electrostatic_gain_ratio"]) < 0.98
        assert int(values["retunes"]) >= 1                       # the controller runs on the tracked model
        assert values["retune_worker"].startswith("process (pid ") and values["retune_failures"] == "0"
        assert float(values["tracked_reachable_min_m"]) < float(values["tracked_reachable_max_m"])
        d_end = np.array([h[1] for h in plant.history[-100:]])
        assert abs(d_end.mean() - targets[5]) < 2e-6             # still controlling after the retunes
    finally:
        PC.stop(proc)
        ex.shutdown()
        node.destroy_node()


def _worker(diags):
    """(pid, starts, plans, failures) of the controller's retune worker from its latest health status."""
    values = {kv.key: kv.value for kv in _health(diags, "membrane health")[-1].values}
    pid, starts = re.match(r"process \(pid (\d+), started (\d+) time", values["retune_worker"]).groups()
    return int(pid), int(starts), int(values["retune_plans"]), int(values["retune_failures"])


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def test_position_controller_node_survives_its_retune_worker_and_takes_it_along(ros_context, spin_until):
    """The worker process killed under the running node: the loop goes on commanding every sample, a new
    worker serves the next retunes; the node killed with SIGKILL: its worker exits too."""
    ns = "/pc_worker"
    inv = ModelInverse(load_parameters(PC.TRUTH), PC.U_MAX)
    lo, hi = inv.reachable_range_m
    proc = PC.start_controller(ns, "sensor_timeout_s:=5.0", "diagnostics_rate_hz:=10.0")
    node = Node("plant_worker", context=ros_context)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    try:
        plant = PC.Plant(node, ns, inv.static_voltage(lo + 60e-6))
        set_pub = node.create_publisher(Float64, f"{ns}/displacement_setpoint", COMMAND_QOS)
        diags = []
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        assert spin_until(ex, lambda: plant.pub.get_subscription_count() > 0, timeout_s=30.0), PC.H.stderr_of(proc)
        assert spin_until(ex, lambda: plant.sample(ex, spin_until, timeout_s=0.2), timeout_s=20.0)
        targets = [lo + f * (hi - lo) for f in (0.35, 0.65, 0.45, 0.75, 0.3, 0.6)]
        k = 0

        def run_until(done, max_samples):
            nonlocal k
            for _ in range(max_samples):
                if k % 700 == 0:
                    set_pub.publish(Float64(data=targets[(k // 700) % len(targets)]))
                assert plant.sample(ex, spin_until), f"no command for sample {k}"   # every sample answered
                k += 1
                if k % 100 == 0 and _health(diags, "membrane health") and done():
                    return True
            return False

        assert run_until(lambda: _worker(diags)[2] >= 1, 8000)       # a first plan from the worker
        pid, starts, plans, _ = _worker(diags)
        os.kill(pid, signal.SIGKILL)
        # the loop carries on; the next retune is served by a new worker (a retune in flight is dropped)
        assert run_until(lambda: _worker(diags)[0] != pid and _worker(diags)[2] > plans, 12000), _worker(diags)
        new_pid, new_starts, _, failures = _worker(diags)
        assert new_starts == starts + 1 and failures <= 1
        while k % 700 != 650:                                       # let the last move settle: still controlling
            run_until(lambda: False, 1)
        d_end = np.array([h[1] for h in plant.history[-100:]])
        assert abs(d_end.mean() - targets[(k // 700) % len(targets)]) < 2e-6
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and not _gone(new_pid):
            time.sleep(0.1)
        assert _gone(new_pid)
    finally:
        PC.stop(proc)
        ex.shutdown()
        node.destroy_node()
