"""Position control benchmark (issue 11): tracking on the simulated rig, loop timing of the node.

Part 1 -- tracking, on the simulated plant of the core (``dea_ros.control.simulation``), not on the
ROS mock rig: the plant is the mock rig's membrane (``config/rig/mock_membrane.yaml``, the demo's
truth) integrated by the same RK4 as mock_hardware_node (0.25 ms), sampled at 1 kHz with the mock's
laser noise (1 um) and ILD1320 quantisation (0.156 um); the command reaches the amplifier
``--latency-ms`` after the sample (default 0.5 ms, the node's measured median) and the amplifier is
the real safety core (SafeVoltageController: 3150 V, slew ``--slew`` V/s, default 100 kV/s as
config/amplifier.yaml) updating at 1 kHz. Controllers, all with the parameters IDENTIFIED by the
demo (``--params``, default the newest runs/*/params.yaml), none with the true ones:

  (a) open loop: the static inverse (eq. 20) of the raw reference;
  (b) the best PID without the model: PID on the voltage (bumpless from the initial voltage,
      derivative filter, conditional-integration anti-windup), gains tuned by direct search
      (Nelder-Mead on log-gains) of the closed-loop IAE on the simulated plant itself over a
      training set (50 um steps up and down, 5 Hz and 10 Hz sines; another noise seed than the
      evaluation) -- what an experiment-based tuning on the real rig could reach at best;
  (c) feedforward (eq. 5 inverted) + PID on u^2 (dea_ros.control.PositionController).

References: 50 um steps across the reachable range (setpoints: shaped by (c), raw for (a), (b));
30 um sines at 1, 5, 10, 15 Hz around mid-stroke (faded in over 2 periods, evaluated afterwards);
a smooth point-to-point trajectory (quintic, 100 um in 60 ms and back). Errors are of the TRUE
displacement (the plant's state); steps: overshoot and 2 % settling time from the step command,
on the noise-free run (settling on the noisy run is also given); voltage effort: RMS voltage and
mean |du/dt|. Medians over ``--seeds`` noise seeds.

Part 2 -- loop timing of position_controller_node at 1 kHz (separate processes, real rclpy over
loopback DDS): a publisher process sends sensor_msgs/Range at 1 kHz stamped at send time; the node
(own process, publish_stamped_command) answers each sample; this process measures receive time -
sample stamp (sensor-to-command latency) and the intervals between commands (period jitter), and
model_node's latency is measured in the same run with bench_nodes.py's method, side by side.

Run: python bench/bench_control.py [--params runs/<run>/params.yaml] [--timing-s 30]
Writes bench/results/control.md (and the parameters used to bench/results/control_params.yaml).
"""
from __future__ import annotations

import argparse
import dataclasses
import glob
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))
from machine_info import machine  # noqa: E402

from dea_ros.control import (  # noqa: E402
    ControllerConfig,
    ModelInverse,
    PiecewiseQuintic,
    PositionController,
    SimulatedRig,
    loop_delays,
    SineReference,
    Trajectory,
    run_closed_loop,
)
from dea_ros.model import load_parameters, static_equilibrium  # noqa: E402

U_MAX = 3150.0          # A2: 0.9 x 100 V/um x 35 um (amplifier_node's limit)
STEP = 50e-6
HOLD_S = 0.5


