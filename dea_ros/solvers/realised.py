"""The response a measurement sees where no periodic solution is stable: forward integration.

Where the periodic solutions the continuation follows are all unstable (a torus band after
a Neimark-Sacker bifurcation, or beyond a period-doubling cascade) the rig shows a modulated,
quasi-periodic (or chaotic) motion. :func:`realised_response` integrates the model (eq. 17)
from a given state with a fixed-step classical Runge-Kutta scheme on plain floats
(``steps_per_period`` steps per excitation period, u^2 tabulated at the stage phases), lets
``settle_periods`` excitation periods pass and then measures over ``window_periods``:

* ``d_rms_m``: eq. 21 over the whole window (what a long record gives);
* ``d_rms_min_m`` / ``d_rms_max_m``: the smallest and largest RMS over single excitation
  periods in the window (the envelope of the modulation);
* ``kind``: ``"periodic"`` when the state repeats every T/2 (with a T/2-periodic u^2) or every
  T, ``"period-doubled"`` when it repeats every T but not every T/2 (or every 2T, 4T),
  otherwise ``"quasi-periodic"`` (no repetition over the last 8 periods to 1e-4 of the state
  scale).

Accuracy: at the default 64 steps per period the RK4 RMS of a stable periodic orbit agrees
with the harmonic balance to ~2e-4 (1e-5 at 128 steps; tested); the window average of a
quasi-periodic motion is a statistic of the window, stated with it (its scatter between
windows is several per cent in the A2 torus band). Cost: ~5 us per step on plain floats,
~0.2 s for the default 300 periods.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..model.dynamics import DEAModel
from ..model.parameters import MembraneParameters
from .inputs import PeriodicInput
from .jit import jit

__all__ = ["RealisedResponse", "realised_response", "rk4_periods", "SETTLE_PERIODS", "WINDOW_PERIODS"]

#: Default number of excitation periods integrated before the measurement window.
SETTLE_PERIODS = 100
#: Default number of excitation periods in the measurement window.
WINDOW_PERIODS = 200


@dataclass
class RealisedResponse:
    """What forward integration shows at one frequency (see the module docstring)."""

    frequency_Hz: float
    d_rms_m: float
    d_rms_min_m: float
    d_rms_max_m: float
    mean_displacement_m: float
    kind: str
    settle_periods: int
    window_periods: int
    steps_per_period: int
    wall_time_s: float
    final_state: np.ndarray

    @property
    def window_s(self) -> tuple:
        """(start, end) of the measurement window in s from the start of the integration."""
        t = 1.0 / self.frequency_Hz
        return (self.settle_periods * t, (self.settle_periods + self.window_periods) * t)

    def to_dict(self) -> dict:
        return {
            "frequency_Hz": self.frequency_Hz, "d_rms_m": self.d_rms_m, "d_rms_min_m": self.d_rms_min_m,
            "d_rms_max_m": self.d_rms_max_m, "mean_displacement_m": self.mean_displacement_m,
            "kind": self.kind, "settle_periods": self.settle_periods, "window_periods": self.window_periods,
            "window_s": list(self.window_s), "steps_per_period": self.steps_per_period,
        }


@jit
def rk4_periods(constants, x0, u2_tab, h, steps, total, d0_m, settle_periods, starts, halves, per_period_ms,
                per_period_mean):
    """Classical RK4 over ``total`` periods of ``steps`` steps (h s each) from x0, the model of eq. 18.

    ``u2_tab`` holds u^2 at the 2 * steps node and midpoint phases of a period. Fills ``starts``
    (total + 1, 3: the state at each period start), ``halves`` (the state half a period in), and,
    after ``settle_periods``, the mean of (d - d0)^2 and of d per period. Returns (period index
    where d left |d| < 1 m, or -1; the last d). Compiled (:func:`~dea_ros.solvers.jit.jit`).
    """
    l0_sq, kg, c2, k1, rr, eta2, g, b1, b2, b3, g1, g2, g3 = constants

    def f(d, e, v, u2):
        s = 1.0 + d * d / l0_sq
        lam = math.sqrt(s)
        si = 1.0 / s
        strain = lam - 1.0 - e
        stress = (c2 * u2 * s + (b1 + (b2 + b3 * s) * s) * s - (g1 + (g2 + g3 * si) * si) * si
                  + k1 * strain + eta2 * d / (l0_sq * lam) * v)
        return v, rr * strain, g - kg * d * si * stress

    d, e, v = float(x0[0]), float(x0[1]), float(x0[2])
    h2, h6 = 0.5 * h, h / 6.0
    for n in range(total):
        starts[n, 0], starts[n, 1], starts[n, 2] = d, e, v
        acc = 0.0
        acc_d = 0.0
        for k in range(steps):
            if k == steps // 2:
                halves[n, 0], halves[n, 1], halves[n, 2] = d, e, v
            dd = d - d0_m
            acc += dd * dd
            acc_d += d
            u_a = u2_tab[2 * k]
            u_m = u2_tab[2 * k + 1]
            u_b = u2_tab[(2 * k + 2) % (2 * steps)]
            k1d, k1e, k1v = f(d, e, v, u_a)
            k2d, k2e, k2v = f(d + h2 * k1d, e + h2 * k1e, v + h2 * k1v, u_m)
            k3d, k3e, k3v = f(d + h2 * k2d, e + h2 * k2e, v + h2 * k2v, u_m)
            k4d, k4e, k4v = f(d + h * k3d, e + h * k3e, v + h * k3v, u_b)
            d += h6 * (k1d + 2.0 * k2d + 2.0 * k3d + k4d)
            e += h6 * (k1e + 2.0 * k2e + 2.0 * k3e + k4e)
            v += h6 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
        if not (abs(d) < 1.0):
            return n, d
        if n >= settle_periods:
            per_period_ms[n - settle_periods] = acc / steps      # rectangle rule: exact for the period
            per_period_mean[n - settle_periods] = acc_d / steps
    starts[total, 0], starts[total, 1], starts[total, 2] = d, e, v
    return -1, d


def realised_response(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    x0,
    d0_m: float,
    settle_periods: int = SETTLE_PERIODS,
    window_periods: int = WINDOW_PERIODS,
    steps_per_period: int = 64,
    repeat_tol: float = 1e-4,
) -> RealisedResponse:
    """Integrate from ``x0`` ([d, eps1, d'] at phase 0) and measure the response (module docstring).

    ``d0_m`` is the reference of eq. 21 (the rest position at 0 V for the paper's d_rms).
    """
    t_start = time.perf_counter()
    if settle_periods < 0 or window_periods < 1:
        raise ValueError("settle_periods >= 0 and window_periods >= 1 required")
    steps = int(steps_per_period)
    if steps < 8 or steps % 2:
        raise ValueError(f"steps_per_period: an even number >= 8, got {steps_per_period}")
    model = DEAModel.from_parameters(params)
    period = 1.0 / periodic_input.frequency_Hz
    h = period / steps
    # u^2 at the RK4 stage phases: node k at 2k, midpoint at 2k + 1 (2 * steps entries per period)
    phase = np.pi * np.arange(2 * steps) / steps
    u2_tab = [float(v) for v in periodic_input.at_phase(phase) ** 2]
    total = settle_periods + window_periods
    d = float(np.asarray(x0, float).reshape(3)[0])
    scale = max(abs(d), 1e-3 * params.electrode_width_m)
    l0_sq = model.l0_sq
    per_period_ms = np.empty(window_periods)
    per_period_mean = np.empty(window_periods)
    starts = np.empty((total + 1, 3))
    halves = np.empty((total, 3))
    diverged, d = rk4_periods(model.constants, np.asarray(x0, float).reshape(3), np.array(u2_tab), h, steps, total,
                              float(d0_m), settle_periods, starts, halves, per_period_ms, per_period_mean)
    if diverged >= 0:
        raise FloatingPointError(f"integration diverged at {periodic_input.frequency_Hz:g} Hz (d = {d})")
    rms_each = np.sqrt(per_period_ms)
    # What repeats: the state every q periods (q = 1, 2, 4) over the last 8 periods.
    sc = np.array([scale, max(scale * scale / l0_sq, 1e-9), scale * 2.0 * np.pi / period])
    kind = "quasi-periodic"
    last = starts[-9:] / sc
    for q in (1, 2, 4):
        if np.max(np.abs(last[q:] - last[:-q])) < repeat_tol:
            if q == 1:
                symmetric = periodic_input.u2_half_periodic() and \
                    np.max(np.abs(halves[-8:] / sc - starts[-9:-1] / sc)) < repeat_tol
                kind = "periodic" if (symmetric or not periodic_input.u2_half_periodic()) else "period-doubled"
            else:
                kind = "period-doubled"
            break
    return RealisedResponse(
        frequency_Hz=float(periodic_input.frequency_Hz),
        d_rms_m=float(math.sqrt(np.mean(per_period_ms))),
        d_rms_min_m=float(np.min(rms_each)),
        d_rms_max_m=float(np.max(rms_each)),
        mean_displacement_m=float(np.mean(per_period_mean)),
        kind=kind,
        settle_periods=int(settle_periods),
        window_periods=int(window_periods),
        steps_per_period=steps,
        wall_time_s=time.perf_counter() - t_start,
        final_state=starts[total].copy(),
    )
