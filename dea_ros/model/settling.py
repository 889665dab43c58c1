"""How long a held voltage takes to settle: the slowest time constant of the linearised state equation.

At a static operating point (voltage u, mass m: eq. 20, eps1 relaxed, d' = 0) the state equation
x' = f(x, u) of eqs. 5-12 (eq. 18, :mod:`.dynamics`) linearises to dx' = A dx with A = df/dx its
analytic Jacobian (:meth:`~.dynamics.DEAModel.jacobian`). Its three eigenvalues are the ringing of the
mass (a complex pair, or two real roots when overdamped) and the creep of the viscoelastic damper;
the slowest time constant is tau = 1 / min(-Re lambda). It is not the creep time eta1/k1: the creep
mode couples with the hyperelastic stiffness (the damper relaxes against the membrane's static
stiffness), and on a soft operating point tau is several times eta1/k1.

A transient of amplitude A0 (m) decays below a tolerance tol (m) after

    t_settle = tau ln(A0 / tol)

(the slowest mode governs the tail; the faster modes have decayed more by then). A0 is bounded here
by the jump of the static displacement between the operating point the membrane comes from and the
one it settles to (:func:`settle_time`). When the membrane is not stable there (tau infinite) or the
settle time exceeds a cap, the cap is used and :attr:`SettleTime.capped` says so, with a plain warning
(:meth:`SettleTime.warning`): a record measured then is still settling.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .dynamics import DEAModel
from .equilibrium import static_equilibrium
from .parameters import MembraneParameters

__all__ = ["SettleTime", "slowest_time_constant_s", "settle_time"]


def slowest_time_constant_s(params: MembraneParameters, voltage_V: float = 0.0, mass_kg: float | None = None) -> float:
    """The slowest time constant (s) of the state equation linearised at the static equilibrium at
    ``voltage_V`` (V) and ``mass_kg`` (kg, default ``params.mass_kg``): 1 / min(-Re eig(df/dx)), inf
    where an eigenvalue has a non-negative real part (not stable there). NoEquilibriumError where
    eq. 20 has no solution."""
    p = params if mass_kg is None else params.replace(mass_kg=float(mass_kg))
    eq = static_equilibrium(p, float(voltage_V))
    jac = DEAModel.from_parameters(p).jacobian(np.asarray(eq.state, float).reshape(3), float(voltage_V))
    decay = -np.real(np.linalg.eigvals(np.asarray(jac, float).reshape(3, 3)))
    return float(1.0 / decay.min()) if decay.min() > 0 else math.inf


@dataclass(frozen=True)
class SettleTime:
    """Result of :func:`settle_time` (V, kg, m, s)."""

    voltage_V: float
    mass_kg: float
    time_constant_s: float       # slowest, of the linearisation at the operating point (inf: not stable)
    amplitude_m: float           # initial transient amplitude bound: largest static displacement jump
    tolerance_m: float           # what may be left of the transient when the record is measured
    uncapped_s: float            # tau ln(amplitude / tolerance), at least min_s (inf when tau is)
    settle_s: float              # min(uncapped_s, cap_s)
    cap_s: float

    @property
    def capped(self) -> bool:
        return self.uncapped_s > self.cap_s

    @property
    def residual_m(self) -> float:
        """The transient left after ``settle_s`` (m): amplitude e^(-settle_s / tau)."""
        if not math.isfinite(self.time_constant_s):
            return self.amplitude_m
        return self.amplitude_m * math.exp(-self.settle_s / self.time_constant_s)

    def warning(self, what: str = "") -> str:
        """A plain warning when the cap bites ('' otherwise); ``what``: the hold's name (default: the hold at
        its voltage and mass)."""
        if not self.capped:
            return ""
        if not math.isfinite(self.time_constant_s):
            why = "the membrane is not stable there (an eigenvalue of the linearisation has Re >= 0)"
        else:
            why = (f"its slowest time constant is {self.time_constant_s:.3g} s: settling to "
                   f"{self.tolerance_m * 1e9:.3g} nm needs {self.uncapped_s:.3g} s; up to "
                   f"{self.residual_m * 1e6:.3g} um of the transient is left")
        what = what or f"the hold at {self.voltage_V:.0f} V ({self.mass_kg * 1e3:.3g} g)"
        return f"{what} is capped at {self.cap_s:.3g} s: {why}; the record is measured before the membrane has settled"


def settle_time(params: MembraneParameters, voltage_V: float, from_voltages_V: Sequence[float] = (0.0,),
                tolerance_m: float = 2e-9, cap_s: float = 60.0, min_s: float = 0.0,
                mass_kg: float | None = None, slower_s: float = 0.0) -> SettleTime:
    """How long to hold ``voltage_V`` (V) at ``mass_kg`` (default ``params.mass_kg``) after arriving from
    any of ``from_voltages_V`` (relaxed there) until the transient is below ``tolerance_m`` (module
    docstring): tau ln(A0 / tol), A0 the largest jump of the static displacement, at least ``min_s``,
    at most ``cap_s``. ``slower_s``: a time constant known otherwise (s; a periodic orbit's, from its Floquet
    multipliers: :attr:`~dea_ros.solvers.periodic_solution.PeriodicSolution.slowest_time_constant_s`), used
    where it is the larger. NoEquilibriumError where eq. 20 has no solution at ``voltage_V``."""
    if not (tolerance_m > 0 and cap_s > 0 and min_s >= 0):
        raise ValueError("settle_time: tolerance_m and cap_s must be positive, min_s non-negative")
    p = params if mass_kg is None else params.replace(mass_kg=float(mass_kg))
    tau = max(slowest_time_constant_s(p, voltage_V), float(slower_s) if slower_s == slower_s else 0.0)
    d = static_equilibrium(p, np.array([float(voltage_V), *map(float, from_voltages_V)])).displacement_m
    amplitude = float(np.max(np.abs(d[1:] - d[0]))) if d.size > 1 else 0.0
    if not math.isfinite(tau):
        uncapped = math.inf
    else:
        uncapped = max(float(min_s), tau * math.log(amplitude / tolerance_m) if amplitude > tolerance_m else 0.0)
    return SettleTime(float(voltage_V), p.mass_kg, tau, amplitude, float(tolerance_m), uncapped,
                      min(uncapped, float(cap_s)), float(cap_s))
