"""Harness for attacking amplifier_node from another process and judging what reached the amplifier.

The node runs as the user runs it (``python -m dea_ros.nodes.amplifier_node --ros-args ...``, the
console script's body) with the mock backend; its UDP datagrams go to a :class:`Capture` in the
test process, which records every one (voltage, sender session, sequence, sender time). The test
process is the attacker: it publishes commands and ``/clock``, calls the node's parameter and
lifecycle services, and sends signals. Loaded by path (the suite runs with --import-mode=importlib).
"""
from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

from dea_ros.sim.amplifier_receiver import MockAmplifierReceiver

READY_TIMEOUT_S = 30.0  # a loaded CI machine: process start, imports, discovery


class Capture:
    """Records every datagram the amplifier node sends (a background thread drains the socket)."""

    def __init__(self, deadman_timeout_s=None):
        self.receiver = MockAmplifierReceiver(port=0, deadman_timeout_s=deadman_timeout_s)
        self.port = self.receiver.port
        self.datagrams = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            got = self.receiver.poll_all()
            if got:
                with self._lock:
                    self.datagrams.extend(got)
            time.sleep(0.002)

    def snapshot(self):
        with self._lock:
            return list(self.datagrams)

    def voltages(self):
        return [d.voltage_V for d in self.snapshot()]

    def last_V(self):
        data = self.snapshot()
        return data[-1].voltage_V if data else None

    def wait_for(self, predicate, timeout_s=10.0):
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            if predicate(self):
                return True
            time.sleep(0.01)
        return predicate(self)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.receiver.close()


def start_amplifier(port, namespace, sim_time=False, **params):
    """The amplifier node process (mock backend -> ``port``), autostarted, in ``namespace``."""
    base = dict(backend="mock", mock_port=port, autostart=True, params_file="A2", update_rate_hz=250.0,
                slew_rate_V_per_s=20000.0, ramp_down_rate_V_per_s=10000.0, watchdog_timeout_s=0.3)
    base.update(params)
    cmd = [sys.executable, "-m", "dea_ros.nodes.amplifier_node", "--ros-args", "-r", f"__ns:={namespace}",
           "-r", f"/clock:={namespace}/clock"]
    for key, value in base.items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        cmd += ["-p", f"{key}:={value}"]
    if sim_time:
        cmd += ["-p", "use_sim_time:=true"]
    return spawn_logged(cmd)


def spawn_logged(cmd) -> subprocess.Popen:
    """A node process whose log goes to a file (a pipe nobody reads blocks the node once 64 KiB are logged)."""
    log = tempfile.TemporaryFile(mode="w+")
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.DEVNULL, stderr=log, text=True)
    proc.log = log
    return proc


def stderr_of(proc) -> str:
    """What the node process has logged so far."""
    proc.log.seek(0)
    return proc.log.read()


def stop(proc, sig=signal.SIGINT, timeout_s=15.0):
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def sessions(datagrams):
    """Datagrams grouped by sender session (one per configure), in order."""
    out = {}
    for d in datagrams:
        out.setdefault(d.session_id, []).append(d)
    return list(out.values())


def check_safe(datagrams, ceiling_V, slew_V_per_s, sim_period_s=None):
    """What reached the amplifier: finite, 0 <= V <= ceiling, every session opens at 0 V, and between
    consecutive datagrams of a session |dV| <= slew x dt on the sender's monotonic stamps (real time)
    or <= slew x one update period (simulated time, whatever the simulated clock did)."""
    assert datagrams, "nothing reached the amplifier"
    for d in datagrams:
        assert math.isfinite(d.voltage_V) and 0.0 <= d.voltage_V <= ceiling_V, d
    for group in sessions(datagrams):
        group = sorted(group, key=lambda d: d.sequence)
        assert group[0].sequence == 0 and group[0].voltage_V == 0.0, "a session did not open at 0 V"
        for a, b in zip(group, group[1:]):
            du = abs(b.voltage_V - a.voltage_V)
            if sim_period_s is None:
                bound = slew_V_per_s * max(0.0, b.sent_s - a.sent_s)
            else:
                bound = slew_V_per_s * sim_period_s
            assert du <= bound * (1 + 1e-9) + 1e-6, f"slew violated: {a} -> {b} (bound {bound} V)"


# ------------------------------------------------------------------ ROS services from the attacker node
def call(node, executor, client, request, timeout_s=10.0):
    """Call a service and spin until the answer (None on timeout)."""
    if not client.wait_for_service(timeout_sec=timeout_s):
        return None
    future = client.call_async(request)
    t_end = time.monotonic() + timeout_s
    while not future.done() and time.monotonic() < t_end:
        executor.spin_once(timeout_sec=0.01)
    return future.result() if future.done() else None


def set_parameter_request(name, value):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    request = SetParameters.Request()
    request.parameters = [Parameter(name, value=value).to_parameter_msg()]
    return request


def get_parameters_request(names):
    from rcl_interfaces.srv import GetParameters

    request = GetParameters.Request()
    request.names = list(names)
    return request


def transition_request(transition_id):
    from lifecycle_msgs.srv import ChangeState

    request = ChangeState.Request()
    request.transition.id = int(transition_id)
    return request


def parameter_value(msg):
    from rclpy.parameter import parameter_value_to_python

    return parameter_value_to_python(msg)
