"""Limits of the high-voltage amplifier, fixed at start-up (pure: no ROS, no I/O).

A dielectric elastomer membrane is destroyed by dielectric breakdown when the voltage across it
is too high, and can be damaged by too fast a change. :class:`SafetyLimits` holds the validated
limits every output obeys: maximum voltage, slew rate, command watchdog timeout and ramp-down
rate. :meth:`SafetyLimits.from_membrane` derives the maximum from the membrane
(``margin x breakdown field x thickness``, :func:`membrane_voltage_limit_V`) and refuses a
configured maximum above that derived limit. The limits are frozen: nothing can raise them
after they are made. :mod:`~dea_ros.hardware.amplifier.safety` enforces them.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Any, Mapping

from ...errors import SafetyConfigError
from ...model.parameters import MAX_BREAKDOWN_FIELD_V_PER_M

__all__ = [
    "SafetyConfigError",
    "SafetyLimits",
    "membrane_voltage_limit_V",
    "finite_field",
    "ABSOLUTE_MAX_VOLTAGE_V",
    "MAX_WATCHDOG_TIMEOUT_S",
    "MAX_TIME_TO_ZERO_S",
    "MIN_THICKNESS_M",
    "MAX_THICKNESS_M",
]

#: No DEA amplifier in use here exceeds this; a larger max is taken for a unit slip.
ABSOLUTE_MAX_VOLTAGE_V = 30_000.0
#: A watchdog longer than this is taken for a unit slip (milliseconds for seconds).
MAX_WATCHDOG_TIMEOUT_S = 60.0
#: Limits derived for a membrane (:meth:`SafetyLimits.from_membrane`) must bring the output
#: from its maximum to 0 V within this time after the last command: watchdog timeout plus
#: ramp-down time, s.
MAX_TIME_TO_ZERO_S = 10.0
#: Membrane thickness range (1-1000 um) accepted for a voltage limit, m.
MIN_THICKNESS_M = 1e-6
MAX_THICKNESS_M = 1e-3


def finite_field(name: str, value: Any) -> float:
    """``value`` of the configuration field ``name`` as a finite float; :class:`SafetyConfigError` otherwise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise SafetyConfigError(f"field '{name}': must be a number, got {value!r}")
    result = float(value)
    if not math.isfinite(result):
        raise SafetyConfigError(f"field '{name}': must be finite, got {result}")
    return result


def membrane_voltage_limit_V(
    thickness_m: float, breakdown_field_V_per_m: float, margin: float
) -> float:
    """Largest voltage allowed on a membrane: ``margin x breakdown_field x thickness``, V.

    ``thickness_m`` should be the thinnest the dielectric gets (the membrane thins
    when it stretches under voltage); ``margin`` in (0, 1), strictly below 1, covers
    that and the scatter of the breakdown field. The breakdown field may not exceed
    :data:`dea_ros.model.parameters.MAX_BREAKDOWN_FIELD_V_PER_M` (what elastomers reach).
    """
    thickness_m = finite_field("thickness_m", thickness_m)
    breakdown_field_V_per_m = finite_field("breakdown_field_V_per_m", breakdown_field_V_per_m)
    margin = finite_field("margin", margin)
    if not (MIN_THICKNESS_M <= thickness_m <= MAX_THICKNESS_M):
        raise SafetyConfigError(
            f"field 'thickness_m': {thickness_m:g} m is outside [1e-06, 0.001] m (1-1000 um); SI metres "
            "expected (micrometres are 1e-6 m: 27 um -> 2.7e-05)"
        )
    if not (1e6 <= breakdown_field_V_per_m <= MAX_BREAKDOWN_FIELD_V_PER_M):
        raise SafetyConfigError(
            f"field 'breakdown_field_V_per_m': {breakdown_field_V_per_m:g} V/m is outside "
            f"[1e6, {MAX_BREAKDOWN_FIELD_V_PER_M:g}] V/m; SI V/m expected (100 V/um -> 1e8); no "
            "elastomer reaches more than ~300 V/um: a typo in the exponent (8e8 for 8e7)?"
        )
    if not (0.0 < margin < 1.0):
        raise SafetyConfigError(
            f"field 'margin': must be in (0, 1), strictly below 1 (fraction of the breakdown voltage; "
            f"1 leaves no headroom for thinning under voltage and scatter; typical 0.8-0.9), got {margin}"
        )
    return margin * breakdown_field_V_per_m * thickness_m


