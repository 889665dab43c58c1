"""Voltage inputs u(t) in V: steps, sines, sampled arrays, and periodic inputs for harmonic balance.

Transient signals are callables ``u(t)`` (vectorised) with a list of
``breakpoints`` (times where u or its slope jumps) so the adaptive integrator
can restart there. Periodic inputs are functions of the phase
``theta = omega t`` in [0, 2 pi) with a frequency, as harmonic balance needs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "VoltageSignal", "ConstantVoltage", "StepVoltage", "SineVoltage", "SampledVoltage",
    "PeriodicInput", "SinePeriodic", "SampledPeriodic", "check_voltage", "check_recorded_voltage",
    "check_harmonics", "MAX_HARMONICS", "MIN_PLAUSIBLE_PEAK_V", "input_groups", "squared_input_rows",
]

#: Largest number of harmonics accepted from a user: the harmonic-balance solve (and its Floquet
#: stability) grows like (2N + 1)^3 per frequency, so N = 100000 would never finish; N <= 16
#: resolves the DEA's response (the solvers warn when a higher harmonic still matters) and 32 is
#: the most the solver's ``n_harmonics="auto"`` tries.
MAX_HARMONICS = 32
#: A recorded DEA drive voltage whose peak is below this is taken for a unit slip (kV for V):
#: DEAs need hundreds to thousands of volts to move at all.
MIN_PLAUSIBLE_PEAK_V = 50.0


def check_harmonics(value, name: str = "n_harmonics") -> int:
    """An integer number of harmonics in 1..:data:`MAX_HARMONICS`, or ValueError naming ``name``."""
    try:
        n = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: an integer number of harmonics is needed, got {value!r}") from None
    if n != value or not 1 <= n <= MAX_HARMONICS:
        raise ValueError(
            f"{name}: must be an integer from 1 to {MAX_HARMONICS}, got {value!r} (the solve grows like "
            f"(2N+1)^3 per frequency; N <= 16 resolves a DEA response, {MAX_HARMONICS} is the most "
            "the solver's automatic choice uses)"
        )
    return n


def check_recorded_voltage(voltage_V, name: str = "voltage_V") -> np.ndarray:
    """A recorded or measured drive voltage in V: finite, not negative, not a kV unit slip.

    DEA amplifiers are unipolar (0 V to a few kV), so a negative sample is an offset or sign
    error; a peak below :data:`MIN_PLAUSIBLE_PEAK_V` (but above 0) is almost surely kV written
    as V (2.5 instead of 2500). Raises ValueError naming ``name``, the value and the fix.
    """
    u = check_voltage(voltage_V, name)
    if u.size and np.min(u) < 0.0:
        k = int(np.argmin(u))
        raise ValueError(
            f"{name}: negative voltage {u.flat[k]:g} V (sample {k}); a DEA amplifier drives 0 V to a few kV "
            "(remove the offset or the sign)"
        )
    peak = float(np.max(np.abs(u), initial=0.0))
    if 0.0 < peak < MIN_PLAUSIBLE_PEAK_V:
        raise ValueError(
            f"{name}: the largest voltage is {peak:g} V, too small to move a DEA: this looks like kV; "
            f"give volts (2.5 kV -> 2500)"
        )
    return u


def check_voltage(value, name: str = "voltage_V") -> np.ndarray:
    """Reject NaN/inf voltages with a message naming the argument."""
    arr = np.asarray(value, dtype=float)
    # a plain number (np.float64 too) by float arithmetic; arrays by one reduction (NaN and inf propagate)
    peak = abs(float(value)) if isinstance(value, (int, float)) else float(np.max(np.abs(arr), initial=0.0))
    if not math.isfinite(peak):
        raise ValueError(f"{name}: must be finite (got NaN or inf)")
    if peak > 1e6:
        raise ValueError(f"{name}: {peak:.3g} V is beyond any DEA amplifier; volts expected (2.5 kV -> 2500)")
    return arr


class VoltageSignal:
    """Base class of transient inputs: ``signal(t)`` in V, ``breakpoints`` in s."""

    breakpoints: tuple = ()

    def __call__(self, t):  # pragma: no cover - interface
        raise NotImplementedError


@dataclass(frozen=True)
class ConstantVoltage(VoltageSignal):
    voltage_V: float

    def __post_init__(self):
        check_voltage(self.voltage_V)

    def __call__(self, t):
        return np.full(np.shape(t), float(self.voltage_V)) if np.ndim(t) else float(self.voltage_V)


@dataclass(frozen=True)
class StepVoltage(VoltageSignal):
    """u = initial_V for t < step_time_s, final_V afterwards."""

    final_V: float
    step_time_s: float = 0.0
    initial_V: float = 0.0

    def __post_init__(self):
        check_voltage(self.final_V, "final_V")
        check_voltage(self.initial_V, "initial_V")

    @property
    def breakpoints(self):
        return (float(self.step_time_s),)

    def __call__(self, t):
        return np.where(np.asarray(t) < self.step_time_s, self.initial_V, self.final_V)


@dataclass(frozen=True)
class SineVoltage(VoltageSignal):
    """u = offset_V + amplitude_V sin(2 pi f t + phase_rad)."""

    amplitude_V: float
    frequency_Hz: float
    offset_V: float = 0.0
    phase_rad: float = 0.0

    def __post_init__(self):
        check_voltage(self.amplitude_V, "amplitude_V")
        check_voltage(self.offset_V, "offset_V")
        if not (np.isfinite(self.frequency_Hz) and self.frequency_Hz > 0):
            raise ValueError(f"frequency_Hz: must be > 0, got {self.frequency_Hz}")

    def __call__(self, t):
        return self.offset_V + self.amplitude_V * np.sin(
            2 * np.pi * self.frequency_Hz * np.asarray(t) + self.phase_rad
        )


@dataclass(frozen=True)
class SampledVoltage(VoltageSignal):
    """A recorded voltage: samples at increasing times, linear interpolation or zero-order hold.

    Before the first sample the first value holds, after the last the last.
    """

    time_s: np.ndarray
    voltage_V: np.ndarray
    hold: str = "linear"

    def __post_init__(self):
        t = np.asarray(self.time_s, dtype=float).reshape(-1)
        u = check_voltage(self.voltage_V, "voltage_V").reshape(-1)
        if t.size != u.size:
            raise ValueError(f"time_s and voltage_V: lengths differ ({t.size} vs {u.size})")
        if t.size < 1 or not np.all(np.isfinite(t)):
            raise ValueError("time_s: needs at least one finite sample")
        if np.any(np.diff(t) <= 0):
            raise ValueError("time_s: must be strictly increasing")
        if self.hold not in ("linear", "zoh"):
            raise ValueError(f"hold: 'linear' or 'zoh', got {self.hold!r}")
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "voltage_V", u)

    @property
    def breakpoints(self):
        if self.hold == "zoh":
            jumps = np.nonzero(np.diff(self.voltage_V))[0] + 1
            return tuple(self.time_s[jumps])
        return ()

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        if self.hold == "linear":
            return np.interp(t, self.time_s, self.voltage_V)
        idx = np.clip(np.searchsorted(self.time_s, t, side="right") - 1, 0, self.time_s.size - 1)
        return self.voltage_V[idx]


# ---------------------------------------------------------------------------- periodic
class PeriodicInput:
    """A T-periodic voltage as a function of phase theta = 2 pi f t (rad)."""

    frequency_Hz: float

    @property
    def omega(self) -> float:
        return 2.0 * np.pi * self.frequency_Hz

    def at_phase(self, theta):  # pragma: no cover - interface
        raise NotImplementedError

    def with_frequency(self, frequency_Hz: float) -> "PeriodicInput":  # pragma: no cover
        raise NotImplementedError

    def waveform_key(self):
        """A hashable key, equal for inputs whose ``at_phase`` is the same function (they may differ
        in frequency), so solvers evaluate a shared waveform once; None when unknown (never shared)."""
        return None

    def as_signal(self) -> VoltageSignal:
        """The same input as a transient signal u(t) for forward integration."""
        inp = self

        class _Signal(VoltageSignal):
            def __call__(self, t):
                return inp.at_phase(inp.omega * np.asarray(t, dtype=float))

        return _Signal()

    def u2_half_periodic(self, samples: int = 64) -> bool:
        """True when u^2 has period T/2 (a sine without offset): the response then has only even harmonics."""
        theta = np.linspace(0.0, np.pi, samples, endpoint=False)
        a = self.at_phase(theta) ** 2
        b = self.at_phase(theta + np.pi) ** 2
        return bool(np.allclose(a, b, rtol=1e-12, atol=1e-9 * max(1.0, np.max(a))))

    def mean_square_V2(self, samples: int = 256) -> float:
        theta = np.linspace(0.0, 2 * np.pi, samples, endpoint=False)
        return float(np.mean(self.at_phase(theta) ** 2))


@dataclass(frozen=True)
class SinePeriodic(PeriodicInput):
    """u = offset_V + amplitude_V sin(theta), theta = 2 pi f t (the paper's excitation)."""

    amplitude_V: float
    frequency_Hz: float
    offset_V: float = 0.0

    def __post_init__(self):
        check_voltage(self.amplitude_V, "amplitude_V")
        check_voltage(self.offset_V, "offset_V")
        if not (math.isfinite(self.frequency_Hz) and self.frequency_Hz > 0):
            raise ValueError(f"frequency_Hz: must be > 0, got {self.frequency_Hz}")

    def at_phase(self, theta):
        return self.offset_V + self.amplitude_V * np.sin(theta)

    def with_frequency(self, frequency_Hz: float) -> "SinePeriodic":
        # amplitude and offset were checked when self was made: only the frequency is new (a sweep
        # makes hundreds of these per design)
        f = float(frequency_Hz)
        if not (math.isfinite(f) and f > 0):
            raise ValueError(f"frequency_Hz: must be > 0, got {f}")
        out = object.__new__(SinePeriodic)
        object.__setattr__(out, "amplitude_V", self.amplitude_V)
        object.__setattr__(out, "frequency_Hz", f)
        object.__setattr__(out, "offset_V", self.offset_V)
        return out

    def waveform_key(self):
        return ("sine", float(self.amplitude_V), float(self.offset_V))

    def u2_half_periodic(self, samples: int = 64) -> bool:
        return self.offset_V == 0.0 or self.amplitude_V == 0.0

    def as_signal(self) -> VoltageSignal:
        return SineVoltage(self.amplitude_V, self.frequency_Hz, self.offset_V)


@dataclass(frozen=True)
class SampledPeriodic(PeriodicInput):
    """One period of a voltage sampled at equal phase steps (K samples over [0, T)).

    Evaluated between samples by trigonometric (Fourier) interpolation.
    """

    voltage_V: np.ndarray
    frequency_Hz: float
    _coeffs: np.ndarray = field(default=None, repr=False, compare=False)
    #: u2_half_periodic per number of samples (the waveform is fixed: a solver asks for every solve)
    _u2_half: dict = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        u = check_voltage(self.voltage_V, "voltage_V").reshape(-1)
        if u.size < 3:
            raise ValueError("voltage_V: a sampled period needs at least 3 samples")
        if not (np.isfinite(self.frequency_Hz) and self.frequency_Hz > 0):
            raise ValueError(f"frequency_Hz: must be > 0, got {self.frequency_Hz}")
        object.__setattr__(self, "voltage_V", u)
        object.__setattr__(self, "_coeffs", np.fft.rfft(u) / u.size)
        object.__setattr__(self, "_u2_half", {})

    def u2_half_periodic(self, samples: int = 64) -> bool:
        """As :meth:`PeriodicInput.u2_half_periodic`, evaluated once per ``samples`` (the waveform is fixed)."""
        hit = self._u2_half.get(samples)
        if hit is None:
            hit = self._u2_half[samples] = super().u2_half_periodic(samples)
        return hit

    def at_phase(self, theta):
        theta = np.asarray(theta, dtype=float)
        c = self._coeffs
        n = np.arange(c.size)
        weights = np.full(c.size, 2.0)
        weights[0] = 1.0
        if self.voltage_V.size % 2 == 0:  # the Nyquist term is counted once
            weights[-1] = 1.0
        phase = np.multiply.outer(theta, n)
        return np.real(np.exp(1j * phase) @ (weights * c))

    def with_frequency(self, frequency_Hz: float) -> "SampledPeriodic":
        return SampledPeriodic(self.voltage_V, float(frequency_Hz))


def input_groups(inputs, divisors) -> tuple:
    """(codes (B,), [(input, divisor)] per code): items with the same waveform
    (:meth:`PeriodicInput.waveform_key`; an input without one is its own) and divisor share a code, so
    that what depends on the waveform only is evaluated once per code."""
    codes = np.empty(len(inputs), dtype=np.int64)
    reps, index = [], {}
    for b, (inp, divisor) in enumerate(zip(inputs, divisors)):
        key = inp.waveform_key()
        key = (id(inp) if key is None else key, divisor)
        code = index.get(key)
        if code is None:
            code = index[key] = len(reps)
            reps.append((inp, divisor))
        codes[b] = code
    return codes, reps


def squared_input_rows(groups: tuple, phases_for) -> np.ndarray:
    """u^2 (V^2) of each item of ``groups`` (:func:`input_groups`) at the phases ``phases_for(divisor)``
    (rad), one row each, evaluated once per code."""
    codes, reps = groups
    return np.stack([inp.at_phase(phases_for(divisor)) ** 2 for inp, divisor in reps])[codes]