# ----------------------------------------------------------------------------- references
class StepSequence(Trajectory):
    """Raw steps: level k from k * hold_s (the reference (a) and (b) see)."""

    def __init__(self, levels, hold_s):
        self.levels, self.hold_s = list(levels), hold_s
        self.start_s, self.end_s = 0.0, hold_s * len(levels)

    def sample(self, t):
        k = min(max(int(t // self.hold_s), 0), len(self.levels) - 1)
        return self.levels[k], 0.0, 0.0


def scenarios(inv: ModelInverse, truth_range):
    lo = max(inv.reachable_range_m[0], truth_range[0])
    hi = min(inv.reachable_range_m[1], truth_range[1])
    n = int((hi - lo - 20e-6) // STEP)
    base = lo + 0.5 * ((hi - lo) - n * STEP)
    up = [base + k * STEP for k in range(n + 1)]
    levels = up + up[::-1][1:]
    mid = 0.5 * (lo + hi)
    out = [("steps", StepSequence(levels, HOLD_S), levels)]
    for f in (1.0, 5.0, 10.0, 15.0):
        fade = 2.0 / f
        out.append((f"sine {f:g} Hz", SineReference(mid, 30e-6, f, start_s=0.05, fade_periods=2.0),
                    (0.05 + fade + 0.1, 0.05 + fade + 0.1 + max(5.0 / f, 1.0))))
    a, b = mid - 50e-6, mid + 50e-6
    p2p = PiecewiseQuintic([0.05, 0.11, 0.31, 0.37], [a, b, b, a], velocities=[0, 0, 0, 0],
                           accelerations=[0, 0, 0, 0])
    out.append(("point to point", p2p, (0.05, 0.6)))
    return out, mid


# ----------------------------------------------------------------------------- controllers
class OpenLoop:
    name = "(a) open loop, static inverse"

    def __init__(self, inv):
        self.inv = inv

    def reset(self, ref, d0):
        self.ref = ref

    def __call__(self, t, m):
        lo, hi = self.inv.reachable_range_m
        d = min(max(self.ref.sample(t)[0], lo), hi)
        return float(self.inv.static_voltage(d, check=False))


class VoltagePID:
    """PID on the voltage, no model: u = u0 + kp e + ki int e + kd De, clamped, slew-limited, anti-windup."""

    name = "(b) PID on the voltage, no model"

    def __init__(self, kp, ki, kd, tf, slew, dt=1e-3):
        self.kp, self.ki, self.kd, self.tf, self.slew, self.dt = kp, ki, kd, tf, slew, dt

    def reset(self, ref, d0, u0):
        self.ref, self.u0 = ref, u0
        self.i = 0.0
        self.der = 0.0
        self.last_e = None
        self.u = u0
        self.sat = 0

    def __call__(self, t, m):
        e = self.ref.sample(t)[0] - m
        dt = self.dt
        if self.last_e is not None:
            a = self.tf / (self.tf + dt)
            self.der = a * self.der + (e - self.last_e) / (self.tf + dt)
            if not (self.sat > 0 and e > 0) and not (self.sat < 0 and e < 0):
                self.i += e * dt
        self.last_e = e
        u = self.u0 + self.kp * e + self.ki * self.i + self.kd * self.der
        sat = 0
        if u > U_MAX:
            u, sat = U_MAX, 1
        elif u < 0.0:
            u, sat = 0.0, -1
        step = self.slew * dt
        if u > self.u + step:
            u, sat = self.u + step, 1
        elif u < self.u - step:
            u, sat = self.u - step, -1
        self.sat, self.u = sat, u
        return u


class ModelBased:
    name = "(c) feedforward + feedback (model)"

    def __init__(self, params, cfg):
        self.ctl = PositionController(params, cfg)

    def reset(self, ref, d0, kind, levels=None):
        self.ref, self.kind, self.levels, self.d0 = ref, kind, levels, d0
        self.started = False
        self.k = -1

    def __call__(self, t, m):
        ctl = self.ctl
        if not self.started:
            ctl.start(t, self.d0)
            self.started = True
            if self.kind != "steps":
                ctl.set_trajectory(t, self.ref)
        if self.kind == "steps":
            k = int((t + 1e-9) // HOLD_S)
            if k != self.k and 0 < k < len(self.levels):
                ctl.set_setpoint(t, self.levels[k])
            self.k = k
        return ctl.update(t, m).voltage_V


# ----------------------------------------------------------------------------- runs and metrics
def run(rig, controller, ref, duration, d0, kind, levels=None, inv=None):
    u0 = float(static_voltage_true(rig, d0))
    if isinstance(controller, ModelBased):
        controller.reset(ref, d0, kind, levels)
    elif isinstance(controller, VoltagePID):
        controller.reset(ref, d0, u0)
    else:
        controller.reset(ref, d0)
    return run_closed_loop(rig, controller, duration, initial_voltage_V=u0)


_u0_cache: dict = {}


def static_voltage_true(rig, d0):
    """The voltage that holds the TRUE plant at rest at d0 (the rig's state before each experiment)."""
    key = (rig.params.name, round(d0 * 1e9))
    if key not in _u0_cache:
        inv = ModelInverse(rig.params, U_MAX)
        _u0_cache[key] = inv.static_voltage(min(max(d0, inv.reachable_range_m[0]), inv.reachable_range_m[1]),
                                            check=False)
    return _u0_cache[key]


def effort(res, mask):
    u = res.applied_V[mask]
    return float(np.sqrt(np.mean(u ** 2))), float(np.mean(np.abs(np.diff(u))) / 1e-3)


def step_metrics(res, levels):
    out = []
    for k in range(1, len(levels)):
        m = (res.time_s >= k * HOLD_S) & (res.time_s < (k + 1) * HOLD_S)
        t = res.time_s[m] - k * HOLD_S
        d = res.true_m[m]
        size = levels[k] - levels[k - 1]
        e = d - levels[k]
        over = max(0.0, float(np.max(np.sign(size) * e))) / abs(size) * 100
        outside = np.nonzero(np.abs(e) > 0.02 * abs(size))[0]
        settle = float(t[outside[-1]] + 1e-3) if outside.size else 0.0
        if outside.size and outside[-1] >= t.size - 1:
            settle = math.inf
        out.append({"overshoot_pct": over, "settling_s": settle, "rms_m": float(np.sqrt(np.mean(e ** 2))),
                    "max_m": float(np.max(np.abs(e)))})
    return out


def track_metrics(res, ref, window):
    m = (res.time_s >= window[0]) & (res.time_s <= window[1])
    e = res.true_m[m] - ref.sample_many(res.time_s[m])[0]
    return float(np.sqrt(np.mean(e ** 2))), float(np.max(np.abs(e))), m


# ----------------------------------------------------------------------------- PID tuning (no model)
def tune_pid(truth, slew, inv_levels, mid, seed, evals):
    """Nelder-Mead on log(kp, ki, kd, tf) of the IAE over training experiments on the plant itself."""
    rig = SimulatedRig(truth, U_MAX, slew_rate_V_per_s=slew, seed=seed, latency_s=5e-4, amplifier_phase_s=7.5e-4)
    lv = [inv_levels[1], inv_levels[2], inv_levels[1]]
    train = [("steps", StepSequence(lv, 0.3), lv, 0.9, lv[0]),
             ("sine", SineReference(mid, 30e-6, 5.0, start_s=0.05, fade_periods=2.0), None, 0.8, mid),
             ("sine", SineReference(mid, 30e-6, 10.0, start_s=0.05, fade_periods=2.0), None, 0.6, mid)]

    def cost(x):
        kp, ki, kd, tf = np.exp(x)
        if tf < 2e-4 or tf > 0.05:
            return 1e3
        total = 0.0
        for kind, ref, levels, dur, d0 in train:
            pid = VoltagePID(kp, ki, kd, tf, slew)
            res = run(rig, pid, ref, dur, d0, kind)
            e = res.true_m - ref.sample_many(res.time_s)[0]
            if not np.all(np.isfinite(e)) or np.max(np.abs(e)) > 500e-6:
                return 1e3
            total += float(np.mean(np.abs(e))) * 1e6
        return total

    # start: what a step test gives without a model (static gain ~2e-7 m/V, 18 Hz ringing): derivative
    # action damping the ringing (~0.3), an integral 10x slower than it, a small proportional part
    x0 = np.log([3e5, 5e7, 2e4, 2e-3])
    simplex = x0 + np.vstack([np.zeros(4), np.eye(4) * 1.0])
    best = minimize(cost, x0, method="Nelder-Mead", options={"maxfev": evals, "xatol": 0.02, "fatol": 0.01,
                                                             "initial_simplex": simplex})
    kp, ki, kd, tf = np.exp(best.x)
    return (kp, ki, kd, tf), best.fun, best.nfev


# ----------------------------------------------------------------------------- timing
PUBLISHER = r"""
import sys, time, rclpy
from rclpy.node import Node
from sensor_msgs.msg import Range
from dea_ros.nodes.common import SENSOR_QOS, make_range
rclpy.init(); n = Node('laser_source'); pub = n.create_publisher(Range, 'displacement', SENSOR_QOS)
duration = float(sys.argv[1]); d = float(sys.argv[2])
# wait until the node under test is up (a loaded machine: 10+ s), then 1 s more
t_wait = time.monotonic() + 120.0
while pub.get_subscription_count() == 0 and time.monotonic() < t_wait: time.sleep(0.05)
time.sleep(1.0)
t_end = time.monotonic() + duration; k = 0; next_t = time.monotonic()
while time.monotonic() < t_end:
    pub.publish(make_range(d, n.get_clock().now().nanoseconds, 'dea_laser')); k += 1
    next_t += 0.001
    delay = next_t - time.monotonic()
    if delay > 0: time.sleep(delay)
print(k, flush=True)
"""


def bench_controller_timing(seconds, env, params_file, d):
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import BatteryState

    from dea_ros.nodes.common import SENSOR_QOS

    ctl = subprocess.Popen([sys.executable, "-m", "dea_ros.nodes.position_controller_node", "--ros-args",
                            "--params-file", str(ROOT / "config" / "position_controller.yaml"),
                            "-p", f"params_file:={params_file}", "-p", "autostart:=true",
                            "-p", "publish_stamped_command:=true", "-p", "sensor_timeout_s:=0.5"],
                           env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    source = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(seconds), str(d)], env=env,
                              stdout=subprocess.PIPE, text=True)
    rclpy.init()
    node = Node("control_latency_probe")
    lat, arrivals = [], []

    def on_cmd(msg):
        now = node.get_clock().now().nanoseconds
        lat.append((now - (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)) * 1e-9)
        arrivals.append(time.monotonic())

    node.create_subscription(BatteryState, "position_controller_node/command_stamped", on_cmd, SENSOR_QOS)
    t_end = time.monotonic() + seconds + 130.0
    while time.monotonic() < t_end and source.poll() is None:
        rclpy.spin_once(node, timeout_sec=0.01)
    sent = int(source.communicate(timeout=10)[0].strip() or 0)
    ctl.terminate()
    ctl.wait(timeout=10)
    node.destroy_node()
    rclpy.shutdown()
    lat = np.array(lat)
    gaps = np.diff(np.array(arrivals)) * 1e3
    return {"sent": sent, "received": int(lat.size), "median_ms": float(np.median(lat) * 1e3),
            "p99_ms": float(np.percentile(lat, 99) * 1e3), "max_ms": float(lat.max() * 1e3),
            "period_median_ms": float(np.median(gaps)), "period_p1_ms": float(np.percentile(gaps, 1)),
            "period_p99_ms": float(np.percentile(gaps, 99)), "period_std_ms": float(np.std(gaps))}


# ----------------------------------------------------------------------------- the ROS mock rig, simulated time
def mock_rig(args, params_file, levels, mid):
    """(c) through ROS: mock_hardware_node (simulated time, lockstep with the amplifier's updates, its
    acknowledgement of every command received -- sample -> applied voltage exactly one tick -- and this
    driver), amplifier_node (mock backend), position_controller_node with config/position_controller.yaml.
    Noise-free laser (quantisation only), so the measured displacement is the true one."""
    import rclpy
    from builtin_interfaces.msg import Duration
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Range
    from std_msgs.msg import Float64, Header
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from dea_ros.nodes.common import COMMAND_QOS, SENSOR_QOS
    from dea_ros.cli.rig import RigProcesses
    from dea_ros.sim import free_udp_port

    ns = "/dea_bench"
    port = free_udp_port()   # for the mock amplifier
    rig = RigProcesses(namespace=ns, quiet=True)
    rig.start("mock_hardware_node", {
        "params_file": args.truth, "amplifier_port": port, "noise_m": 0.0, "sample_rate_hz": 1000.0,
        "publish_clock": True, "real_time_factor": 1.0, "laser_output": "topic", "clock_rate_hz": 1000.0,
        "lockstep_timeout_s": 1.5, "amplifier_deadman_s": 1.5,
        # the clock waits for the command of each sample to reach the amplifier (fixed 1-tick delay) and for
        # this driver (its setpoints go out at the sample they are planned for)
        "lockstep_topics": "[amplifier_node/command_received, bench_driver/tick_done]"})
    time.sleep(1.0)
    rig.start("amplifier_node", {"use_sim_time": True, "params_file": params_file, "backend": "mock",
                                 "mock_port": port, "autostart": True, "update_rate_hz": 1000.0,
                                 "slew_rate_V_per_s": args.slew, "ramp_down_rate_V_per_s": 20000.0,
                                 "watchdog_timeout_s": 0.5})
    cfg = str(ROOT / "config" / "position_controller.yaml")
    ctl_cmd = [sys.executable, "-m", "dea_ros.nodes.position_controller_node", "--ros-args", "--params-file", cfg,
               "-p", "use_sim_time:=true", "-p", f"params_file:={params_file}", "-p", "autostart:=true",
               "-p", "lockstep_ack:=true", "-p", f"slew_rate_V_per_s:={args.slew}",
               "-p", "publish_stamped_command:=true", "-r", f"__ns:={ns}"]
    if args.mock_loop_delay_ms is not None:
        ctl_cmd[-2:-2] = ["-p", f"loop_delay_s:={args.mock_loop_delay_ms * 1e-3}"]
    ctl = subprocess.Popen(ctl_cmd, env=rig.env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rclpy.init()
    node = Node("bench_driver", namespace=ns, parameter_overrides=[Parameter("use_sim_time", value=True)])
    samples = []
    events = []                               # (time, kind, value)
    ack = node.create_publisher(Header, "~/tick_done", 10)
    set_pub = node.create_publisher(Float64, "displacement_setpoint", COMMAND_QOS)
    traj_pub = node.create_publisher(JointTrajectory, "joint_trajectory", COMMAND_QOS)
    sine_f, sine_start = 10.0, None
    sine = None
    plan = [(0.5 + k * HOLD_S, "set", lv) for k, lv in enumerate(levels)]
    t_mid = plan[-1][0] + HOLD_S
    plan.append((t_mid, "set", mid))
    plan.append((t_mid + 0.5, "sine", None))
    t_end = t_mid + 0.5 + 0.01 + 2.0 / sine_f + 1.2
    state = {"t0": None, "i": 0}

    def on_sample(msg):
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if state["t0"] is None:
            ack.publish(Header(stamp=msg.header.stamp, frame_id="bench_driver"))
            if not (applied and commands):
                return   # the plan starts once the amplifier applies and the controller commands
            state["t0"] = t
        rel = t - state["t0"]
        samples.append((rel, msg.range))
        while state["i"] < len(plan) and rel >= plan[state["i"]][0]:
            _, kind, value = plan[state["i"]]
            state["i"] += 1
            if kind == "set":
                set_pub.publish(Float64(data=float(value)))
                events.append((rel, "set", value))
            else:
                nonlocal sine, sine_start
                sine_start = rel + 0.01
                sine = SineReference(mid, 30e-6, sine_f, start_s=sine_start, fade_periods=2.0)
                traj = JointTrajectory(joint_names=["dea_joint"])
                start_abs = state["t0"] + sine_start
                traj.header.stamp.sec = int(start_abs)
                traj.header.stamp.nanosec = int(round((start_abs - int(start_abs)) * 1e9))
                for tt in np.arange(0.002, 2.0 / sine_f + 1.2, 0.002):
                    d, v, a = sine.sample(sine_start + tt)
                    pt = JointTrajectoryPoint(positions=[d], velocities=[v], accelerations=[a])
                    pt.time_from_start = Duration(sec=int(tt), nanosec=int(round((tt - int(tt)) * 1e9)))
                    traj.points.append(pt)
                traj_pub.publish(traj)
                events.append((rel, "sine", sine_start))
        ack.publish(Header(stamp=msg.header.stamp, frame_id="bench_driver"))

    node.create_subscription(Range, "displacement", on_sample, SENSOR_QOS)
    from sensor_msgs.msg import BatteryState

    applied, commands = [], []    # (stamp, V): amplifier output when applied; command with its sample's stamp
    node.create_subscription(BatteryState, "voltage", lambda m: applied.append(
        (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, float(m.voltage))), SENSOR_QOS)
    node.create_subscription(BatteryState, "position_controller_node/command_stamped", lambda m: commands.append(
        (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, float(m.voltage))), SENSOR_QOS)
    from diagnostic_msgs.msg import DiagnosticArray

    mock_diag = {}
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: mock_diag.update(
        {kv.key: kv.value for st in m.status if st.name.startswith("mock_hardware_node") for kv in st.values}), 10)
    wall0 = time.monotonic()
    try:
        while (not samples or samples[-1][0] < t_end) and time.monotonic() - wall0 < 1800:
            rclpy.spin_once(node, timeout_sec=0.05)
            if rig.check_alive() or ctl.poll() is not None:
                raise RuntimeError(f"mock rig: {rig.check_alive() or 'position_controller_node exited'}")
    finally:
        wall = time.monotonic() - wall0
        ctl.send_signal(2)
        try:
            ctl.wait(timeout=10)
        except subprocess.TimeoutExpired:
            ctl.kill()
        rig.stop()
        node.destroy_node()
        rclpy.shutdown()
    t = np.array([x[0] for x in samples])
    d = np.array([x[1] for x in samples])
    sim_s = float(t[-1]) if t.size else 0.0
    steps = []
    set_events = [e for e in events if e[1] == "set"]
    for k in range(1, len(levels)):
        t_cmd = set_events[k][0]
        m = (t >= t_cmd) & (t < t_cmd + HOLD_S)
        tt, e = t[m] - t_cmd, d[m] - levels[k]
        size = levels[k] - levels[k - 1]
        over = max(0.0, float(np.max(np.sign(size) * e))) / abs(size) * 100
        outside = np.nonzero(np.abs(e) > 0.02 * abs(size))[0]
        settle = math.inf if outside.size and outside[-1] >= tt.size - 1 else \
            (float(tt[outside[-1]] + 1e-3) if outside.size else 0.0)
        steps.append((over, settle))
    m = (t >= sine_start + 2.0 / sine_f + 0.1) & (t <= sine_start + 2.0 / sine_f + 1.1)
    err = d[m] - sine.sample_many(t[m])[0]
    # sample -> applied voltage, in ticks: an applied voltage equal to exactly one command (not slew-limited)
    delays = loop_delays([c for c in commands if c[0] >= state["t0"]], [a for a in applied if a[0] >= state["t0"]],
                         1e-3, args.slew)
    vals, counts = np.unique(np.array(delays), return_counts=True) if delays else (np.array([]), np.array([]))
    delay_text = ", ".join(f"{v:g} tick{'s' if v != 1 else ''} ({v:g} ms): {c} of {len(delays)}"
                           for v, c in zip(vals, counts))
    return {"delay": delay_text, "lockstep_timeouts": mock_diag.get("lockstep_timeouts", "?"), "steps": steps,
            "sine_rms": float(np.sqrt(np.mean(err ** 2))), "sine_max": float(np.max(np.abs(err))),
            "sim_s": sim_s, "wall_s": wall, "samples": int(t.size)}


# ----------------------------------------------------------------------------- main
def fmt_s(x):
    return "never" if not math.isfinite(x) else f"{x * 1e3:.0f}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--params", default=None, help="identified params.yaml (default: newest runs/*/params.yaml)")
    ap.add_argument("--truth", default=str(ROOT / "config" / "rig" / "mock_membrane.yaml"))
    ap.add_argument("--slew", type=float, default=1e5, help="amplifier slew limit, V/s (config/amplifier.yaml)")
    ap.add_argument("--latency-ms", type=float, default=0.5, help="sample -> command at the amplifier, ms")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--pid-evals", type=int, default=120)
    ap.add_argument("--timing-s", type=float, default=30.0, help="0: skip the node timing")
    ap.add_argument("--timing-only", action="store_true", help="only part 2 (writes control_timing.md)")
    ap.add_argument("--mock-loop-delay-ms", type=float, default=None,
                    help="loop_delay_s of the node on the mock rig (default: config/position_controller.yaml)")
    ap.add_argument("--mock-rig-only", action="store_true",
                    help="only (c) through the ROS mock rig in simulated time (writes control_mock_rig.md)")
    ap.add_argument("--drift-only", action="store_true",
                    help="only the drift cases of issue 23 (bench_drift.py; writes control_drift.md)")
    ap.add_argument("--out", default=None, help="default bench/results/control.md (control_timing.md)")
    args = ap.parse_args()
    params_file = args.params
    if params_file is None:
        found = sorted(glob.glob(str(ROOT / "runs" / "*" / "params.yaml")), key=os.path.getmtime)
        if not found:
            sys.exit("no runs/*/params.yaml: run ./scripts/run_demo.sh first or pass --params")
        params_file = found[-1]
    if args.out is None:
        args.out = str(HERE / "results" / ("control_timing.md" if args.timing_only else
                                           "control_drift.md" if args.drift_only else
                                           "control_mock_rig.md" if args.mock_rig_only else "control.md"))
    ident = load_parameters(params_file)
    truth = load_parameters(args.truth)
    results_dir = Path(args.out).parent
    results_dir.mkdir(parents=True, exist_ok=True)
    if Path(params_file).resolve() != (results_dir / "control_params.yaml").resolve():
        shutil.copy(params_file, results_dir / "control_params.yaml")

    latency = args.latency_ms * 1e-3
    phase = latency + 2.5e-4                          # the amplifier's next update after the command arrives
    loop_delay = phase                                # acquisition -> voltage applied
    cfg = ControllerConfig(U_MAX, args.slew, loop_delay_s=loop_delay)
    inv = ModelInverse(ident, U_MAX)
    truth_inv = ModelInverse(truth, U_MAX)
    scen, mid = scenarios(inv, truth_inv.reachable_range_m)
    levels = scen[0][2]
    rig0 = SimulatedRig(truth, U_MAX, slew_rate_V_per_s=args.slew, latency_s=latency, amplifier_phase_s=phase)

    lines = [f"Machine: {machine()}", ""]
    if args.mock_rig_only:
        os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
        r = mock_rig(args, params_file, levels, mid)
        lines += [f"### (c) through the ROS mock rig in simulated time ({r['sim_s']:.1f} s simulated in "
                  f"{r['wall_s']:.0f} s wall, {r['samples']} laser samples, lockstep; noise-free laser; slew "
                  f"{args.slew:g} V/s; config/position_controller.yaml"
                  + (f", loop_delay_s {args.mock_loop_delay_ms:g} ms" if args.mock_loop_delay_ms is not None else "")
                  + ")", "",
                  "| step | overshoot [%] | 2 % settling [ms] |", "|---|---|---|"]
        for (a, b), (over, settle) in zip(zip(levels[:-1], levels[1:]), r["steps"]):
            lines.append(f"| {a * 1e6:.0f} -> {b * 1e6:.0f} um | {over:.1f} | {fmt_s(settle)} |")
        lines += ["", "10 Hz 30 um sine sent as a JointTrajectory (2 ms points): "
                      f"RMS error {r['sine_rms'] * 1e6:.2f} um, "
                      f"max {r['sine_max'] * 1e6:.2f} um.", "",
                  f"Sample -> voltage applied by the amplifier (commands matched by value, `loop_delays`): "
                  f"{r['delay']}; lockstep timeouts: {r['lockstep_timeouts']}."]
        args.timing_s = 0
    elif args.drift_only:
        from bench_drift import callback_cost_lines, drift_lines
        lines += callback_cost_lines(ident, cfg, rig0)
        lines += drift_lines(ident, params_file, cfg, rig0)
        args.timing_s = 0
    elif not args.timing_only:
        lines += tracking(args, ident, truth, params_file, cfg, inv, scen, mid, levels, rig0, phase)
    if args.timing_s > 0:
        lines += timing(args, ident, params_file)
    text = "\n".join(lines) + "\n"
    print(text)
    Path(args.out).write_text(text)


def tracking(args, ident, truth, params_file, cfg, inv, scen, mid, levels, rig0, phase):
    t0 = time.perf_counter()
    gains, pid_cost, nfev = tune_pid(truth, args.slew, levels, mid, seed=99, evals=args.pid_evals)
    t_tune = time.perf_counter() - t0
    print(f"PID tuned in {t_tune:.0f} s ({nfev} evaluations): kp {gains[0]:.4g} V/m, ki {gains[1]:.4g} V/(m s), "
          f"kd {gains[2]:.4g} V s/m, Tf {gains[3] * 1e3:.3f} ms; training IAE {pid_cost:.3f} um", flush=True)

    def controllers():
        return [OpenLoop(inv), VoltagePID(*gains, args.slew), ModelBased(ident, cfg)]

    names = [c.name for c in controllers()]
    rows = {}          # (scenario, controller) -> list over seeds of metric dicts
    step_rows = {}
    for seed in [None] + list(range(1, args.seeds + 1)):
        rig = dataclasses.replace(rig0, seed=seed or 0, noise_m=0.0 if seed is None else rig0.noise_m,
                                  quantisation_m=0.0 if seed is None else rig0.quantisation_m)
        for name, ref, extra in scen:
            for ctl in controllers():
                if name == "steps":
                    res = run(rig, ctl, ref, HOLD_S * len(levels), levels[0], "steps", levels)
                    sm = step_metrics(res, levels)
                    e = res.true_m - ref.sample_many(res.time_s)[0]
                    mask = res.time_s >= HOLD_S
                    urms, rate = effort(res, mask)
                    step_rows.setdefault(("noise-free" if seed is None else "noisy", ctl.name), []).append(
                        {"steps": sm, "rms_m": float(np.sqrt(np.mean(e[mask] ** 2))),
                         "max_m": float(np.max(np.abs(e[mask]))), "u_rms": urms, "u_rate": rate})
                else:
                    if seed is None:
                        continue
                    window = extra
                    res = run(rig, ctl, ref, window[1] + 0.01, ref.sample(0.0)[0], "track")
                    rms, mx, mask = track_metrics(res, ref, window)
                    urms, rate = effort(res, mask)
                    rows.setdefault((name, ctl.name), []).append({"rms_m": rms, "max_m": mx, "u_rms": urms,
                                                                  "u_rate": rate})
        print(f"seed {seed}: done ({time.perf_counter() - t0:.0f} s)", flush=True)

    med = lambda xs: float(np.median(xs))  # noqa: E731
    lines = [f"Controller model: `{params_file}` (identified by the demo); plant: `{args.truth}` (the mock's truth); "
             f"amplifier slew {args.slew:g} V/s, max {U_MAX:g} V; command at the amplifier {args.latency_ms:g} ms "
             f"after the sample, applied {phase * 1e3:g} ms after it; laser 1 kHz, noise 1 um, quantisation 0.156 um; "
             f"medians over {args.seeds} noise seeds.", "",
             f"PID without the model (b): Nelder-Mead over log-gains, {nfev} closed-loop evaluations "
             f"({t_tune:.0f} s) of the IAE on the plant (steps, 5 and 10 Hz sines, seed 99): kp {gains[0]:.4g} V/m, "
             f"ki {gains[1]:.4g} V/(m s), kd {gains[2]:.4g} V s/m, Tf {gains[3] * 1e3:.3f} ms.", "",
             f"(c) feedback design: {ModelBased(ident, cfg).ctl.gains.describe()}", "",
             f"### 50 um steps across the reachable range ({len(levels) - 1} steps: "
             f"{' -> '.join(f'{x * 1e6:.0f}' for x in levels)} um)", "",
             "| controller | run | overshoot median / max [%] | 2 % settling median / max [ms] | RMS error [um] | "
             "max error [um] | RMS voltage [V] | mean abs du/dt [V/s] |",
             "|---|---|---|---|---|---|---|---|"]
    for run_kind in ("noise-free", "noisy"):
        for n in names:
            rs = step_rows[(run_kind, n)]
            over = [s["overshoot_pct"] for r in rs for s in r["steps"]]
            sett = [s["settling_s"] for r in rs for s in r["steps"]]
            lines.append(f"| {n} | {run_kind} | {np.median(over):.1f} / {np.max(over):.1f} | "
                         f"{fmt_s(np.median(sett))} / {fmt_s(np.max(sett))} | "
                         f"{med([r['rms_m'] for r in rs]) * 1e6:.2f} | "
                         f"{med([r['max_m'] for r in rs]) * 1e6:.1f} | {med([r['u_rms'] for r in rs]):.0f} | "
                         f"{med([r['u_rate'] for r in rs]):.3g} |")
    lines += ["", "Per step (noise-free run), overshoot % / settling ms:", "",
              "| controller | " + " | ".join(f"{a * 1e6:.0f}->{b * 1e6:.0f}" for a, b in zip(levels[:-1], levels[1:]))
              + " |", "|---|" + "---|" * (len(levels) - 1)]
    for n in names:
        st = step_rows[("noise-free", n)][0]["steps"]
        lines.append(
            f"| {n} | " + " | ".join(f"{s['overshoot_pct']:.1f} / {fmt_s(s['settling_s'])}" for s in st) + " |")
    lines += ["", "### Tracking: 30 um sines around mid-stroke, point-to-point (100 um in 60 ms and back)", "",
              "| reference | controller | RMS error [um] | max error [um] | RMS voltage [V] | mean abs du/dt [V/s] | "
              "RMS error vs (c) |", "|---|---|---|---|---|---|---|"]
    for name, _, _ in scen[1:]:
        c_rms = med([r["rms_m"] for r in rows[(name, names[2])]])
        for n in names:
            rs = rows[(name, n)]
            r_rms = med([r["rms_m"] for r in rs])
            lines.append(f"| {name} | {n} | {r_rms * 1e6:.2f} | {med([r['max_m'] for r in rs]) * 1e6:.2f} | "
                         f"{med([r['u_rms'] for r in rs]):.0f} | {med([r['u_rate'] for r in rs]):.3g} | "
                         f"{r_rms / c_rms:.1f}x |")
    return lines


def timing(args, ident, params_file):
    lines = []
    if True:
        env = dict(os.environ)
        env.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
        os.environ.update(env)
        from bench_nodes import bench_latency

        d_hold = float(static_equilibrium(ident, 2000.0).displacement_m)
        ctl_t = bench_controller_timing(args.timing_s, env, params_file, d_hold)
        model_t = bench_latency(args.timing_s, env)
        load = os.getloadavg()
        lines += ["", f"### Loop timing at 1 kHz, {args.timing_s:g} s each, separate processes (same run)", "",
                  f"Load average at the end: {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1/5/15 min) on "
                  f"{os.cpu_count()} cores.", "",
                  "| node | sent | received | latency median [ms] | p99 [ms] | max [ms] | command period median [ms] | "
                  "p1-p99 [ms] | std [ms] |", "|---|---|---|---|---|---|---|---|---|",
                  f"| position_controller_node (sample -> command) | {ctl_t['sent']} | {ctl_t['received']} | "
                  f"{ctl_t['median_ms']:.3f} | {ctl_t['p99_ms']:.3f} | {ctl_t['max_ms']:.2f} | "
                  f"{ctl_t['period_median_ms']:.3f} | {ctl_t['period_p1_ms']:.3f}-{ctl_t['period_p99_ms']:.3f} | "
                  f"{ctl_t['period_std_ms']:.3f} |",
                  f"| model_node (voltage -> prediction) | {model_t['sent']} | {model_t['received']} | "
                  f"{model_t['median_ms']:.3f} | {model_t['p99_ms']:.3f} | {model_t['max_ms']:.2f} | | | |",
                  "", "Latency ratio controller / model_node: "
                      f"median {ctl_t['median_ms'] / model_t['median_ms']:.2f}x, "
                  f"p99 {ctl_t['p99_ms'] / model_t['p99_ms']:.2f}x."]
    return lines


if __name__ == "__main__":
    main()
