"""Real-time prediction of the displacement from the applied voltage (model_node's core, no ROS).

The model (eq. 18) is advanced by the core's fixed-step RK4
(:class:`~dea_ros.solvers.integrate.RealTimeStepper`) with the latest voltage held (zero-order hold,
like the DAQ). Times are integer nanoseconds on the caller's clock:

* :meth:`ModelPredictor.input` -- an applied voltage stamped ``t_ns``: the model is advanced exactly
  to ``t_ns`` from the *anchor* (the state at the previous input), with the previous voltage held,
  and the new voltage is latched. Extrapolations made in between are discarded, so a late input
  never integrates an interval twice. An input older than the anchor is stale (counted, ignored);
  a gap longer than ``max_catch_up_s`` restarts the model at the static equilibrium of the held
  voltage (counted, reported to ``on_gap_reset``).
* :meth:`ModelPredictor.extrapolate` -- no input for a while: advance to now with the held voltage
  (a restart at equilibrium when more than ``max_catch_up_s`` behind).
"""
from __future__ import annotations

from typing import Callable

from ..model import MembraneParameters
from ..solvers.integrate import RealTimeStepper

__all__ = ["ModelPredictor"]


class ModelPredictor:
    """The model driven by stamped voltage inputs, extrapolated in between (module docstring)."""

    def __init__(self, params: MembraneParameters, dt_s: float, max_catch_up_s: float,
                 on_gap_reset: Callable[[int, float], None] | None = None):
        self.dt_s = float(dt_s)
        self.dt_ns = max(1, int(round(self.dt_s * 1e9)))
        self.max_catch_up_s = float(max_catch_up_s)
        #: called as on_gap_reset(gap_ns, held voltage V) when a gap restarts the model
        self.on_gap_reset = on_gap_reset
        self.stepper = RealTimeStepper(params, dt_s=self.dt_s)
        self.voltage_V = 0.0                     # the held voltage
        self.model_time_ns: int | None = None    # time of the stepper's state (may be extrapolated)
        self.anchor_ns: int | None = None        # stamp of the latest input: exact state below
        self.anchor_state: list | None = None
        self.stale_inputs = 0
        self.resets_for_gaps = 0

    @property
    def params(self) -> MembraneParameters:
        return self.stepper.params

    @property
    def displacement_m(self) -> float:
        return self.stepper.displacement_m

    def behind_s(self, now_ns: int) -> float:
        """How far the model's time is behind ``now_ns``, s."""
        return (now_ns - self.model_time_ns) * 1e-9

    def integrate(self, from_ns: int, to_ns: int) -> None:
        """Advance the stepper from from_ns to to_ns with the held voltage (fixed steps, last shortened)."""
        n, rest_ns = divmod(to_ns - from_ns, self.dt_ns)
        for _ in range(n):
            self.stepper.step(self.voltage_V, self.dt_s)
        if rest_ns > 0:
            self.stepper.step(self.voltage_V, rest_ns * 1e-9)

    def input(self, t_ns: int, voltage_V: float) -> bool:
        """An applied voltage stamped ``t_ns``: the model advanced exactly to ``t_ns``, the voltage latched.

        False for a stale (out-of-order) stamp, which is ignored (counted in ``stale_inputs``).
        """
        if not self.advance_to(t_ns):
            return False
        self.voltage_V = voltage_V
        return True

    def advance_to(self, t_ns: int) -> bool:
        """Exact update at an input stamp: re-integrate from the anchor with the held voltage."""
        if self.anchor_ns is None:
            self.anchor_ns = self.model_time_ns = t_ns
            self.anchor_state = list(self.stepper.state)
            return True
        if t_ns < self.anchor_ns:
            self.stale_inputs += 1
            return False
        gap_ns = t_ns - self.anchor_ns
        self.stepper.state = list(self.anchor_state)
        if gap_ns > self.max_catch_up_s * 1e9:
            self.resets_for_gaps += 1
            if self.on_gap_reset is not None:
                self.on_gap_reset(gap_ns, self.voltage_V)
            self.stepper.reset(self.voltage_V)
        else:
            self.integrate(self.anchor_ns, t_ns)
        self.anchor_ns = self.model_time_ns = t_ns
        self.anchor_state = list(self.stepper.state)
        return True

    def extrapolate(self, now_ns: int) -> None:
        """Advance to ``now_ns`` with the held voltage (restart at equilibrium when too far behind)."""
        if self.behind_s(now_ns) > self.max_catch_up_s:
            self.stepper.reset(self.voltage_V)
        else:
            self.integrate(self.model_time_ns, now_ns)
        self.model_time_ns = now_ns

    def start_clock(self, now_ns: int) -> None:
        """The model's time starts at ``now_ns`` (the state as it is)."""
        self.model_time_ns = now_ns

    def restart(self) -> None:
        """Start over (the clock jumped back): equilibrium at the held voltage, no time, no anchor."""
        self.stepper.reset(self.voltage_V)
        self.model_time_ns = self.anchor_ns = self.anchor_state = None

    def reset(self) -> None:
        """Back to the static equilibrium at the held voltage (the anchor's state too)."""
        self.stepper.reset(self.voltage_V)
        self.anchor_state = list(self.stepper.state)

    def replace_model(self, params: MembraneParameters) -> None:
        """Other parameters, at their static equilibrium at the held voltage (ValueError: refused, unchanged)."""
        self.stepper = RealTimeStepper(params, dt_s=self.dt_s, initial_voltage_V=self.voltage_V)
        self.anchor_state = list(self.stepper.state)
