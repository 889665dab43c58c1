"""The DEA state equation x' = f(x, u) (paper eqs. 1-12, 17-18) and its Jacobians.

State ``x = [d, eps1, d']``: mass displacement d (m, positive downwards, d = 0
is the flat membrane), strain eps1 of the viscoelastic damper (eq. 11, -) and
velocity d' (m/s). Input u is the voltage (V). The voltage enters only through
u^2 (Maxwell pressure, eq. 6), so the functions also accept ``u2 = u**2``.

Every function here works on Python floats (the real-time stepper) and on numpy
arrays of any shape (vectorised over time points or parameter sets): the state
arrays are ``(3, ...)`` and the Jacobian ``(3, 3, ...)``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .parameters import MembraneParameters

__all__ = ["DEAModel", "state_equation"]


@dataclass(frozen=True)
class DEAModel:
    """Precomputed constants of the model for one parameter set.

    Build it once with :meth:`from_parameters` and call :meth:`rhs`,
    :meth:`jacobian` many times.
    """

    params: MembraneParameters
    l0_sq: float          # l0^2, m^2
    force_gain: float     # c1bar / m, m/kg (eq. 18); 0 for a massless membrane
    c2: float             # Pa/V^2 (eq. 6)
    k1: float             # Pa
    relax_rate: float     # k1/eta1, 1/s
    eta2: float           # Pa s
    g: float              # m/s^2
    beta: tuple
    gamma: tuple

    @classmethod
    def from_parameters(cls, p: MembraneParameters) -> "DEAModel":
        if p.mass_kg <= 0.0:
            raise ValueError(
                "mass_kg must be > 0 for the dynamic model (eq. 5 divides by m); "
                "use static_equilibrium() for the massless membrane"
            )
        return cls(
            params=p,
            l0_sq=p.electrode_width_m**2,
            force_gain=p.c1bar_m / p.mass_kg,
            c2=p.c2_Pa_per_V2,
            k1=p.k1_Pa,
            relax_rate=p.k1_Pa / p.eta1_Pa_s,
            eta2=p.eta2_Pa_s,
            g=p.gravity_m_per_s2,
            beta=tuple(p.beta_Pa),
            gamma=tuple(p.gamma_Pa),
        )

    # ------------------------------------------------------------ kinematics
    def stretch_squared(self, d):
        """s(d) = lambda_r^2 = 1 + d^2/l0^2 (eq. 2 and the text after eq. 4)."""
        return 1.0 + d * d / self.l0_sq

    def hyperelastic_stress(self, s):
        """sigma_h = sum_i beta_i s^i - gamma_i s^-i (eq. 10, lambda_r^(2i) = s^i), Pa."""
        b1, b2, b3 = self.beta
        g1, g2, g3 = self.gamma
        si = 1.0 / s
        return (b1 + (b2 + b3 * s) * s) * s - (g1 + (g2 + g3 * si) * si) * si

    def hyperelastic_stress_ds(self, s):
        """d sigma_h / ds, Pa."""
        b1, b2, b3 = self.beta
        g1, g2, g3 = self.gamma
        si = 1.0 / s
        return b1 + (2.0 * b2 + 3.0 * b3 * s) * s + (g1 + (2.0 * g2 + 3.0 * g3 * si) * si) * si * si

    # ------------------------------------------------------------- dynamics
    def rhs_u2(self, d, eps1, v, u2):
        """f(x, u) of eq. 18 with u2 = u^2; returns the tuple (d', eps1', d'')."""
        s = 1.0 + d * d / self.l0_sq
        lam = s**0.5
        phi = d / (self.l0_sq * lam)                      # eq. 12
        stress = (
            self.c2 * s * u2                               # Maxwell, eq. 6
            + self.hyperelastic_stress(s)                  # eq. 10
            + self.k1 * (lam - 1.0 - eps1)                 # eq. 11
            + self.eta2 * phi * v                          # eq. 12
        )
        acc = self.g - self.force_gain * (d / s) * stress  # eqs. 5, 18
        deps = self.relax_rate * (lam - 1.0 - eps1)        # eq. 11
        return v, deps, acc

    def rhs(self, x, u):
        """f(x, u) (eq. 18) for x of shape (3, ...) and voltage u broadcastable to x[0]."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        f = self.rhs_u2(x[0], x[1], x[2], u * u)
        return np.stack(np.broadcast_arrays(*f))

    @functools.cached_property
    def constants(self) -> tuple:
        """The model constants as the flat tuple :func:`state_equation` takes (SI units, see the fields)."""
        return (self.l0_sq, self.force_gain, self.c2, self.k1, self.relax_rate, self.eta2, self.g) \
            + tuple(self.beta) + tuple(self.gamma)

    def rhs_and_jacobian_u2(self, d, eps1, v, u2):
        """f (tuple of 3) and the analytic df/dx (J[i][j], row i = equation) sharing the work."""
        return state_equation(self.constants, d, eps1, v, u2)

    def jacobian_u2(self, d, eps1, v, u2):
        """Analytic df/dx as nested tuples J[i][j] (row i = equation), same shapes as d."""
        return self.rhs_and_jacobian_u2(d, eps1, v, u2)[1]

    def jacobian(self, x, u):
        """df/dx of shape (3, 3, ...) for x of shape (3, ...)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        rows = self.jacobian_u2(x[0], x[1], x[2], u * u)
        return np.stack([np.stack(np.broadcast_arrays(*r)) for r in rows])

    def input_gain_u2(self, d):
        """df/d(u^2) = (0, 0, -c1bar/m c2 d) (eqs. 6, 18): the voltage acts through u^2."""
        return -self.force_gain * self.c2 * d

    def input_jacobian(self, x, u):
        """df/du of shape (3, ...)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        g3 = self.input_gain_u2(x[0]) * 2.0 * u
        zero = np.zeros_like(g3)
        return np.stack([zero, zero, g3])

    # ---------------------------------------------------------------- statics
    def static_force_N(self, d, u2):
        """Net static membrane force c1bar d/s (sigma_h + sigma_Maxwell), eps1 relaxed (eq. 20), N."""
        s = 1.0 + d * d / self.l0_sq
        return self.params.c1bar_m * (d / s) * (self.hyperelastic_stress(s) + self.c2 * s * u2)

    def static_stiffness_N_per_m(self, d, u2):
        """d(static force)/dd with the viscoelastic strain relaxed, N/m."""
        s = 1.0 + d * d / self.l0_sq
        q = d * d / self.l0_sq
        ds_dd = 2.0 * d / self.l0_sq
        sigma = self.hyperelastic_stress(s) + self.c2 * s * u2
        dsigma = (self.hyperelastic_stress_ds(s) + self.c2 * u2) * ds_dd
        return self.params.c1bar_m * ((1.0 - q) / (s * s) * sigma + (d / s) * dsigma)


