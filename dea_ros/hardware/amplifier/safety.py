"""Safety core of the high-voltage amplifier: a clock-injected state machine (pure: no ROS, no I/O).

This module holds the logic that stands between any voltage request and the amplifier:

* :class:`SafeVoltageController` -- a state machine that validates commands, limits the
  output to the :class:`~dea_ros.hardware.amplifier.limits.SafetyLimits` fixed at start-up
  (maximum, slew rate), ramps the output down when deactivated, when the command stream
  goes silent (watchdog) or on an emergency stop;
* :func:`drive_to_zero` -- the emergency ramp to 0 V outside any executor (signal handlers);
* :class:`ControlClock` -- the controller's time axis built from one or more source clocks.

Time is always passed in as an argument (seconds, any monotonic clock); the
controller never reads a clock itself, so it behaves identically under a ROS
clock, a simulated clock or a test.

Time handling
-------------
* The output moves only in :meth:`SafeVoltageController.update`, by at most
  ``rate x dt`` where ``dt`` is the time since the previous ``update``. For every
  two consecutive updates at ``t1 <= t2``: ``|u(t2) - u(t1)| <= slew x (t2 - t1)``
  holds exactly in floating point (the step is nudged by one ulp if rounding
  would exceed it).
* A clock that jumps backwards produces no movement on that update; later updates
  measure time from the new (earlier) value ("re-basing"), so a clock reset never
  freezes a ramp-down or blinds the watchdog. Backward jumps are counted.
* The watchdog measures silence by accumulating the positive increments of every
  ``t`` passed to any method since the last valid command (the accumulator restarts
  at 0 on every command, so no clock glitch, however large, makes later increments
  vanish in floating point).
* :class:`ControlClock` builds the controller's time axis from one or more source
  clocks with every step clamped to ``[0, max_step_s]``: with a simulated clock a
  jump never moves the output by more than one update's worth of slew.
"""
from __future__ import annotations

import dataclasses
import enum
import math
import numbers
from dataclasses import dataclass
from typing import Any, Callable

from ...errors import SafetyConfigError
from .limits import SafetyLimits, finite_field

__all__ = [
    "ControllerState",
    "RejectionReason",
    "CommandResult",
    "ACCEPTED",
    "ControllerDiagnostics",
    "SafeVoltageController",
    "drive_to_zero",
    "ControlClock",
]