@dataclass(frozen=True)
class SafetyLimits:
    """Validated amplifier safety limits (SI units).

    * ``max_voltage_V``: highest output voltage ever applied, V (> 0);
    * ``slew_rate_V_per_s``: largest rate of change of the output, V/s (> 0);
    * ``watchdog_timeout_s``: without a valid command for this long the output is ramped
      to 0 V, s (> 0);
    * ``ramp_down_rate_V_per_s``: rate of the ramp to 0 V when deactivated, on a watchdog
      trip and on an emergency stop, V/s; must be <= the slew rate;
    * ``membrane_limit_V``: optional limit derived from the membrane (see
      :meth:`from_membrane`); ``max_voltage_V`` above it is refused.
    """

    max_voltage_V: float
    slew_rate_V_per_s: float
    watchdog_timeout_s: float
    ramp_down_rate_V_per_s: float
    membrane_limit_V: float | None = None

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "membrane_limit_V" and value is None:
                continue
            value = finite_field(f.name, value)
            if value <= 0.0:
                raise SafetyConfigError(f"field '{f.name}': must be > 0, got {value}")
            object.__setattr__(self, f.name, value)
        if self.max_voltage_V > ABSOLUTE_MAX_VOLTAGE_V:
            raise SafetyConfigError(
                f"field 'max_voltage_V': {self.max_voltage_V} V is above "
                f"{ABSOLUTE_MAX_VOLTAGE_V:g} V; SI volts expected (3 kV -> 3000.0)"
            )
        if self.watchdog_timeout_s > MAX_WATCHDOG_TIMEOUT_S:
            raise SafetyConfigError(
                f"field 'watchdog_timeout_s': {self.watchdog_timeout_s} s is above "
                f"{MAX_WATCHDOG_TIMEOUT_S:g} s; seconds expected (500 ms -> 0.5)"
            )
        if self.ramp_down_rate_V_per_s > self.slew_rate_V_per_s:
            raise SafetyConfigError(
                f"field 'ramp_down_rate_V_per_s': {self.ramp_down_rate_V_per_s} V/s exceeds "
                f"slew_rate_V_per_s = {self.slew_rate_V_per_s} V/s; the ramp-down is bounded by "
                "the slew limit too: lower ramp_down_rate_V_per_s or raise slew_rate_V_per_s"
            )
        if self.membrane_limit_V is not None and self.max_voltage_V > self.membrane_limit_V:
            raise SafetyConfigError(
                f"field 'max_voltage_V': {self.max_voltage_V} V exceeds the membrane limit "
                f"{self.membrane_limit_V} V (margin x breakdown field x thickness); lower "
                "max_voltage_V to at most the membrane limit"
            )

    @classmethod
    def from_membrane(
        cls,
        thickness_m: float,
        breakdown_field_V_per_m: float,
        margin: float,
        *,
        slew_rate_V_per_s: float,
        watchdog_timeout_s: float,
        ramp_down_rate_V_per_s: float | None = None,
        max_voltage_V: float | None = None,
        max_time_to_zero_s: float = MAX_TIME_TO_ZERO_S,
    ) -> "SafetyLimits":
        """Limits whose maximum is derived from the membrane.

        The derived limit is ``margin x breakdown_field_V_per_m x thickness_m``.
        ``max_voltage_V`` defaults to it; a configured ``max_voltage_V`` above it
        raises :class:`SafetyConfigError`. ``ramp_down_rate_V_per_s`` defaults to
        the slew rate. The output must reach 0 V within ``max_time_to_zero_s``
        after the last command (watchdog timeout + maximum / ramp-down rate).
        """
        limit_V = membrane_voltage_limit_V(thickness_m, breakdown_field_V_per_m, margin)
        if max_voltage_V is None:
            max_voltage_V = limit_V
        else:
            max_voltage_V = finite_field("max_voltage_V", max_voltage_V)
            if max_voltage_V > limit_V:
                raise SafetyConfigError(
                    f"field 'max_voltage_V': configured {max_voltage_V} V exceeds the membrane "
                    f"limit {limit_V:.6g} V = margin {margin} x breakdown field "
                    f"{breakdown_field_V_per_m:.6g} V/m x thickness {thickness_m:.6g} m; lower "
                    "max_voltage_V, or leave it unset to use the membrane limit"
                )
        if ramp_down_rate_V_per_s is None:
            ramp_down_rate_V_per_s = slew_rate_V_per_s
        limits = cls(
            max_voltage_V=max_voltage_V,
            slew_rate_V_per_s=slew_rate_V_per_s,
            watchdog_timeout_s=watchdog_timeout_s,
            ramp_down_rate_V_per_s=ramp_down_rate_V_per_s,
            membrane_limit_V=limit_V,
        )
        silence_to_zero_s = limits.watchdog_timeout_s + limits.time_to_zero_s(limits.max_voltage_V)
        if silence_to_zero_s > max_time_to_zero_s:
            budget = (f"when commands stop the output would need {limits.watchdog_timeout_s:g} s "
                      f"(watchdog_timeout_s) + {limits.max_voltage_V:.0f} V / "
                      f"{limits.ramp_down_rate_V_per_s:g} V/s = {silence_to_zero_s:.4g} s to reach 0 V, "
                      f"more than {max_time_to_zero_s:g} s")
            if limits.watchdog_timeout_s >= 0.5 * max_time_to_zero_s:
                raise SafetyConfigError(
                    f"field 'watchdog_timeout_s': {budget}; lower watchdog_timeout_s well below "
                    f"{max_time_to_zero_s:g} s (typically 0.2-1 s; a timeout in ms?)")
            needed = limits.max_voltage_V / (max_time_to_zero_s - limits.watchdog_timeout_s)
            raise SafetyConfigError(
                f"field 'ramp_down_rate_V_per_s': {budget}; raise ramp_down_rate_V_per_s to at least "
                f"{needed:.4g} V/s or lower watchdog_timeout_s (a rate in V/ms?)")
        return limits

    @classmethod
    def from_membrane_parameters(cls, parameters: Any, margin: float, **kwargs: Any) -> "SafetyLimits":
        """:meth:`from_membrane` from any object with ``thickness_m`` and
        ``breakdown_field_V_per_m`` (e.g. ``dea_ros.model.parameters.MembraneParameters``)."""
        return cls.from_membrane(
            parameters.thickness_m, parameters.breakdown_field_V_per_m, margin, **kwargs
        )

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str = "safety limits") -> "SafetyLimits":
        """Limits from a mapping (e.g. a YAML section); unknown keys are refused."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise SafetyConfigError(
                f"{source}: unknown field(s) {unknown}; expected a subset of {sorted(names)}"
            )
        missing = sorted(n for n in names - set(data) if n != "membrane_limit_V")
        if missing:
            raise SafetyConfigError(f"{source}: missing field(s) {missing}")
        return cls(**dict(data))

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary of the fields."""
        return dataclasses.asdict(self)

    def time_to_zero_s(self, voltage_V: float) -> float:
        """Time the ramp-down needs from ``voltage_V`` to 0 V, s."""
        return max(0.0, float(voltage_V)) / self.ramp_down_rate_V_per_s
