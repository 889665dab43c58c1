"""Attacks on amplifier_node from ANOTHER PROCESS on the same ROS graph, judged on what the amplifier
received (the mock backend's UDP datagrams, captured in this process).

The node process is started as a user starts it (``python -m dea_ros.nodes.amplifier_node --ros-args
...``, the console script's body). This test process attacks it: parameter set services, lifecycle
change_state services, /clock, commands, signals, and a fuzzer mixing them. Every test asserts that
what reached the amplifier never exceeded the start-up ceiling, never moved faster than the slew
limit, and that silence ends at 0 V. The README's "Safety" section points here.
"""
import importlib.util
import math
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

from dea_ros.model import preset
from dea_ros.nodes.common import COMMAND_QOS
from fakes import AMPLIFIER_SABOTEUR

HERE = Path(__file__).parent
_spec = importlib.util.spec_from_file_location("amp_harness", HERE / "amp_harness.py")
H = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(H)

SLEW = 20000.0  # V/s (harness default)
CEILING = 0.9 * 100e6 * 35e-6  # A2: margin x 100 V/um x 35 um (3149.9999999999995 V)
PERIOD = 1.0 / 250.0  # harness update rate


class Attacker:
    """This process's node: publishes on the amplifier's namespace and calls its services."""

    def __init__(self, ctx, ns):
        self.node = Node("attacker", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.cmd = self.node.create_publisher(Float64, f"{ns}/voltage_cmd", COMMAND_QOS)
        self.clock = self.node.create_publisher(Clock, f"{ns}/clock", 10)
        self.global_clock = self.node.create_publisher(Clock, "/clock", 10)
        self.set_params = self.node.create_client(SetParameters, f"{ns}/amplifier_node/set_parameters")
        self.get_params = self.node.create_client(GetParameters, f"{ns}/amplifier_node/get_parameters")
        self.change_state = self.node.create_client(ChangeState, f"{ns}/amplifier_node/change_state")

    def command_for(self, voltage_V, duration_s=None, until=None, timeout_s=15.0):
        """Publish a command at ~100 Hz for ``duration_s`` or until ``until()``; True if it came."""
        t_end = time.monotonic() + (duration_s if duration_s is not None else timeout_s)
        while time.monotonic() < t_end:
            self.cmd.publish(Float64(data=float(voltage_V)))
            self.ex.spin_once(timeout_sec=0.01)
            if until is not None and until():
                return True
        return until is None

    def call(self, client, request):
        return H.call(self.node, self.ex, client, request)

    def publish_clock(self, t_s, also_global=True):
        msg = Clock()
        t_s = max(0.0, min(t_s, 2.0**31 - 1.0))
        msg.clock.sec = int(math.floor(t_s))
        msg.clock.nanosec = min(int((t_s - math.floor(t_s)) * 1e9), 999_999_999)
        self.clock.publish(msg)
        if also_global:
            self.global_clock.publish(msg)

    def close(self):
        self.ex.shutdown()
        self.node.destroy_node()


@pytest.fixture
def capture():
    cap = H.Capture()
    yield cap
    cap.close()


def _membrane_file(path, **changes):
    data = preset("A2").to_dict()
    data.update(name="film", **changes)
    path.write_text(yaml.safe_dump(data))
    return path


def test_parameter_and_lifecycle_attacks_cannot_raise_the_voltage(ros_context, capture, tmp_path):
    """Issue 9's reproduction: max_voltage_V=30000, margin=1, slew 1e7, ramp 1 V/s, watchdog 60 s,
    params_file -> a 1 mm membrane, use_sim_time, then deactivate/cleanup/configure/activate from
    another node. It used to apply 20 kV. Every set is refused; the membrane file rewritten on disk is
    not re-read; the ceiling holds; reads report what is enforced; silence ends at 0 V."""
    membrane = _membrane_file(tmp_path / "film.yaml")
    thick = _membrane_file(tmp_path / "thick.yaml", thickness_m=1e-3)
    proc = H.start_amplifier(capture.port, "/atk_param", params_file=str(membrane))
    attacker = Attacker(ros_context, "/atk_param")
    try:
        assert attacker.command_for(3000.0, until=lambda: capture.last_V() == 3000.0, timeout_s=H.READY_TIMEOUT_S), \
            H.stderr_of(proc)
        attacks = [("max_voltage_V", 30000.0), ("margin", 1.0), ("slew_rate_V_per_s", 1e7),
                   ("ramp_down_rate_V_per_s", 1.0), ("watchdog_timeout_s", 60.0), ("params_file", str(thick)),
                   ("backend", "inprocess"), ("use_sim_time", True), ("amplifier_gain_V_per_V", 100.0),
                   ("enforced_max_voltage_V", 30000.0), ("autostart", False), ("update_rate_hz", 1.0)]
        for name, value in attacks:
            response = attacker.call(attacker.set_params, H.set_parameter_request(name, value))
            assert response is not None, f"no answer to set {name}"
            result = response.results[0]
            assert not result.successful and ("fixed at start-up" in result.reason or "read-only" in result.reason), \
                (name, result.reason)
        _membrane_file(membrane, thickness_m=1e-3)  # the file is rewritten on disk: a 1 mm film
        for transition in (Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP,
                           Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            response = attacker.call(attacker.change_state, H.transition_request(transition))
            assert response is not None and response.success, transition
        names = ["max_voltage_V", "margin", "slew_rate_V_per_s", "use_sim_time", "enforced_max_voltage_V"]
        response = attacker.call(attacker.get_params, H.get_parameters_request(names))
        values = dict(zip(names, (H.parameter_value(v) for v in response.values)))
        assert values == {"max_voltage_V": 0.0, "margin": 0.9, "slew_rate_V_per_s": SLEW, "use_sim_time": False,
                          "enforced_max_voltage_V": pytest.approx(CEILING)}
        attacker.command_for(20000.0, duration_s=0.4)  # refused: above the ceiling
        attacker.command_for(3200.0, duration_s=0.4)
        assert attacker.command_for(CEILING, until=lambda: capture.last_V() == CEILING)
        # silence (the commander dies); use_sim_time was refused, so no /clock is needed to reach 0 V
        assert capture.wait_for(lambda c: c.last_V() == 0.0, timeout_s=10.0)
        data = capture.snapshot()
        H.check_safe(data, CEILING, SLEW)
        assert max(d.voltage_V for d in data) == CEILING
        assert len(H.sessions(data)) == 2  # the reconfiguration opened a second session, at 0 V
    finally:
        attacker.close()
        H.stop(proc)
    assert capture.last_V() == 0.0


def test_every_catchable_signal_ramps_to_zero_before_exit(ros_context):
    """Issue 9: SIGHUP (a closed SSH session) and SIGQUIT left 3 kV; SIGINT/SIGTERM ramped down.
    Four node processes (one per signal) at 2 kV, each signalled: each ramps to 0 V, then exits 0."""
    signals = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT]
    captures = {sig: H.Capture() for sig in signals}
    procs = {sig: H.start_amplifier(captures[sig].port, f"/atk_{sig.name.lower()}", watchdog_timeout_s=2.0)
             for sig in signals}
    attackers = {sig: Attacker(ros_context, f"/atk_{sig.name.lower()}") for sig in signals}
    try:
        t_end = time.monotonic() + H.READY_TIMEOUT_S
        while time.monotonic() < t_end and not all(c.last_V() == 2000.0 for c in captures.values()):
            for attacker in attackers.values():
                attacker.command_for(2000.0, duration_s=0.01)
        for sig in signals:
            assert captures[sig].last_V() == 2000.0, (sig.name, H.stderr_of(procs[sig]))
        for sig in signals:
            procs[sig].send_signal(sig)
        for sig in signals:
            procs[sig].wait(timeout=20)
    finally:
        for attacker in attackers.values():
            attacker.close()
        for proc in procs.values():
            H.stop(proc, signal.SIGKILL)
    time.sleep(0.1)
    for sig in signals:
        assert procs[sig].returncode == 0, (sig.name, H.stderr_of(procs[sig]))
        data = captures[sig].snapshot()
        captures[sig].close()
        values = [d.voltage_V for d in data]
        assert values[-1] == 0.0, sig.name
        tail = values[len(values) - 1 - values[::-1].index(2000.0):]
        assert all(b <= a for a, b in zip(tail, tail[1:])) and len(tail) > 10, sig.name  # a ramp, not a step
        H.check_safe(data, CEILING, SLEW)


def test_sigkill_the_mock_amplifier_drops_to_zero_by_itself(ros_context):
    """SIGKILL cannot be caught: the last datagram stays at 2 kV. The mock amplifier's dead-man (as a
    real rig's interlock) brings its output to 0 V when the datagrams stop."""
    cap = H.Capture(deadman_timeout_s=0.3)
    proc = H.start_amplifier(cap.port, "/atk_kill", watchdog_timeout_s=2.0)
    attacker = Attacker(ros_context, "/atk_kill")
    try:
        assert attacker.command_for(2000.0, until=lambda: cap.last_V() == 2000.0, timeout_s=H.READY_TIMEOUT_S), \
            H.stderr_of(proc)
        assert cap.receiver.applied_voltage_V() == 2000.0
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        assert cap.last_V() == 2000.0  # what the killed process left on the link
        assert cap.wait_for(lambda c: c.receiver.applied_voltage_V() == 0.0, timeout_s=5.0)
        assert cap.receiver.deadman_trip_count == 1
        H.check_safe(cap.snapshot(), CEILING, SLEW)
    finally:
        attacker.close()
        H.stop(proc, signal.SIGKILL)
        cap.close()


@pytest.mark.parametrize("mode", ["raise", "shutdown"])
def test_uncaught_exception_or_executor_shutdown_ramps_to_zero(capture, mode):
    proc = subprocess.Popen([sys.executable, str(AMPLIFIER_SABOTEUR), mode, str(capture.port),
                             f"/atk_{mode}"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert "at 2 kV" in out, err
    if mode == "raise":
        assert proc.returncode != 0 and "saboteur: an uncaught exception" in err
    time.sleep(0.1)
    values = capture.voltages()
    assert 2000.0 in values and values[-1] == 0.0, err
    tail = values[values.index(2000.0):]
    assert all(b <= a for a, b in zip(tail, tail[1:])) and len(tail) > 10
    H.check_safe(capture.snapshot(), CEILING, SLEW)


def test_simulated_clock_jumps_move_the_output_one_update_at_most(ros_context, capture):
    """Issue 9: a /clock jump of +0.4 s moved the output 0 -> 3000 V in one datagram. With simulated time
    (mock backend only) each update advances the controller by one period at most, whatever the clock
    does; when the clock stops the wall-clock backstop ramps to 0 V."""
    proc = H.start_amplifier(capture.port, "/atk_sim", sim_time=True, watchdog_timeout_s=0.5)
    attacker = Attacker(ros_context, "/atk_sim")
    t = 1000.0
    try:
        def tick_and_command(dt, voltage):
            nonlocal t
            t += dt
            attacker.publish_clock(t, also_global=False)
            attacker.cmd.publish(Float64(data=voltage))
            t_tick = time.monotonic()
            attacker.ex.spin_once(timeout_sec=0.004)
            time.sleep(max(0.0, PERIOD - (time.monotonic() - t_tick)))  # a clock master paced by the wall clock

        t_end = time.monotonic() + H.READY_TIMEOUT_S
        while len(capture.voltages()) < 3 and time.monotonic() < t_end:  # the update follows the clock
            tick_and_command(PERIOD, 0.0)
        assert len(capture.voltages()) >= 3, H.stderr_of(proc)
        for _ in range(50):  # normal ticks, then jumps while commanding 3 kV
            tick_and_command(PERIOD, 0.0)
        for dt in [0.4, 0.4, -100.0, 1e6, 0.4, PERIOD, 5.0, -0.4, 0.4] * 5:
            tick_and_command(dt, 3000.0)
        for _ in range(100):
            tick_and_command(PERIOD, 3000.0)
        assert capture.last_V() > 0.0, H.stderr_of(proc)
        # the clock master dies: no /clock, no commands -> the backstop ramps to 0 V on the wall clock
        assert capture.wait_for(lambda c: c.last_V() == 0.0, timeout_s=15.0)
        H.check_safe(capture.snapshot(), CEILING, SLEW, sim_period_s=PERIOD)
    finally:
        attacker.close()
        H.stop(proc)


def _fuzz(ros_context, capture, seed, sim_time):
    """Random commands, parameter sets, lifecycle transitions and /clock messages from this process,
    for a few seconds; then silence. Returns the datagrams."""
    rng = random.Random(seed)
    ns = f"/fuzz_{seed}"
    proc = H.start_amplifier(capture.port, ns, sim_time=sim_time, watchdog_timeout_s=0.3)
    attacker = Attacker(ros_context, ns)
    t_sim = 100.0
    names = ["max_voltage_V", "margin", "slew_rate_V_per_s", "ramp_down_rate_V_per_s", "watchdog_timeout_s",
             "params_file", "backend", "use_sim_time", "amplifier_gain_V_per_V", "update_rate_hz",
             "enforced_max_voltage_V", "mock_port", "no_such_parameter"]
    values = [30000.0, 1.0, 1e7, 1.0, 60.0, "LP1", True, 0, -1.0, math.inf, math.nan, "x", 1e308]
    transitions = [Transition.TRANSITION_ACTIVATE] * 3 + [
        Transition.TRANSITION_DEACTIVATE, Transition.TRANSITION_CLEANUP, Transition.TRANSITION_CONFIGURE]
    futures = []

    def clock_tick(dt):
        nonlocal t_sim
        t_sim = max(0.0, t_sim + dt)
        attacker.publish_clock(t_sim)

    try:
        t_end = time.monotonic() + H.READY_TIMEOUT_S
        while capture.last_V() is None and time.monotonic() < t_end:
            clock_tick(PERIOD)
            attacker.ex.spin_once(timeout_sec=0.004)
        assert capture.last_V() is not None, H.stderr_of(proc)
        assert attacker.set_params.wait_for_service(timeout_sec=10.0)
        assert attacker.change_state.wait_for_service(timeout_sec=10.0)
        # a deterministic start: high voltage
        t_end = time.monotonic() + 10.0
        while capture.last_V() != 2500.0 and time.monotonic() < t_end:
            clock_tick(PERIOD)
            attacker.cmd.publish(Float64(data=2500.0))
            attacker.ex.spin_once(timeout_sec=0.004)
        assert capture.last_V() == 2500.0
        t_end = time.monotonic() + 3.0
        while time.monotonic() < t_end:
            r = rng.random()
            if r < 0.45:
                kind = rng.random()
                if kind < 0.15:
                    value = rng.choice([math.nan, math.inf, -math.inf, -1.0, 1e9, CEILING, CEILING + 1e-9, 0.0])
                elif kind < 0.3:
                    value = rng.uniform(-5000.0, 40000.0)
                else:
                    value = rng.uniform(0.0, CEILING)
                for _ in range(rng.choice([1, 1, 1, 10])):
                    attacker.cmd.publish(Float64(data=value))
            elif r < 0.80:
                clock_tick(rng.choice([PERIOD, PERIOD, PERIOD, 0.4, -rng.uniform(0, 50), 1e14, rng.uniform(0, 5)]))
            elif r < 0.90:
                request = H.set_parameter_request(rng.choice(names), rng.choice(values))
                futures.append(attacker.set_params.call_async(request))
            elif r < 0.93:
                futures.append(attacker.change_state.call_async(H.transition_request(rng.choice(transitions))))
            attacker.ex.spin_once(timeout_sec=rng.choice([0.0, 0.002, 0.01]))
        # silence: no commands; in simulated time the clock master dies too
        n_futures = len(futures)
        t_end = time.monotonic() + 15.0
        while time.monotonic() < t_end and not (capture.last_V() == 0.0 and all(f.done() for f in futures)):
            attacker.ex.spin_once(timeout_sec=0.01)
        assert capture.last_V() == 0.0 and n_futures > 10
        answered = [f.result() for f in futures if f.done() and f.result() is not None]
        assert not any(getattr(res, "successful", False)
                       for a in answered if hasattr(a, "results") for res in a.results), "a parameter set succeeded"
        return capture.snapshot()
    finally:
        attacker.close()
        H.stop(proc)


def test_fuzz_the_node_from_another_process(ros_context, capture):
    data = _fuzz(ros_context, capture, seed=11, sim_time=False)
    H.check_safe(data, CEILING, SLEW)
    assert max(d.voltage_V for d in data) >= 2500.0


def test_fuzz_the_node_in_simulated_time(ros_context, capture):
    data = _fuzz(ros_context, capture, seed=12, sim_time=True)
    H.check_safe(data, CEILING, SLEW, sim_period_s=PERIOD)
    assert max(d.voltage_V for d in data) >= 2500.0


def test_console_script_refuses_a_configuration_slip_with_exit_code_2(tmp_path):
    membrane = _membrane_file(tmp_path / "thick.yaml", thickness_m=2.7e-4, breakdown_field_V_per_m=1e8)
    proc = H.start_amplifier(1, "/atk_cli", params_file=str(membrane))
    try:
        proc.wait(timeout=60)
        err = H.stderr_of(proc)
    finally:
        proc.kill()
    assert proc.returncode == 2, err
    assert "rated output" in err and "thickness or breakdown-field slip" in err
