"""Plausibility of decoded distances: the ILD1320's binary stream has no checksum (pure, no I/O).

A corrupted or random byte sequence with the right flag bits decodes to a "valid" distance.
Every distance therefore passes :class:`PlausibilityFilter` (inside the measuring range, not
the first frame after a framing error, within the distance the mass can travel since the
previous accepted value, confirmed by consecutive samples when there is no trusted previous
value).
"""
from __future__ import annotations

import math

from .base import MeasurementError, validated_measuring_range_m
from .ild1320_protocol.frames import DEFAULT_MEASURING_RANGE_M

__all__ = [
    "DEFAULT_MAX_SPEED_M_PER_S",
    "DEFAULT_JUMP_TOLERANCE_M",
    "DEFAULT_CONFIRM_SAMPLES",
    "PlausibilityFilter",
]

#: Default speed limit of the measured target (m/s). The mass on the membrane is
#: driven by the membrane stress and gravity only: forward integration of the
#: model (eq. 17) for steps between 0 V and the breakdown voltage of the A1, A2
#: and LP1 presets gives at most 0.07 m/s (accelerations below 9 m/s^2); a mass
#: falling freely through the whole 10 mm range (a torn membrane) reaches
#: sqrt(2 g 10 mm) = 0.44 m/s. 0.5 m/s covers both.
DEFAULT_MAX_SPEED_M_PER_S = 0.5
#: Default allowance for sensor noise and quantisation on top of the speed limit (m).
DEFAULT_JUMP_TOLERANCE_M = 20e-6
#: Consecutive consistent samples needed to accept a value without a trusted previous one.
DEFAULT_CONFIRM_SAMPLES = 3


class PlausibilityFilter:
    """Per-sample plausibility checks of decoded distances (the stream has no checksum).

    :meth:`check` returns the value when it is accepted, otherwise the reason as
    a :class:`MeasurementError` (sensor error codes pass through unchanged):

    1. ``OUTSIDE_MEASURING_RANGE``: the distance lies in the reserves before the
       SMR or after the EMR (outside ``[0, MR]``).
    2. ``AFTER_FRAMING_ERROR``: bytes were dropped just before the frame; random
       bytes carry valid flag bits once every ~64 positions, so a frame right
       after corrupt bytes is not trusted (the decoder resynchronises on the
       flag bits, the filter on the next clean frame). Also restarts the
       confirmation chain.
    3. ``IMPLAUSIBLE_JUMP``: farther from the last accepted sample than the mass
       can travel in the time between them,
       ``|d - d_ref| > max_speed_m_per_s * (t - t_ref) + jump_tolerance_m``.
    4. ``UNCONFIRMED``: without a trusted reference (start of the stream, after
       :meth:`reset`) a value is accepted only as the ``confirm_samples``-th of
       consecutive samples each consistent with its predecessor; the same chain
       re-anchors the reference after a real jump (a target moved by hand):
       the samples of the chain before the last are discarded.

    Counters: ``accepted``, ``discarded`` (per :class:`MeasurementError`, sensor
    error codes included) and ``reanchors``. Never raises on values.
    """

    def __init__(
        self,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        *,
        max_speed_m_per_s: float = DEFAULT_MAX_SPEED_M_PER_S,
        jump_tolerance_m: float = DEFAULT_JUMP_TOLERANCE_M,
        confirm_samples: int = DEFAULT_CONFIRM_SAMPLES,
    ) -> None:
        self.measuring_range_m = validated_measuring_range_m(measuring_range_m)
        self.max_speed_m_per_s = float(max_speed_m_per_s)
        if not (math.isfinite(self.max_speed_m_per_s) and self.max_speed_m_per_s > 0.0):
            raise ValueError(f"max_speed_m_per_s must be a positive speed, got {max_speed_m_per_s!r}")
        self.jump_tolerance_m = float(jump_tolerance_m)
        if not (math.isfinite(self.jump_tolerance_m) and self.jump_tolerance_m >= 0.0):
            raise ValueError(f"jump_tolerance_m must be >= 0 m, got {jump_tolerance_m!r}")
        if isinstance(confirm_samples, bool) or int(confirm_samples) != confirm_samples \
                or not 1 <= confirm_samples <= 100:
            raise ValueError(f"confirm_samples must be an integer in [1, 100], got {confirm_samples!r}")
        self.confirm_samples = int(confirm_samples)
        self.accepted = 0
        self.discarded: dict[MeasurementError, int] = {}
        self.reanchors = 0
        self._ref: tuple[float, float] | None = None
        self._chain: list[tuple[float, float]] = []

    def reset(self) -> None:
        """Forget the reference and the chain (a new connection); counters are kept."""
        self._ref = None
        self._chain = []

    @property
    def reference(self) -> tuple[float, float] | None:
        """(time s, distance m) of the last accepted sample, or ``None``."""
        return self._ref

    def allowed_jump_m(self, dt_s: float) -> float:
        """Largest plausible change of the distance in ``dt_s`` seconds."""
        return self.max_speed_m_per_s * max(float(dt_s), 0.0) + self.jump_tolerance_m

    def _consistent(self, a: tuple[float, float], t_s: float, d_m: float) -> bool:
        return abs(d_m - a[1]) <= self.allowed_jump_m(t_s - a[0])

    def _reject(self, reason: MeasurementError) -> MeasurementError:
        self.discarded[reason] = self.discarded.get(reason, 0) + 1
        return reason

    def check(
        self, t_s: float, value: float | MeasurementError, framing_error_before: bool = False
    ) -> float | MeasurementError:
        """The value if plausible, else the reason it is discarded (see the class docstring)."""
        if isinstance(value, MeasurementError):
            return self._reject(value)
        try:
            d = float(value)
            t = float(t_s)
        except (TypeError, ValueError):
            return self._reject(MeasurementError.UNKNOWN_CODE)
        if not (math.isfinite(d) and math.isfinite(t)):
            return self._reject(MeasurementError.UNKNOWN_CODE)
        if framing_error_before:
            self._chain = []
            return self._reject(MeasurementError.AFTER_FRAMING_ERROR)
        if not 0.0 <= d <= self.measuring_range_m:
            return self._reject(MeasurementError.OUTSIDE_MEASURING_RANGE)
        if self._ref is not None and self._consistent(self._ref, t, d):
            self._chain = []
            self._ref = (t, d)
            self.accepted += 1
            return d
        if self._chain and self._consistent(self._chain[-1], t, d):
            self._chain.append((t, d))
        else:
            self._chain = [(t, d)]
        if len(self._chain) >= self.confirm_samples:
            if self._ref is not None:
                self.reanchors += 1
            self._chain = []
            self._ref = (t, d)
            self.accepted += 1
            return d
        return self._reject(
            MeasurementError.UNCONFIRMED if self._ref is None else MeasurementError.IMPLAUSIBLE_JUMP
        )
