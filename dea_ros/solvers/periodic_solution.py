"""A periodic steady state of the model (:class:`PeriodicSolution`) and what is read from it.

The solution holds the collocation values over one *response* period (the input period T divided
by ``period_divisor``: 2 for a sine without offset, whose u^2 has period T/2), and reads from them
the RMS of eq. 21, harmonic amplitudes, the truncation indicator, values at any time (trigonometric
interpolation) and, once its Floquet multipliers are attached (:func:`.floquet.attach_floquet`),
its stability. Every solver of the periodic steady state returns one (native and mousai harmonic
balance, forward integration, shooting).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from .collocation import periodic_interpolation_matrix
from .floquet import classify_stability
from .inputs import PeriodicInput

__all__ = ["PeriodicSolution", "truncation_ratios"]


@dataclass
class PeriodicSolution:
    """A periodic steady state of the model under a periodic voltage.

    ``state`` holds the collocation values over one *response* period, which is
    the input period T divided by ``period_divisor`` (2 for a sine without
    offset). ``phases`` are the phases of those points in the response period.
    """

    frequency_Hz: float                  # excitation frequency
    periodic_input: PeriodicInput
    state: np.ndarray                    # (3, M)
    period_divisor: int                  # response period = T / period_divisor
    n_harmonics: int                     # harmonics of the response frequency (2N+1 points)
    method: str
    iterations: int
    residual: float                      # max scaled residual at the solution
    wall_time_s: float
    multipliers: np.ndarray | None = None   # Floquet multipliers over the response period
    extra: dict = field(default_factory=dict)
    #: Floquet multipliers over T/2 when a full-period solution (divisor 1) is in fact T/2-periodic
    #: under a T/2-periodic u^2 (see :func:`attach_floquet`): its stability is judged on them
    half_period_multipliers: np.ndarray | None = None

    @property
    def n_points(self) -> int:
        return self.state.shape[1]

    @property
    def response_period_s(self) -> float:
        return 1.0 / (self.frequency_Hz * self.period_divisor)

    @property
    def phases(self) -> np.ndarray:
        return 2.0 * np.pi * np.arange(self.n_points) / self.n_points

    @property
    def times_s(self) -> np.ndarray:
        """Times of the collocation points within the response period, s."""
        return self.phases / (2.0 * np.pi) * self.response_period_s

    @property
    def displacement_m(self) -> np.ndarray:
        return self.state[0]

    @property
    def mean_displacement_m(self) -> float:
        return float(self.state[0].sum()) / self.n_points

    def displacement_rms(self, d0_m: float | None = None) -> float:
        """RMS of d - d0 over a period (eq. 21); exact for the trigonometric polynomial.

        d0 defaults to the mean displacement (then this is the standard deviation).
        """
        d0 = self.mean_displacement_m if d0_m is None else float(d0_m)
        dev = self.state[0] - d0
        return math.sqrt(float(dev @ dev) / self.n_points)

    def peak_to_peak_m(self, samples: int = 512) -> float:
        d = self.evaluate(np.linspace(0, self.response_period_s, samples, endpoint=False))[0]
        return float(d.max() - d.min())

    def evaluate(self, t_s) -> np.ndarray:
        """State at times t (s, any), by trigonometric interpolation; shape (3, len(t))."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        phase = 2.0 * np.pi * np.mod(t / self.response_period_s, 1.0)
        return self.state @ periodic_interpolation_matrix(self.n_points, phase).T

    @property
    def highest_excitation_harmonic(self) -> int:
        """Highest harmonic of the excitation frequency represented (N x period divisor)."""
        return self.n_harmonics * self.period_divisor

    def harmonic_amplitudes_m(self) -> np.ndarray:
        """Amplitudes of d at harmonics 0..N of the response frequency (index 0: mean)."""
        c = np.fft.rfft(self.state[0]) / self.n_points
        amp = 2.0 * np.abs(c)
        amp[0] = abs(c[0].real)
        return amp

    @functools.cached_property
    def truncation_ratio(self) -> float:
        """Amplitude of the highest retained harmonic of d over the largest non-constant one.

        A spectrally converged solution has a small ratio (< 1e-3 is typical at
        0.01 % RMS accuracy); a ratio near 1 means N is far too small and the
        solution may be spurious (a solution of the truncated equations only).
        """
        return float(truncation_ratios([self])[0])

    def odd_harmonic_ratio(self) -> float:
        """RMS of the odd harmonics of the response frequency over that of all non-constant ones.

        For a full-period solution (``period_divisor`` 1) under a sine without offset this is
        0 for the symmetric (T/2-periodic) orbit and O(1) for a period-doubled one.
        """
        c = np.fft.rfft(self.state[0])[1:]
        total = float(np.sum(np.abs(c) ** 2))
        return float(np.sqrt(np.sum(np.abs(c[0::2]) ** 2) / total)) if total > 0 else 0.0

    @property
    def stability_multipliers(self) -> np.ndarray | None:
        """The multipliers that decide stability: over T/2 for a symmetric full-period solution."""
        return self.half_period_multipliers if self.half_period_multipliers is not None else self.multipliers

    @property
    def slowest_time_constant_s(self) -> float:
        """The slowest decay time of a perturbation of the orbit, s: response period / -ln max|multiplier|
        (the periodic counterpart of :func:`dea_ros.model.settling.slowest_time_constant_s`); inf when it
        is not stable, NaN without multipliers."""
        mu, period = self.multipliers, self.response_period_s
        if mu is None:
            mu, period = self.half_period_multipliers, self.response_period_s / 2.0
        if mu is None or not np.all(np.isfinite(mu)):
            return float("nan")
        largest = float(np.max(np.abs(mu)))
        return period / -math.log(largest) if largest < 1.0 else math.inf

    @property
    def stable(self) -> bool | None:
        mu = self.stability_multipliers
        if mu is None:
            return None
        return bool(np.max(np.abs(mu)) < 1.0)

    @property
    def stability(self) -> str:
        """See :func:`classify_stability`."""
        return classify_stability(self.stability_multipliers)


def truncation_ratios(solutions) -> np.ndarray:
    """:attr:`PeriodicSolution.truncation_ratio` of many solutions (one stacked FFT per point count).

    Amplitude of the highest retained harmonic of d over the largest non-constant one (0 when d is
    constant)."""
    sols = list(solutions)
    out = np.zeros(len(sols))
    by_m = {}
    for i, sol in enumerate(sols):
        by_m.setdefault(sol.n_points, []).append(i)
    for m, idx in by_m.items():
        if m < 3:
            continue
        amps = np.abs(np.fft.rfft(np.stack([sols[i].state[0] for i in idx]), axis=1)[:, 1:])
        top = amps.max(axis=1)
        out[idx] = np.divide(amps[:, -1], top, out=np.zeros(len(idx)), where=top > 0)
    return out
