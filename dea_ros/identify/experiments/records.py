"""Sampled records under a periodic voltage: whole periods, the RMS of eq. 21, laser noise, the applied input.

* :func:`period_weights` -- quadrature weights of the samples over the largest whole number of
  excitation periods (interpolated period boundaries; a record one sample short keeps its last period);
* :func:`rms_statistics` -- d_rms of eq. 21 over those periods with the laser noise removed, and its
  standard uncertainty;
* :func:`third_difference_noise` -- the white laser noise of a record from its third differences;
* :func:`periodic_input_from_record` -- the voltage the membrane actually received, as one period
  for harmonic balance (the model sees u^2 only, eq. 6).
"""
from __future__ import annotations

import math

import numpy as np

from ...errors import ExperimentError
from ...solvers.inputs import SampledPeriodic

__all__ = ["period_weights", "rms_statistics", "third_difference_noise", "detrended_rms",
           "periodic_input_from_record"]


def periodic_input_from_record(time_s, voltage_V, frequency_Hz: float, hold: str = "linear",
                               harmonics: int = 24, samples: int = 256, source: str = "sine record"):
    """The voltage actually applied during a record, as one period for harmonic balance
    (a SampledPeriodic, phase 0 at the first sample).

    The model sees u^2 only (eq. 6): the harmonics 0..``harmonics`` of the excitation frequency
    of u^2 over whole periods of the record (the period average of what the membrane received,
    with command jitter and slew limiting included), then u = sqrt(u^2) sampled at ``samples``
    phases. How u^2 between the samples is known depends on ``hold``: ``zoh`` (a held staircase,
    as an amplifier fed by a DAQ or a command topic at a finite rate applies it; each value from
    its time stamp until the next): the Fourier integrals of the piecewise-constant u^2 are
    exact, so the hold's sinc(2 f / f_hold) attenuation of the 2f component and its half-step
    delay are in the input; ``linear`` (samples of a continuous waveform): least-squares
    projection of the samples.
    """
    t = np.asarray(time_s, float) - float(time_s[0])
    u = np.asarray(voltage_V, float)
    f = float(frequency_Hz)
    dt = float(np.median(np.diff(t)))
    # only harmonics below the Nyquist frequency of the samples (above it the projection aliases,
    # and a staircase has its images of the hold rate there)
    harmonics = max(2, min(int(harmonics), int(0.45 / (dt * f))))
    k = np.arange(1, harmonics + 1)
    if hold == "zoh":
        n = int(math.floor((t[-1] + dt) * f + 1e-9))   # the last value holds one sample interval
        if n < 1:
            raise ExperimentError(f"{source}: shorter than one period at {f:g} Hz")
        length = n / f
        a = np.minimum(t, length)
        b = np.minimum(np.r_[t[1:], t[-1] + dt], length)
        kw = (2.0 * np.pi * f * k)[:, None]
        u2 = u * u
        coeffs = np.r_[float(u2 @ (b - a)) / length,
                       2.0 / length * ((np.sin(kw * b) - np.sin(kw * a)) / kw) @ u2,
                       2.0 / length * ((np.cos(kw * a) - np.cos(kw * b)) / kw) @ u2]
        keep = t < length
    else:
        keep = period_weights(t, f, source)[0] > 0
        theta = 2.0 * np.pi * f * t[keep]
        basis = np.column_stack([np.ones_like(theta), np.cos(np.outer(theta, k)), np.sin(np.outer(theta, k))])
        coeffs, *_ = np.linalg.lstsq(basis, u[keep] ** 2, rcond=None)
    phase = 2.0 * np.pi * np.arange(samples) / samples
    grid = np.column_stack([np.ones_like(phase), np.cos(np.outer(phase, k)), np.sin(np.outer(phase, k))])
    period = np.sqrt(np.clip(grid @ coeffs, 0.0, None))
    peak = float(np.max(np.abs(u[keep])))
    if np.max(period) > 1.05 * peak + 1.0:
        raise ExperimentError(
            f"{source}: the applied voltage at {f:g} Hz cannot be represented with {harmonics} harmonics "
            f"(projection peaks at {np.max(period):.0f} V, data at {peak:.0f} V); record more samples per period")
    return SampledPeriodic(period, f)


