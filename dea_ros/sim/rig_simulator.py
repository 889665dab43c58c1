"""The simulated rig on a clock: what mock_hardware_node runs (no ROS, thread-safe).

:class:`RigSimulator` runs the :class:`~dea_ros.sim.plant.RigPlant` on a monotonic time axis in
seconds (the wall clock's monotonic time in real-time mode, the simulated clock otherwise): the
amplifier's output changes at the instants it was sent (:meth:`~RigSimulator.apply_voltage`),
and the laser reads the displacement at any acquisition time with its latency
(:meth:`~RigSimulator.measure`, past values from a history buffer, linearly interpolated).
:class:`LaserSampler` reads it at a fixed rate (the mock's ``displacement`` topic); the ILD1320
emulator reads it at its own sample times from its own thread.
"""
from __future__ import annotations

import collections
import math
import threading

from ..model.parameters import MembraneParameters
from .plant import RigPlant

__all__ = ["RigSimulator", "LaserSampler"]


class RigSimulator:
    """The physics of the mock rig on a time axis, independent of ROS (thread-safe).

    ``advance_to(t)`` integrates with the voltage applied at that moment; ``measure(t)`` returns
    what the laser reads for an acquisition at ``t``. ``noise_m``, ``quantisation_m`` and
    ``seed`` are the laser's (:class:`~dea_ros.sim.plant.RigPlant`), ``latency_s`` its latency,
    ``history_s`` how far back it can read, s.
    """

    #: times within this of a step boundary are on it (s): an epoch time in float64 (~1.8e9 s) carries
    #: ~0.2 us of rounding, so t - t0 of a clock tick lands up to that far on either side of its step
    BOUNDARY_TOLERANCE_S = 1e-6

    def __init__(self, params: MembraneParameters, physics_dt_s: float, t0_s: float, noise_m: float,
                 quantisation_m: float, latency_s: float, seed: int = 0, history_s: float = 2.0) -> None:
        self.params = params
        self.plant = RigPlant(params, physics_dt_s, noise_m=noise_m, quantisation_m=quantisation_m, seed=seed)
        self.dt_s = physics_dt_s
        # Time is kept relative to t0: absolute epoch seconds (~1.8e9) resolve only ~0.2 us in
        # float64, and summing physics steps there drifts step boundaries off the clock ticks.
        self.t0_s = float(t0_s)
        self.steps = 0
        self.voltage_V = 0.0
        self.latency_s = latency_s
        self.lock = threading.Lock()
        n = int(history_s / physics_dt_s) + 2
        self.history = collections.deque(maxlen=n)   # (time relative to t0, displacement)
        self.history.append((0.0, self.plant.displacement_m))

    @property
    def t_s(self) -> float:
        """Current simulation time (absolute, s)."""
        return self.t0_s + self.steps * self.dt_s

    @property
    def displacement_m(self) -> float:
        """The membrane's displacement at :attr:`t_s`, m."""
        return self.plant.displacement_m

    def apply_voltage(self, voltage_V: float, from_s: float | None = None) -> None:
        """The amplifier's output becomes ``voltage_V`` at ``from_s`` (s; None: now).

        The membrane is first integrated up to ``from_s`` with the previous voltage, so transport
        and executor delays do not shift the physics (an instant already simulated: from now).
        """
        with self.lock:
            if from_s is not None:
                self._advance_locked(max(from_s, self.t_s) - self.t0_s)
            self.voltage_V = float(voltage_V)

    def advance_to(self, t_s: float) -> None:
        """Integrate the membrane up to ``t_s`` with the voltage applied now."""
        with self.lock:
            self._advance_locked(t_s - self.t0_s)

    def _advance_locked(self, t_rel: float) -> None:
        # whole steps up to t: a tick that rounds to just below its boundary must still reach it, or the
        # laser reads the position half a step old and the next voltage starts half a step early
        target = int(math.floor((t_rel + self.BOUNDARY_TOLERANCE_S) / self.dt_s))
        while self.steps < target:
            self.plant.step(self.voltage_V)
            self.steps += 1
            self.history.append((self.steps * self.dt_s, self.plant.displacement_m))

    def true_displacement_m(self, t_s: float) -> float:
        """Displacement at t (interpolated in the history; the future is integrated first)."""
        with self.lock:
            t_rel = t_s - self.t0_s
            if t_rel > self.steps * self.dt_s:
                self._advance_locked(t_rel)
            hist = self.history
            if t_rel >= hist[-1][0]:
                return hist[-1][1]
            if t_rel <= hist[0][0]:
                return hist[0][1]
            lo, hi = 0, len(hist) - 1
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if hist[mid][0] <= t_rel:
                    lo = mid
                else:
                    hi = mid
            (ta, da), (tb, db) = hist[lo], hist[hi]
            return da + (db - da) * (t_rel - ta) / (tb - ta)

    def measure(self, t_acq_s: float) -> float:
        """Laser reading for an acquisition at t: latency, noise, quantisation."""
        return self.plant.laser_reading_m(self.true_displacement_m(t_acq_s - self.latency_s))


class LaserSampler:
    """The laser read at ``rate_hz``: sample k = 1, 2, ... acquired at ``t0_s + k / rate_hz``."""

    def __init__(self, simulator: RigSimulator, rate_hz: float, t0_s: float) -> None:
        self.simulator = simulator
        self.rate_hz = rate_hz
        self.t0_s = t0_s
        self.next_index = 1

    def samples_until(self, t_end_s: float) -> list[tuple[float, float]]:
        """``(acquisition time, reading)`` of every sample acquired up to ``t_end_s``, s and m, oldest first."""
        period = 1.0 / self.rate_hz
        samples = []
        while self.t0_s + self.next_index * period <= t_end_s + RigSimulator.BOUNDARY_TOLERANCE_S:
            t_acq = self.t0_s + self.next_index * period
            self.next_index += 1
            samples.append((t_acq, self.simulator.measure(t_acq)))
        return samples