def _as_time_s(name: str, value: Any) -> float:
    """Time arguments are programming inputs, not commands: invalid ones raise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"argument '{name}': time in seconds must be a real number, got {value!r}")
    result = float(value)
    if not math.isfinite(result):
        raise ValueError(f"argument '{name}': time in seconds must be finite, got {result}")
    return result


# --------------------------------------------------------------------------- state machine
class ControllerState(str, enum.Enum):
    """States of :class:`SafeVoltageController` (the values are the diagnostic strings)."""

    INACTIVE = "inactive"  #: not activated, output 0 V
    RAMPING_DOWN = "ramping_down"  #: deactivated, output still ramping to 0 V
    ACTIVE = "active"  #: activated, output follows valid commands at the slew limit
    WATCHDOG_TRIPPED = "watchdog_tripped"  #: activated but commands went silent: ramping to 0 V
    EMERGENCY_STOP = "emergency_stop"  #: latched by emergency_ramp_down() until activate()


class RejectionReason(str, enum.Enum):
    """Why :meth:`SafeVoltageController.command` refused a command."""

    INVALID_TYPE = "invalid_type"  #: not a real number (str, None, bool, ...)
    NAN = "nan"
    INFINITE = "infinite"  #: +inf or -inf
    NEGATIVE = "negative"
    ABOVE_MAX = "above_max"
    INACTIVE = "inactive"  #: the controller is not activated (or emergency-stopped)


#: ``CommandResult.reason`` of an accepted command.
ACCEPTED = "accepted"


@dataclass(frozen=True)
class CommandResult:
    """Outcome of :meth:`SafeVoltageController.command`.

    ``reason`` is ``"accepted"`` or a :class:`RejectionReason` value; ``target_V``
    is the target after the call (unchanged when rejected).
    """

    accepted: bool
    reason: str
    requested: Any
    target_V: float

    def __bool__(self) -> bool:
        return self.accepted


@dataclass(frozen=True)
class ControllerDiagnostics:
    """Snapshot of :class:`SafeVoltageController` for logging and ROS diagnostics."""

    state: str
    target_V: float
    output_V: float
    max_voltage_V: float
    accepted_count: int
    rejected_counts: dict
    rejected_total: int
    watchdog_trip_count: int
    clock_backward_jump_count: int
    emergency_stop_count: int
    last_command_age_s: float | None
    last_update_t_s: float | None
    time_to_zero_s: float

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def key_values(self) -> list[tuple[str, str]]:
        """Flat ``(key, value-string)`` pairs, e.g. for ``diagnostic_msgs/KeyValue``."""
        pairs: list[tuple[str, str]] = []
        for key, value in self.to_dict().items():
            if isinstance(value, dict):
                pairs.extend((f"{key}.{k}", str(v)) for k, v in value.items())
            else:
                pairs.append((key, "none" if value is None else str(value)))
        return pairs


_ACTIVATED_STATES = (ControllerState.ACTIVE, ControllerState.WATCHDOG_TRIPPED)


class SafeVoltageController:
    """Clock-injected safety state machine between voltage requests and the amplifier.

    Usage per control tick::

        controller.command(requested_V, t)   # whenever a request arrives
        applied_V = controller.update(t)      # every tick; write applied_V to the amplifier

    Guarantees (for any sequence of calls):

    * ``0 <= output <= max_voltage_V`` always;
    * between consecutive updates at ``t1 <= t2``: ``|du| <= slew_rate x (t2 - t1)``;
      a backward clock jump gives ``du = 0``;
    * the output is 0 V unless activated; after :meth:`deactivate`, a watchdog trip
      or :meth:`emergency_ramp_down` it decreases at ``ramp_down_rate`` to 0 V;
    * NaN, +-inf, negative, above-max, non-numeric commands and commands while not
      activated are rejected, counted per reason, and do not move the target.

    Not thread-safe: call it from one thread (in ROS 2, a single-threaded executor
    or one mutually exclusive callback group for the command subscription and the
    update timer).
    """

    def __init__(self, limits: SafetyLimits) -> None:
        if not isinstance(limits, SafetyLimits):
            raise TypeError(f"limits must be a SafetyLimits, got {type(limits).__name__}")
        self._limits = limits
        self._state = ControllerState.INACTIVE
        self._target_V = 0.0
        self._output_V = 0.0
        self._last_update_t: float | None = None
        # Watchdog: the positive increments of every t seen, accumulated since the last feed
        # (and since the last accepted command); restarted at 0, so they stay exact.
        self._last_seen_t: float | None = None
        self._silence_s: float | None = None
        self._since_command_s: float | None = None
        self._accepted_count = 0
        self._rejected_counts = {reason.value: 0 for reason in RejectionReason}
        self._watchdog_trip_count = 0
        self._backward_jump_count = 0
        self._emergency_stop_count = 0

    # ------------------------------------------------------------------ properties
    @property
    def limits(self) -> SafetyLimits:
        return self._limits

    @property
    def state(self) -> ControllerState:
        return self._state

    @property
    def is_activated(self) -> bool:
        """True in ``active`` and ``watchdog_tripped`` (a valid command resumes)."""
        return self._state in _ACTIVATED_STATES

    @property
    def target_V(self) -> float:
        """Voltage the output is moving toward (0 V unless active)."""
        return self._target_V

    @property
    def output_V(self) -> float:
        """Output computed by the last :meth:`update` (the value to apply)."""
        return self._output_V

    @property
    def last_update_t_s(self) -> float | None:
        """``t`` of the last :meth:`update` (None before the first)."""
        return self._last_update_t

    @property
    def rejected_counts(self) -> dict[str, int]:
        """Rejected commands per :class:`RejectionReason` value (a copy)."""
        return dict(self._rejected_counts)

    @property
    def accepted_count(self) -> int:
        return self._accepted_count

    @property
    def watchdog_trip_count(self) -> int:
        return self._watchdog_trip_count

    @property
    def clock_backward_jump_count(self) -> int:
        return self._backward_jump_count

    # ------------------------------------------------------------------ clock
    def _observe_time(self, t: float) -> None:
        """Advance the watchdog accumulators by the positive increment of ``t``."""
        if self._last_seen_t is not None:
            dt = t - self._last_seen_t
            if dt > 0.0:
                if self._silence_s is not None:
                    self._silence_s += dt
                if self._since_command_s is not None:
                    self._since_command_s += dt
        self._last_seen_t = t

    def _feed_watchdog(self) -> None:
        self._silence_s = 0.0

    def _watchdog_expired(self) -> bool:
        if self._silence_s is None:
            return False
        return self._silence_s > self._limits.watchdog_timeout_s

    def _check_watchdog(self) -> None:
        if self._state is ControllerState.ACTIVE and self._watchdog_expired():
            self._state = ControllerState.WATCHDOG_TRIPPED
            self._target_V = 0.0
            self._watchdog_trip_count += 1

    # ------------------------------------------------------------------ transitions
    def activate(self, t: float) -> None:
        """Enable the output. The target starts at 0 V; the watchdog starts now.

        Also leaves ``emergency_stop``. No effect when already activated.
        """
        t = _as_time_s("t", t)
        self._observe_time(t)
        if self.is_activated:
            return
        self._state = ControllerState.ACTIVE
        self._target_V = 0.0
        self._feed_watchdog()

    def deactivate(self, t: float) -> None:
        """Disable the output: target 0 V, ramp down at ``ramp_down_rate``."""
        t = _as_time_s("t", t)
        self._observe_time(t)
        self._target_V = 0.0
        if self._state is ControllerState.EMERGENCY_STOP:
            return  # stays latched; it ramps down the same way
        if self._state in _ACTIVATED_STATES or self._state is ControllerState.RAMPING_DOWN:
            self._state = (
                ControllerState.RAMPING_DOWN if self._output_V > 0.0 else ControllerState.INACTIVE
            )

    def emergency_ramp_down(self, t: float) -> float:
        """Emergency stop (shutdown, SIGINT, SIGTERM): target 0 V, latched until :meth:`activate`.

        Returns the time in s the ramp needs to reach 0 V from the present output;
        keep calling :meth:`update` (and writing its result) at least that long.
        """
        t = _as_time_s("t", t)
        self._observe_time(t)
        self._target_V = 0.0
        if self._state is not ControllerState.EMERGENCY_STOP:
            self._emergency_stop_count += 1
        self._state = ControllerState.EMERGENCY_STOP
        return self._limits.time_to_zero_s(self._output_V)

    def _classify(self, voltage_V: Any) -> RejectionReason | None:
        if isinstance(voltage_V, bool) or not isinstance(voltage_V, numbers.Real):
            return RejectionReason.INVALID_TYPE
        try:
            value = float(voltage_V)
        except (TypeError, ValueError, OverflowError):
            return RejectionReason.INVALID_TYPE
        if math.isnan(value):
            return RejectionReason.NAN
        if math.isinf(value):
            return RejectionReason.INFINITE
        if value < 0.0:
            return RejectionReason.NEGATIVE
        if value > self._limits.max_voltage_V:
            return RejectionReason.ABOVE_MAX
        if not self.is_activated:
            return RejectionReason.INACTIVE
        return None

    def command(self, voltage_V: Any, t: float) -> CommandResult:
        """Request an output voltage (V) at time ``t`` (s).

        A valid command (finite, 0 <= V <= max, controller activated) becomes the
        target, feeds the watchdog and clears a watchdog trip. Anything else is
        rejected: counted under its reason, target and state unchanged. (The
        watchdog is evaluated in :meth:`update`, the only place the output moves.)
        """
        t = _as_time_s("t", t)
        self._observe_time(t)
        reason = self._classify(voltage_V)
        if reason is not None:
            self._rejected_counts[reason.value] += 1
            return CommandResult(False, reason.value, voltage_V, self._target_V)
        self._target_V = float(voltage_V) + 0.0  # +0.0 turns -0.0 into 0.0
        self._state = ControllerState.ACTIVE
        self._feed_watchdog()
        self._since_command_s = 0.0
        self._accepted_count += 1
        return CommandResult(True, ACCEPTED, voltage_V, self._target_V)

    # ------------------------------------------------------------------ output
    def update(self, t: float) -> float:
        """Advance the output to time ``t`` (s) and return the voltage to apply, V."""
        t = _as_time_s("t", t)
        self._observe_time(t)
        self._check_watchdog()
        if self._last_update_t is None:
            dt = 0.0
        else:
            dt = t - self._last_update_t
            if dt < 0.0:
                self._backward_jump_count += 1
                dt = 0.0
        self._last_update_t = t

        if self._state is ControllerState.ACTIVE:
            goal_V, rate = self._target_V, self._limits.slew_rate_V_per_s
        else:
            goal_V, rate = 0.0, self._limits.ramp_down_rate_V_per_s
        self._output_V = self._step(self._output_V, goal_V, rate * dt)

        if self._state is ControllerState.RAMPING_DOWN and self._output_V == 0.0:
            self._state = ControllerState.INACTIVE
        return self._output_V

    def _step(self, output_V: float, goal_V: float, max_step_V: float) -> float:
        """Move toward ``goal_V`` by at most ``max_step_V`` (exact in floating point)."""
        max_V = self._limits.max_voltage_V
        goal_V = min(max(goal_V, 0.0), max_V)
        if abs(goal_V - output_V) <= max_step_V:
            new_V = goal_V
        else:
            new_V = output_V + math.copysign(max_step_V, goal_V - output_V)
            # Rounding of the addition may exceed the bound by an ulp: nudge back.
            while abs(new_V - output_V) > max_step_V:
                new_V = math.nextafter(new_V, output_V)
        return min(max(new_V, 0.0), max_V) + 0.0

    # ------------------------------------------------------------------ diagnostics
    def last_command_age_s(self, t: float | None = None) -> float | None:
        """Watchdog-clock time since the last accepted command, s (None if never).

        With ``t`` the age is evaluated at ``t`` (without changing the state),
        otherwise at the latest time seen.
        """
        if self._since_command_s is None:
            return None
        age = self._since_command_s
        if t is not None:
            t = _as_time_s("t", t)
            if self._last_seen_t is not None and t > self._last_seen_t:
                age += t - self._last_seen_t
        return age

    def diagnostics(self, t: float | None = None) -> ControllerDiagnostics:
        """Snapshot of state, target, output, counters and last command age."""
        return ControllerDiagnostics(
            state=self._state.value,
            target_V=self._target_V,
            output_V=self._output_V,
            max_voltage_V=self._limits.max_voltage_V,
            accepted_count=self._accepted_count,
            rejected_counts=dict(self._rejected_counts),
            rejected_total=sum(self._rejected_counts.values()),
            watchdog_trip_count=self._watchdog_trip_count,
            clock_backward_jump_count=self._backward_jump_count,
            emergency_stop_count=self._emergency_stop_count,
            last_command_age_s=self.last_command_age_s(t),
            last_update_t_s=self._last_update_t,
            time_to_zero_s=self._limits.time_to_zero_s(self._output_V),
        )


def drive_to_zero(
    controller: SafeVoltageController,
    write_voltage: Callable[[float], None],
    clock: Callable[[], float],
    sleep: Callable[[float], None],
    period_s: float = 0.01,
    extra_time_s: float = 1.0,
) -> float:
    """Emergency ramp to 0 V outside any executor (e.g. in a SIGTERM handler).

    Calls :meth:`SafeVoltageController.emergency_ramp_down`, then repeatedly
    ``update(clock())`` and ``write_voltage(output)`` every ``period_s`` until the
    output is 0 V or the ramp time plus ``extra_time_s`` has passed on ``clock``.
    Returns the last output written (0.0 on success). ``clock`` and ``sleep`` are
    injected (``time.monotonic`` / ``time.sleep`` in a node).
    """
    if not (period_s > 0.0 and math.isfinite(period_s)):
        raise ValueError(f"argument 'period_s': must be a finite time > 0 s, got {period_s}")
    start_s = clock()
    needed_s = controller.emergency_ramp_down(start_s)
    budget_s = needed_s + max(0.0, extra_time_s)
    deadline_s = start_s + budget_s
    # Guard against a clock that does not advance: never loop much longer than planned.
    max_iterations = int(math.ceil(budget_s / period_s)) + 100
    output_V = controller.output_V
    for _ in range(max_iterations):
        now_s = clock()
        output_V = controller.update(now_s)
        write_voltage(output_V)
        if output_V == 0.0 or now_s >= deadline_s:
            break
        sleep(period_s)
    return output_V


class ControlClock:
    """The controller's time axis, s, built from one or more monotonic source clocks.

    Each :meth:`advance` adds the source's increment since that source's previous
    reading, clamped to ``[0, max_step_s]`` (``None``: no upper clamp). So a source
    that jumps backwards adds nothing, one that jumps forwards adds at most
    ``max_step_s``, and switching between sources (simulated clock, wall clock)
    never makes the axis jump. The axis itself only ever increases.

    In a node with simulated time, ``max_step_s`` = one update period: a jump of the
    simulated clock then moves the output by at most one update's worth of slew.
    """

    def __init__(self, max_step_s: float | None = None, start_s: float = 0.0) -> None:
        if max_step_s is not None:
            max_step_s = finite_field("max_step_s", max_step_s)
            if max_step_s <= 0.0:
                raise SafetyConfigError(f"field 'max_step_s': must be > 0, got {max_step_s}")
        self._max_step_s = max_step_s
        self._t = finite_field("start_s", start_s)
        self._last: dict[str, float] = {}
        self.clamped_steps = 0  #: advances limited by ``max_step_s`` (forward jumps)
        self.backward_steps = 0  #: source readings earlier than the previous one

    @property
    def now_s(self) -> float:
        """The axis' present value (no source read), s."""
        return self._t

    @property
    def max_step_s(self) -> float | None:
        return self._max_step_s

    def advance(self, source_t: float, source: str = "default") -> float:
        """Read ``source`` at ``source_t`` (s) and return the new axis value, s."""
        source_t = _as_time_s("source_t", source_t)
        last = self._last.get(source)
        self._last[source] = source_t
        if last is None:
            return self._t
        step = source_t - last
        if step < 0.0:
            self.backward_steps += 1
            return self._t
        if self._max_step_s is not None and step > self._max_step_s:
            self.clamped_steps += 1
            step = self._max_step_s
        self._t += step
        return self._t

    def forget(self, source: str) -> None:
        """Drop a source's reference: its next reading adds nothing (re-synchronise)."""
        self._last.pop(source, None)
