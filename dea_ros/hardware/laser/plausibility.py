"""Plausibility of decoded distances: the ILD1320's binary stream has no checksum (pure, no I/O).

A corrupted or random byte sequence with the right flag bits decodes to a "valid" distance.
Every distance therefore passes :class:`PlausibilityFilter` (inside the measuring range, not
the first frame after a framing error, within the distance the mass can travel since the
previous accepted value, on the trend of the previous values within what the mass can
accelerate, confirmed by consecutive samples when there is no trusted previous value).

The limits of the mass (:func:`motion_limits`)
----------------------------------------------
The mass moves by eq. 5, ``d'' = g - (c1bar/m) (d/s) (sigma_Maxwell + sigma_mech)``, with the
state ``x = [d, eps1, d']`` of eq. 17. Over the band the mass can reach -- the static equilibria
between 0 V and the largest voltage the amplifier may give, widened on both sides by the band's
width (a step response overshoots by at most the step, eq. 5 being damped by eta2) -- the
acceleration at rest is evaluated on a grid of ``d`` x ``eps1`` (``eps1`` between the extreme
relaxed strains ``lambda_r(d) - 1`` of the band, where eq. 11 keeps it) x ``u in {0, u_max}``:

* ``a_max`` = the largest ``|d''|`` found (the damping term eta2 phi(d) d' of eq. 12 is left to the
  margin: forward integration of steps to and from 0.9 x the breakdown voltage brakes LP1 at 1.27 x
  the grid's bound, A2 at 0.86 x; test/hardware/test_laser_plausibility.py checks it);
* ``v_max = sqrt(2 a_max L)``, ``L`` the width of the widened band: the kinetic energy the mass
  can gain over the band (energy balance of eq. 5 with the largest force over the whole path).

Both are multiplied by ``margin`` (default 2). For A2 at 3150 V: 0.25 m/s and 19.6 m/s^2 (A1:
0.23 m/s, 18.7 m/s^2; LP1: 0.36 m/s, 27.5 m/s^2); the largest |d''| is g, where the membrane is
nearly flat and carries little of the weight.
A sample farther from the last accepted one than ``v_max dt + tol`` is an implausible jump;
farther from the extrapolation ``d_ref + v_ref dt`` than ``a_max dt^2 / 2 + tol_trend (1 + 2 dt /
dt_ref)`` (the error of extrapolating two noisy samples) an implausible acceleration. ``tol`` (20 um)
covers a step of the target's surface; ``tol_trend`` (5 um) only the sensor's noise and quantisation
(the ILD1320-10 repeats to 0.5 um, a quantum is 0.16 um; with 1 um of noise the extrapolation error has
sigma sqrt(6) um, so 15 um at dt = dt_ref is 6 sigma): with the 20 um of ``tol`` there, a bit flipped
in a frame 40 um off the trend was accepted, its false velocity rejected the true samples after it
and let a 319 um error through (bench/bench_laser_edges.py, seed 8). At 2 kHz (A2) a corrupted
value more than ~0.15 mm from the last sample fails the first, one more than ~15 um off the trend
the second. A torn membrane (free fall, outside the model) is refused until the mass
is still again, then the chain of consistent samples re-anchors.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...model.dynamics import DEAModel
from ...model.equilibrium import static_equilibrium
from ...model.parameters import MembraneParameters
from .base import MeasurementError, validated_measuring_range_m
from .ild1320_protocol.frames import DEFAULT_MEASURING_RANGE_M

__all__ = [
    "DEFAULT_MAX_SPEED_M_PER_S",
    "DEFAULT_JUMP_TOLERANCE_M",
    "DEFAULT_TREND_TOLERANCE_M",
    "DEFAULT_CONFIRM_SAMPLES",
    "DEFAULT_MOTION_MARGIN",
    "MotionLimits",
    "motion_limits",
    "PlausibilityFilter",
]

#: Speed limit (m/s) when no membrane is given: a mass falling freely through the whole 10 mm
#: range (a torn membrane) reaches sqrt(2 g 10 mm) = 0.44 m/s; the model bounds of the presets
#: (:func:`motion_limits`) are tighter.
DEFAULT_MAX_SPEED_M_PER_S = 0.5
#: Default allowance for sensor noise and quantisation on top of the limits (m).
DEFAULT_JUMP_TOLERANCE_M = 20e-6
#: Allowance for sensor noise and quantisation on the extrapolated trend (m), see the module docstring.
DEFAULT_TREND_TOLERANCE_M = 5e-6
#: Consecutive consistent samples needed to accept a value without a trusted previous one.
DEFAULT_CONFIRM_SAMPLES = 3
#: Factor on the model's bounds of speed and acceleration.
DEFAULT_MOTION_MARGIN = 2.0


@dataclass(frozen=True)
class MotionLimits:
    """Largest speed (m/s) and acceleration (m/s^2) of the mass, with the margin applied, and
    what they were derived from (see the module docstring)."""

    max_speed_m_per_s: float
    max_acceleration_m_per_s2: float
    band_m: tuple[float, float]  # displacement band evaluated, m
    max_voltage_V: float
    margin: float


def motion_limits(params: MembraneParameters, max_voltage_V: float,
                  margin: float = DEFAULT_MOTION_MARGIN, grid_points: int = 81) -> MotionLimits:
    """Speed and acceleration the mass on ``params`` can have up to ``max_voltage_V`` (module docstring)."""
    margin = float(margin)
    if not (math.isfinite(margin) and margin >= 1.0):
        raise ValueError(f"margin must be >= 1, got {margin!r}")
    u_max = float(max_voltage_V)
    if not (math.isfinite(u_max) and u_max >= 0.0):
        raise ValueError(f"max_voltage_V must be >= 0 V, got {max_voltage_V!r}")
    ends = static_equilibrium(params, np.array([0.0, u_max])).displacement_m
    lo, hi = float(np.min(ends)), float(np.max(ends))
    width = max(hi - lo, 1e-6)
    lo, hi = max(lo - width, 1e-9), hi + width
    model = DEAModel.from_parameters(params)
    d = np.linspace(lo, hi, grid_points)
    relaxed = np.sqrt(model.stretch_squared(d)) - 1.0  # lambda_r(d) - 1 (eq. 11 at rest)
    eps1 = np.linspace(float(relaxed.min()), float(relaxed.max()), grid_points)
    dd, ee = np.meshgrid(d, eps1)
    a_max = 0.0
    for u2 in (0.0, u_max ** 2):
        accel = model.rhs_u2(dd, ee, np.zeros_like(dd), u2)[2]
        a_max = max(a_max, float(np.max(np.abs(accel))))
    v_max = math.sqrt(2.0 * a_max * (hi - lo))
    return MotionLimits(margin * v_max, margin * a_max, (lo, hi), u_max, margin)


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
    3b. ``IMPLAUSIBLE_ACCELERATION`` (with ``max_acceleration_m_per_s2``): off the trend of
       the last two accepted samples by more than ``a dt^2 / 2 + tol_trend (1 + 2 dt / dt_ref)``
       (``trend_tolerance_m``).
    4. ``UNCONFIRMED``: without a trusted reference (start of the stream, after
       :meth:`reset`) a value is accepted only as the ``confirm_samples``-th of
       consecutive samples each consistent with its predecessor; the same chain
       re-anchors the reference after a real jump (a target moved by hand):
       the samples of the chain before the last are discarded.

    Counters: ``accepted``, ``discarded`` (per :class:`MeasurementError`, sensor
    error codes included) and ``reanchors``. Never raises on values.
    """

    #: With the acceleration check: a reference more than this many sample spacings old needs confirmation.
    STALE_SPACINGS = 4.0

    def __init__(
        self,
        measuring_range_m: float = DEFAULT_MEASURING_RANGE_M,
        *,
        max_speed_m_per_s: float = DEFAULT_MAX_SPEED_M_PER_S,
        jump_tolerance_m: float = DEFAULT_JUMP_TOLERANCE_M,
        confirm_samples: int = DEFAULT_CONFIRM_SAMPLES,
        max_acceleration_m_per_s2: float | None = None,
        trend_tolerance_m: float = DEFAULT_TREND_TOLERANCE_M,
    ) -> None:
        self.trend_tolerance_m = float(trend_tolerance_m)
        if not (math.isfinite(self.trend_tolerance_m) and self.trend_tolerance_m >= 0.0):
            raise ValueError(f"trend_tolerance_m must be >= 0 m, got {trend_tolerance_m!r}")
        self.max_acceleration_m_per_s2 = None if max_acceleration_m_per_s2 is None else float(
            max_acceleration_m_per_s2)
        if self.max_acceleration_m_per_s2 is not None and not (
                math.isfinite(self.max_acceleration_m_per_s2) and self.max_acceleration_m_per_s2 > 0.0):
            raise ValueError(f"max_acceleration_m_per_s2 must be positive, got {max_acceleration_m_per_s2!r}")
        self._velocity: tuple[float, float] | None = None  # (m/s, dt of its difference s) at the reference
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
        self._velocity = None
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

    def _on_trend(self, t_s: float, d_m: float) -> bool:
        """Within the acceleration limit of the extrapolation of the last two accepted samples; a
        reference older than ``STALE_SPACINGS`` sample spacings is no trend (the allowance would have
        grown past what a corrupted value needs): the chain of consistent samples decides then."""
        if self.max_acceleration_m_per_s2 is None or self._velocity is None or self._ref is None:
            return True
        v_ref, dt_ref = self._velocity
        dt = t_s - self._ref[0]
        if dt > self.STALE_SPACINGS * dt_ref:
            return False
        allowed = 0.5 * self.max_acceleration_m_per_s2 * dt * dt \
            + self.trend_tolerance_m * (1.0 + 2.0 * dt / dt_ref)
        return abs(d_m - self._ref[1] - v_ref * dt) <= allowed

    def _accept(self, t_s: float, d_m: float) -> None:
        if self._ref is not None and t_s > self._ref[0]:
            dt = t_s - self._ref[0]
            self._velocity = ((d_m - self._ref[1]) / dt, dt)
        self._ref = (t_s, d_m)
        self.accepted += 1

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
        off_trend = False
        if self._ref is not None and self._consistent(self._ref, t, d):
            if self._on_trend(t, d):
                self._chain = []
                self._accept(t, d)
                return d
            off_trend = True  # the chain of consistent samples decides
        if self._chain and self._consistent(self._chain[-1], t, d):
            self._chain.append((t, d))
        else:
            self._chain = [(t, d)]
        if len(self._chain) >= self.confirm_samples:
            if self._ref is not None:
                self.reanchors += 1
            self._velocity = None
            self._ref = self._chain[-2] if len(self._chain) >= 2 else None
            self._accept(t, d)
            self._chain = []
            return d
        if off_trend:
            return self._reject(MeasurementError.IMPLAUSIBLE_ACCELERATION)
        return self._reject(
            MeasurementError.UNCONFIRMED if self._ref is None else MeasurementError.IMPLAUSIBLE_JUMP
        )
