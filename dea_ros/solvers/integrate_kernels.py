"""Compiled kernel of :func:`~dea_ros.solvers.integrate.simulate_held`: the model under a held voltage.

The amplifier holds each voltage for one update period (zero-order hold); within a hold the model
(eq. 18) is autonomous, so each hold is integrated on its own by the embedded Dormand-Prince 5(4) pair
with adaptive steps that end exactly on the hold's end (no dense output, no step across a jump of the
voltage). The model is :func:`dea_ros.model.dynamics.state_equation` compiled as it is (one definition).
"""
from __future__ import annotations

import math

import numpy as np

from ..model.dynamics import state_equation
from .jit import jit

__all__ = ["held_trajectory"]

_state_equation = jit(state_equation)

# Dormand-Prince 5(4) (Hairer, Norsett, Wanner, Solving ODE I, table 5.2)
_A21 = 1.0 / 5.0
_A31, _A32 = 3.0 / 40.0, 9.0 / 40.0
_A41, _A42, _A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
_A51, _A52, _A53, _A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
_A61, _A62, _A63, _A64, _A65 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0
_B1, _B3, _B4, _B5, _B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
_E1, _E3, _E4, _E5, _E6, _E7 = (71.0 / 57600.0, -71.0 / 16695.0, 71.0 / 1920.0, -17253.0 / 339200.0,
                                22.0 / 525.0, -1.0 / 40.0)


@jit
def _f(constants, x, u2):
    f, _jac = _state_equation(constants, x[0], x[1], x[2], u2)
    return np.array([f[0], f[1], f[2]])


@jit
def _hold(constants, x, u2, period, h, rtol, atol):
    """Integrate over one hold of length ``period`` from x (updated in place); returns (h for the next hold,
    accepted steps, rejected steps); h < 0 when the step size collapsed (failure)."""
    t = 0.0
    accepted = 0
    rejected = 0
    k1 = _f(constants, x, u2)
    while t < period * (1.0 - 1e-12):
        last = t + h >= period * (1.0 - 1e-12)
        step = period - t if last else h
        k2 = _f(constants, x + step * _A21 * k1, u2)
        k3 = _f(constants, x + step * (_A31 * k1 + _A32 * k2), u2)
        k4 = _f(constants, x + step * (_A41 * k1 + _A42 * k2 + _A43 * k3), u2)
        k5 = _f(constants, x + step * (_A51 * k1 + _A52 * k2 + _A53 * k3 + _A54 * k4), u2)
        k6 = _f(constants, x + step * (_A61 * k1 + _A62 * k2 + _A63 * k3 + _A64 * k4 + _A65 * k5), u2)
        y = x + step * (_B1 * k1 + _B3 * k3 + _B4 * k4 + _B5 * k5 + _B6 * k6)
        k7 = _f(constants, y, u2)
        err = step * (_E1 * k1 + _E3 * k3 + _E4 * k4 + _E5 * k5 + _E6 * k6 + _E7 * k7)
        norm = 0.0
        for i in range(3):
            sc = atol[i] + rtol * max(abs(x[i]), abs(y[i]))
            norm += (err[i] / sc) ** 2
        norm = math.sqrt(norm / 3.0)
        if not math.isfinite(norm):
            norm = 1e10
        factor = 0.9 * norm ** -0.2 if norm > 0.0 else 5.0
        if norm <= 1.0:
            t += step
            x[:] = y
            k1 = k7
            accepted += 1
            if not last:        # the last step of a hold was shortened: keep the controller's h
                h = step * min(5.0, max(0.2, factor))
        else:
            rejected += 1
            h = step * min(1.0, max(0.1, factor))
            if h < period * 1e-12:
                return -1.0, accepted, rejected
    return h, accepted, rejected


@jit
def held_trajectory(constants, x0, u2_levels, period, rtol, atol):
    """States (3, n + 1) at the ends of n holds of ``period`` s with u^2 = ``u2_levels[k]`` from ``x0``;
    (states, accepted steps, rejected steps, index of the hold that failed or -1)."""
    n = u2_levels.size
    out = np.empty((3, n + 1))
    x = x0.copy()
    out[:, 0] = x
    h = period
    accepted = 0
    rejected = 0
    for k in range(n):
        h, a, r = _hold(constants, x, u2_levels[k], period, min(h, period), rtol, atol)
        accepted += a
        rejected += r
        if h < 0.0:
            return out, accepted, rejected, k
        out[:, k + 1] = x
    return out, accepted, rejected, -1
