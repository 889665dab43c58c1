"""Closed-loop simulation of the rig without ROS: a controller against a simulated plant.

The plant is the simulated rig's (:class:`~dea_ros.sim.plant.RigPlant`, the one
``mock_hardware_node`` runs): the model (eq. 18) with its own, "true" parameters integrated by the
core's RK4 (``physics_dt_s``), and the laser, which samples it every ``sample_period_s`` with
Gaussian noise and quantisation; the controller's command reaches the amplifier ``latency_s``
later; the amplifier is the real safety core
(:class:`~dea_ros.hardware.amplifier.safety.SafeVoltageController`: maximum, slew limit) updating
every ``amplifier_period_s`` (offset ``amplifier_phase_s`` from the laser samples) and holding its
output in between (zero-order hold). All event times are multiples of ``physics_dt_s``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..hardware.amplifier.limits import SafetyLimits
from ..hardware.amplifier.safety import SafeVoltageController
from ..model import MembraneParameters
from ..sim.plant import LASER_QUANTISATION_M, RigPlant

__all__ = ["SimulatedRig", "ClosedLoopResult", "run_closed_loop", "loop_delays"]


@dataclass(frozen=True)
class SimulatedRig:
    """The simulated rig (SI units). Defaults: the mock rig (1 um noise, ILD1320 quantisation,
    1 kHz laser and amplifier, 100 kV/s slew)."""

    params: MembraneParameters
    max_voltage_V: float
    slew_rate_V_per_s: float = 1e5
    physics_dt_s: float = 2.5e-4
    sample_period_s: float = 1e-3
    noise_m: float = 1e-6
    quantisation_m: float = LASER_QUANTISATION_M
    latency_s: float = 2.5e-4
    amplifier_period_s: float = 1e-3
    amplifier_phase_s: float = 5e-4
    seed: int = 0

    def ticks(self, seconds: float) -> int:
        n = seconds / self.physics_dt_s
        if abs(n - round(n)) > 1e-6:
            raise ValueError(f"{seconds} s is not a multiple of physics_dt_s = {self.physics_dt_s} s")
        return int(round(n))


@dataclass
class ClosedLoopResult:
    """Per laser sample: time, true and measured displacement, command, applied voltage."""

    time_s: np.ndarray
    true_m: np.ndarray
    measured_m: np.ndarray
    command_V: np.ndarray          # NaN where the controller sent nothing
    applied_V: np.ndarray          # amplifier output at the sample time


def run_closed_loop(rig: SimulatedRig, controller: Callable[[float, float], float | None],
                    duration_s: float, initial_voltage_V: float = 0.0,
                    applied_hook: Callable[[float, float], None] | None = None) -> ClosedLoopResult:
    """Simulate ``duration_s`` from rest at ``initial_voltage_V``.

    ``controller(t_k, measured_m)`` is called at every laser sample and returns a voltage command
    (V) or None (nothing sent). The amplifier starts active at ``initial_voltage_V``.
    """
    h = rig.physics_dt_s
    n_sample = rig.ticks(rig.sample_period_s)
    n_lat = rig.ticks(rig.latency_s)
    n_amp = rig.ticks(rig.amplifier_period_s)
    n_phase = rig.ticks(rig.amplifier_phase_s) % n_amp
    n_total = rig.ticks(round(duration_s / rig.sample_period_s) * rig.sample_period_s)
    plant = RigPlant(rig.params, h, noise_m=rig.noise_m, quantisation_m=rig.quantisation_m, seed=rig.seed,
                     initial_voltage_V=initial_voltage_V)
    limits = SafetyLimits(max_voltage_V=rig.max_voltage_V, slew_rate_V_per_s=rig.slew_rate_V_per_s,
                          watchdog_timeout_s=60.0, ramp_down_rate_V_per_s=rig.slew_rate_V_per_s)
    amp = SafeVoltageController(limits)
    # the amplifier has been holding initial_voltage_V (no slew from 0 V at t = 0)
    t_pre = initial_voltage_V / rig.slew_rate_V_per_s + 0.01
    amp.activate(-t_pre)
    amp.command(initial_voltage_V, -t_pre)
    for k in range(int(math.ceil(t_pre / 0.005)) + 1):
        amp.update(min(-t_pre + k * 0.005, 0.0))
    n_samples = n_total // n_sample + 1
    t_out = np.empty(n_samples)
    true = np.empty(n_samples)
    meas = np.empty(n_samples)
    cmd = np.full(n_samples, np.nan)
    applied = np.empty(n_samples)
    pending: list = []          # (arrival tick, voltage)
    u_applied = amp.update(0.0)
    j = 0
    for i in range(n_total + 1):
        t = i * h
        if pending and pending[0][0] == i:
            amp.command(pending.pop(0)[1], t)
        if i % n_amp == n_phase:
            u_applied = amp.update(t)
            if applied_hook is not None:
                applied_hook(t, u_applied)
        if i % n_sample == 0:
            d = plant.displacement_m
            m = plant.laser_reading_m(d)
            t_out[j], true[j], meas[j], applied[j] = t, d, m, u_applied
            u_cmd = controller(t, m)
            if u_cmd is not None:
                cmd[j] = u_cmd
                if n_lat == 0:
                    amp.command(u_cmd, t)
                else:
                    pending.append((i + n_lat, u_cmd))
            j += 1
        if i < n_total:
            plant.step(u_applied)
    return ClosedLoopResult(t_out[:j], true[:j], meas[:j], cmd[:j], applied[:j])


def loop_delays(commands, applied, period_s: float, slew_rate_V_per_s: float, window: int = 20) -> list:
    """Sample -> applied-voltage delays, in periods, measured on recorded streams (a rig, the mock rig).

    ``commands``: (stamp of the sample a command answers, s; command, V) pairs;
    ``applied``: (stamp of the amplifier update, s; applied voltage, V) pairs, one per update
    period. Values are compared exactly (both as sent on the wire: the same float32 rounding).
    An applied voltage counts only when the amplifier reached its target (it moved by less than
    the slew limit since the previous update: a slew-limited value is no command), every command
    of the ``window`` periods before it is in the record (a lost one could be the true source)
    and exactly one of them has its value; others are left out.
    Returns one delay (an integer number of periods) per counted applied voltage.
    """
    by_tick = {int(round(t / period_s)): u for t, u in commands}
    out = {int(round(t / period_s)): u for t, u in applied}
    step = 0.99 * slew_rate_V_per_s * period_s
    delays = []
    for j, u in sorted(out.items()):
        if j - 1 not in out or abs(u - out[j - 1]) > step:
            continue
        if any(k not in by_tick for k in range(j - window, j)):
            continue
        hits = [k for k in range(j - window, j + 1) if by_tick.get(k) == u]
        if len(hits) == 1:
            delays.append(j - hits[0])
    return delays
