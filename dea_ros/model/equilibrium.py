"""Static equilibria: displacement d for a voltage u and a mass m (eqs. 5, 20).

At rest the viscoelastic damper has relaxed (eps1 = lambda_r - 1, so
sigma_v1 = 0, eq. 11) and d' = 0, leaving the force balance of eq. 20::

    m g = c1bar d / s(d) * (sigma_h(lambda_r(d)) + c2 s(d) u^2)

The right-hand side vanishes at d = 0 (flat membrane), where the geometry is
singular (the membrane carries no vertical load and lambda_r is flat in d):

* m = 0 with positive membrane tension: d = 0 exactly.
* m = 0 with the tension destroyed by the Maxwell pressure: the membrane
  buckles; the positive buckled equilibrium is returned.
* m > 0: the first d > 0 where the force balance holds (the stable branch,
  reached from the flat membrane as the mass is loaded).

When no equilibrium exists up to d = l0 (stretch sqrt(2), far beyond the
model's range) a :class:`NoEquilibriumError` says so; garbage is never returned.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dynamics import DEAModel
from .parameters import MembraneParameters
from ..errors import NoEquilibriumError

__all__ = ["StaticEquilibrium", "NoEquilibriumError", "static_equilibrium", "static_state"]


@dataclass(frozen=True)
class StaticEquilibrium:
    """Result of :func:`static_equilibrium` (arrays shaped like the voltage input)."""

    voltage_V: np.ndarray
    mass_kg: float
    displacement_m: np.ndarray
    stiffness_N_per_m: np.ndarray  # static, with eps1 relaxed; > 0 means stable
    electrode_width_m: float       # l0 of the membrane (for the state's eps1 = lambda_r(d) - 1)

    @property
    def state(self) -> np.ndarray:
        """Model state [d, eps1, d'] of shape (3, ...) at rest (eps1 relaxed)."""
        return static_state(self.electrode_width_m, self.displacement_m)


def static_state(electrode_width_m: float, displacement_m):
    """State [d, lambda_r(d) - 1, 0] of the relaxed membrane at rest (eqs. 2, 11)."""
    d = np.asarray(displacement_m, dtype=float)
    lam = np.sqrt(1.0 + (d / electrode_width_m) ** 2)
    return np.stack([d, lam - 1.0, np.zeros_like(d)])


def _tension_Pa(model: DEAModel, d, u2):
    s = 1.0 + d * d / model.l0_sq
    return model.hyperelastic_stress(s) + model.c2 * s * u2


def static_equilibrium(
    params: MembraneParameters,
    voltage_V=0.0,
    mass_kg: float | None = None,
    grid_points: int = 600,
) -> StaticEquilibrium:
    """Static displacement for one voltage or an array of voltages (V).

    ``mass_kg`` defaults to ``params.mass_kg``. Raises :class:`NoEquilibriumError`
    naming the voltages without an equilibrium.
    """
    u = np.asarray(voltage_V, dtype=float)
    if not np.all(np.isfinite(u)):
        raise ValueError("voltage_V: must be finite (got NaN or inf)")
    m = params.mass_kg if mass_kg is None else float(mass_kg)
    if not np.isfinite(m) or m < 0.0:
        raise ValueError(f"mass_kg: must be finite and >= 0, got {mass_kg}")
    p = params.replace(mass_kg=m)
    model = _relaxed_model(p)
    balance = _ForceBalance(model, m * p.gravity_m_per_s2, p.electrode_width_m)
    u2 = (u * u).reshape(-1)
    lo, hi, solvable, flat = balance.bracket_first_roots(u2, grid_points)
    bad = ~(solvable | flat)
    if bad.any():
        raise _no_equilibrium_error(u.reshape(-1)[bad], m, p.name)
    d = np.zeros_like(u2)
    idx = np.where(solvable & ~flat)[0]
    if idx.size:
        d[idx] = balance.refine(lo, hi, u2[idx])
    stiffness = model.static_stiffness_N_per_m(d, u2)
    out_shape = u.shape
    return StaticEquilibrium(
        voltage_V=u,
        mass_kg=m,
        displacement_m=d.reshape(out_shape) if out_shape else float(d[0]),
        stiffness_N_per_m=stiffness.reshape(out_shape) if out_shape else float(stiffness[0]),
        electrode_width_m=p.electrode_width_m,
    )


def _relaxed_model(p: MembraneParameters) -> DEAModel:
    """The model of ``p`` for the static force balance (eq. 20; the damper relaxed)."""
    return DEAModel(
        params=p, l0_sq=p.electrode_width_m**2, force_gain=0.0, c2=p.c2_Pa_per_V2,
        k1=p.k1_Pa, relax_rate=p.k1_Pa / p.eta1_Pa_s, eta2=p.eta2_Pa_s,
        g=p.gravity_m_per_s2, beta=tuple(p.beta_Pa), gamma=tuple(p.gamma_Pa),
    )


def _no_equilibrium_error(voltages_V: np.ndarray, mass_kg: float, name: str) -> NoEquilibriumError:
    """The error naming the voltages (V) without an equilibrium."""
    bad_u = np.unique(np.abs(voltages_V))
    shown = ", ".join(f"{x:.6g}" for x in bad_u[:5]) + (" ..." if bad_u.size > 5 else "")
    return NoEquilibriumError(
        f"no static equilibrium for voltage(s) {shown} V with mass {mass_kg:g} kg "
        f"(membrane {name}): the load exceeds what the membrane can carry up to d = l0 "
        f"(the Maxwell pressure removes the membrane tension; electromechanical instability). "
        f"Lower the voltage or the mass."
    )


class _ForceBalance:
    """The residual of eq. 20 for a weight (N), or the membrane tension for no mass, and its first root in d."""

    def __init__(self, model: DEAModel, weight_N: float, electrode_width_m: float):
        self.model = model
        self.weight = weight_N
        self.l0 = electrode_width_m

    def residual(self, d, u2):
        """F(d) - m g (N) with a mass; the membrane tension (Pa) without one."""
        if self.weight > 0.0:
            return self.model.static_force_N(d, u2) - self.weight
        return _tension_Pa(self.model, d, u2)

    def bracket_first_roots(self, u2: np.ndarray, grid_points: int):
        """Per u^2: a bracket (lo, hi) of the first root on a log grid from 1e-7 l0 to l0, whether
        there is one, and whether the massless membrane stays flat (d = 0: positive tension)."""
        grid = self.l0 * np.logspace(-7, 0, grid_points)[:, None]
        if self.weight > 0.0:  # first d where the membrane carries the weight
            crossed = self.model.static_force_N(grid, u2[None, :]) - self.weight > 0.0
        else:  # massless: first d where the tension vanishes (buckled membrane)
            crossed = _tension_Pa(self.model, grid, u2[None, :]) <= 0.0
        has_root = crossed.any(axis=0)
        first = np.argmax(crossed, axis=0)
        flat = np.zeros(u2.shape, dtype=bool)
        if self.weight == 0.0:
            flat = _tension_Pa(self.model, 0.0, u2) > 0.0
        k = first[has_root & ~flat]
        lo = np.where(k > 0, grid[np.maximum(k - 1, 0), 0], 0.0)
        hi = grid[k, 0]
        return lo, hi, has_root, flat

    def refine(self, lo: np.ndarray, hi: np.ndarray, u2: np.ndarray) -> np.ndarray:
        """The roots in their brackets: bisection to a tight bracket (the grid's ~2.7 % -> ~7e-6
        relative), then Newton (safeguarded by the bracket; quadratic from there: rounding after 3 steps)."""
        f_lo = self.residual(lo, u2)
        for _ in range(12):
            mid = 0.5 * (lo + hi)
            fm = self.residual(mid, u2)
            left = np.sign(fm) == np.sign(f_lo)
            lo = np.where(left, mid, lo)
            f_lo = np.where(left, fm, f_lo)
            hi = np.where(left, hi, mid)
        dd = 0.5 * (lo + hi)
        for _ in range(5):
            if self.weight > 0.0:
                slope = self.model.static_stiffness_N_per_m(dd, u2)
            else:
                h = 1e-9 * self.l0
                slope = (self.residual(dd + h, u2) - self.residual(dd - h, u2)) / (2 * h)
            step = np.where(slope != 0.0, self.residual(dd, u2) / np.where(slope != 0.0, slope, 1.0), 0.0)
            trial = dd - step
            dd = np.where((trial > lo) & (trial < hi), trial, dd)
        return dd