def state_equation(constants, d, eps1, v, u2):
    """f(x, u) of eq. 18 and the analytic df/dx, from the flat :attr:`DEAModel.constants`.

    Returns ``(f, J)``: f a tuple of 3, J nested tuples J[i][j] (row i = equation), each of the
    shape of d. Plain arithmetic only, so that the same function runs on floats, on numpy arrays
    and compiled by numba (:mod:`dea_ros.solvers.collocation_kernels`,
    :mod:`dea_ros.solvers.floquet_kernels`).
    """
    l0_sq, kg, c2, k1, a, eta2, g, b1, b2, b3, g1, g2, g3 = constants
    q = d * d / l0_sq
    s = 1.0 + q
    lam = s**0.5
    phi = d / (l0_sq * lam)                              # eq. 12, = d lambda / dd
    strain = lam - 1.0 - eps1
    si = 1.0 / s
    sigma_h = (b1 + (b2 + b3 * s) * s) * s - (g1 + (g2 + g3 * si) * si) * si
    dsigma_h_ds = b1 + (2.0 * b2 + 3.0 * b3 * s) * s + (g1 + (2.0 * g2 + 3.0 * g3 * si) * si) * si * si
    c2u2 = c2 * u2
    stress = c2u2 * s + sigma_h + k1 * strain + eta2 * phi * v
    d_over_s = d * si
    f = (v, a * strain, g - kg * d_over_s * stress)
    dstress_dd = (
        (c2u2 + dsigma_h_ds) * (2.0 * d / l0_sq)
        + k1 * phi
        + eta2 * v / (l0_sq * lam * s)                   # d phi / dd = 1/(l0^2 lambda s)
    )
    zero = 0.0 * d
    jac = (
        (zero, zero, zero + 1.0),
        (a * phi, zero - a, zero),
        (
            -kg * ((1.0 - q) * si * si * stress + d_over_s * dstress_dd),
            kg * d_over_s * k1,
            -kg * d_over_s * eta2 * phi,
        ),
    )
    return f, jac