def _interpolant_weights(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """Weights w with sum(w f) = integral over [a, b] of the linear interpolant of (t, f)."""
    w = np.zeros(t.size)
    left, right = t[:-1], t[1:]
    c = np.clip(a, left, right)
    e = np.clip(b, left, right)
    h = right - left
    use = e > c
    w[:-1] += np.where(use, ((right - c) ** 2 - (right - e) ** 2) / (2.0 * h), 0.0)
    w[1:] += np.where(use, ((e - left) ** 2 - (c - left) ** 2) / (2.0 * h), 0.0)
    return w


def period_weights(time_s, frequency_Hz: float, source: str = "sine record", max_gap_samples: float = 3.0):
    """Weights (s) of the samples for the integral over the largest whole number n of periods
    T = 1/f from the first sample: (weights, n, wrapped).

    The window [t0, t0 + n T] is integrated on the linear interpolant of the samples; its end
    falls between two samples in general (interpolated boundary). When the record stops short of
    t0 + n T by at most ``max_gap_samples`` sample intervals (a record of floor(n T f_s) samples,
    or one sample fewer), the periodic steady state supplies the missing end: the integral over
    [t_last, t0 + n T] equals the one over [t_last - T, t0 + (n-1) T], inside the record, so a
    record one sample short does not lose a whole period (``wrapped``). The trapezoidal end
    corrections of the pieces cancel by periodicity: the mean square of a periodic record is
    accurate to ~1e-6 whatever the number of samples per period.
    Raises :class:`ExperimentError` for a record shorter than one period.
    """
    t = np.asarray(time_s, float) - float(time_s[0])
    dt = float(np.median(np.diff(t)))
    period = 1.0 / float(frequency_Hz)
    n = int(math.floor((t[-1] + max_gap_samples * dt * (1.0 + 1e-9)) / period + 1e-12))
    if n < 1:
        raise ExperimentError(f"{source}: shorter than one period at {frequency_Hz:g} Hz")
    end = n * period
    if end <= t[-1]:
        return _interpolant_weights(t, 0.0, end), n, False
    w = _interpolant_weights(t, 0.0, t[-1])
    if t[-1] - period >= 0.0:
        w += _interpolant_weights(t, t[-1] - period, end - period)
    else:  # a single period: close it with the periodic trapezoid d(t0 + T) = d(t0)
        gap = end - t[-1]
        w[-1] += 0.5 * gap
        w[0] += 0.5 * gap
    return w, n, True


def rms_statistics(series, d0_m: float, noise_m: float | None = None,
                   d0_std_m: float = 0.0) -> tuple:
    """(d_rms, its standard uncertainty or None) of a sampled record over whole periods (eq. 21).

    ``series``: a :class:`~dea_ros.identify.experiments.data.SineSeries` (its time_s, frequency_Hz,
    displacement_m and source). See :meth:`SineSeries.displacement_rms`. Uncertainty (``noise_m``
    given): white noise on every sample and the uncertainty of d0, propagated linearly through the
    weighted mean square.
    """
    w, _n, _wrap = period_weights(series.time_s, series.frequency_Hz, series.source)
    total = float(np.sum(w))
    dev = series.displacement_m - float(d0_m)
    ms = float(w @ (dev * dev)) / total
    if noise_m is not None:
        ms -= float(noise_m) ** 2 + float(d0_std_m) ** 2
    rms = math.sqrt(max(ms, 0.0))
    if noise_m is None or rms <= 0:
        return rms, None
    grad = w * dev / (total * rms)
    mean_dev = float(w @ dev) / total
    var = float(noise_m) ** 2 * float(grad @ grad) + (mean_dev / rms) ** 2 * float(d0_std_m) ** 2
    return rms, math.sqrt(var)


def third_difference_noise(d, min_samples: int = 20) -> float | None:
    """White-noise sigma of samples d from their third differences (variance 20 sigma^2; robust
    spread): slow motion (ringing, creep, a sine well below the sample rate) hardly enters.
    None for fewer than ``min_samples`` samples."""
    d = np.asarray(d, float)
    if d.size < min_samples:
        return None
    d3 = np.diff(d, 3)
    mad = float(np.median(np.abs(d3 - np.median(d3))))
    return 1.4826 * mad / math.sqrt(20.0)


def detrended_rms(time_s, d) -> float:
    """RMS of samples ``d`` about their least-squares straight line in ``time_s`` (m): the laser noise
    alone where the membrane is at rest or drifting uniformly, more where it still rings or creeps."""
    t = np.asarray(time_s, float)
    t = t - t[0]
    d = np.asarray(d, float)
    return float(np.std(d - np.polyval(np.polyfit(t, d, 1), t)))
