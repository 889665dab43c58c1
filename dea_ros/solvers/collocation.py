"""The collocation system of the harmonic balance (eqs. 13-16): spectral matrices, residual, Jacobian, scaling.

The periodic steady state x(theta), theta = omega t, is represented by its values at M = 2N + 1
equally spaced phases (N harmonics, eq. 13). Its derivative is the spectral (Fourier)
differentiation of those values (eq. 14), so the collocation residual (eqs. 15-16) is::

    R(X) = omega X D^T - f(X, u(theta_k)),   X of shape (3, M)

with D the M x M Fourier differentiation matrix, and its exact Jacobian is
``omega kron(I3, D) - blockdiag(df/dx)``. Both are evaluated in scaled variables
(:class:`CollocationSystem`: z = X / scale, residual / (scale rate_ref), all O(1)) by the compiled
kernels of :mod:`.collocation_kernels`. :class:`ModelSetup` holds what depends on the parameter set
only (model, scales, natural frequency, memoised equilibria and systems); :func:`linear_guess` the
response of the model linearised about the static equilibrium, which starts a cold Newton solve.

Harmonics and symmetry (:func:`response_layout`): N counts harmonics of the *response* frequency and
fixes the collocation size. The model sees the voltage only through u^2 (eq. 6); for a sine without
offset u^2 has period T/2, the periodic response contains only even harmonics of the excitation
frequency f, and with ``use_symmetry`` the solver works on the half period: N harmonics of 2f on the
same 2N + 1 points.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from .collocation_kernels import collocation_residual_jacobian, linearised_response
from .inputs import PeriodicInput
from .newton_kernels import newton, newton_error

__all__ = [
    "fourier_differentiation_matrix", "periodic_interpolation_matrix", "resample_state", "CollocationSystem",
    "ModelSetup", "model_setup", "response_layout", "linear_guess",
]


def fourier_differentiation_matrix(m: int) -> np.ndarray:
    """d/dtheta on m (odd) equispaced points of [0, 2 pi): exact for trigonometric polynomials of degree (m-1)/2."""
    if m % 2 == 0 or m < 3:
        raise ValueError(f"m must be odd and >= 3, got {m}")
    k = np.arange(m)
    diff = k[:, None] - k[None, :]
    with np.errstate(divide="ignore"):
        dmat = 0.5 * (-1.0) ** diff / np.sin(np.pi * diff / m)
    dmat[k, k] = 0.0
    return dmat


def periodic_interpolation_matrix(m: int, phases) -> np.ndarray:
    """Matrix P with P @ x_samples = trigonometric interpolant at ``phases`` (m odd, periodic sinc)."""
    theta_k = 2.0 * np.pi * np.arange(m) / m
    delta = np.asarray(phases, dtype=float)[:, None] - theta_k[None, :]
    # reduce to [-pi, pi): near 2 pi the kernel sin(m delta / 2) / (m sin(delta / 2)) would divide
    # two rounding errors (a phase 1e-13 short of a whole period gave O(1) errors)
    delta = np.mod(delta + np.pi, 2.0 * np.pi) - np.pi
    s = np.sin(0.5 * delta)
    small = np.abs(s) < 1e-14
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.sin(0.5 * m * delta) / (m * s)
    p[small] = np.cos(0.5 * m * delta[small]) / np.cos(0.5 * delta[small])
    return p


def resample_state(x: np.ndarray, m: int) -> np.ndarray:
    """Trigonometric resampling of (3, M_old) collocation values to m points."""
    x = np.asarray(x, float)
    phases = 2.0 * np.pi * np.arange(m) / m
    return x @ periodic_interpolation_matrix(x.shape[1], phases).T


class CollocationSystem:
    """The collocation equations for M points, in scaled variables.

    Unknown: z = X / scale[:, None] flattened (state-major). Residual scaled by
    scale * rate_ref so that all equations are O(1).
    """

    def __init__(self, model: DEAModel, n_points: int, scale: np.ndarray, rate_ref: float):
        self.model = model
        self.m = n_points
        self.d_theta = fourier_differentiation_matrix(n_points)
        self.scale = np.asarray(scale, dtype=float)
        self.rate_ref = float(rate_ref)
        self.constants = model.constants
        self.phases = 2.0 * np.pi * np.arange(n_points) / n_points    # of the collocation points, rad

    def unscale(self, z: np.ndarray) -> np.ndarray:
        """Physical collocation values (3, M) of the scaled unknowns z."""
        return z.reshape(3, self.m) * self.scale[:, None]

    def to_z(self, x: np.ndarray) -> np.ndarray:
        """Scaled unknowns of physical collocation values x (3, M)."""
        return (np.asarray(x, float) / self.scale[:, None]).reshape(-1)

    def residual_and_jacobian(self, z, omega, u2, want_jacobian: bool = True):
        """Scaled residual (3M,) and, optionally, its Jacobian (3M, 3M) (compiled:
        :func:`.collocation_kernels.collocation_residual_jacobian`)."""
        r, jac, _drate = collocation_residual_jacobian(np.asarray(z, dtype=float), float(omega),
                                                       np.asarray(u2, dtype=float), self.constants, self.scale,
                                                       self.rate_ref, self.d_theta)
        return r, (jac if want_jacobian else None)

    def residual(self, z, omega, u2) -> np.ndarray:
        """Scaled residual (3M,)."""
        return self.residual_and_jacobian(z, omega, u2, want_jacobian=False)[0]

    def jacobian(self, z, omega, u2) -> np.ndarray:
        """Scaled Jacobian (3M, 3M)."""
        return self.residual_and_jacobian(z, omega, u2)[1]

    def d_residual_d_log_omega(self, z, omega) -> np.ndarray:
        """dR/d(ln omega) = omega X D^T (scaled; it does not depend on u^2)."""
        return collocation_residual_jacobian(np.asarray(z, dtype=float), float(omega), np.zeros(self.m), self.constants,
                                             self.scale, self.rate_ref, self.d_theta)[2]

    def newton(self, z0, omega, u2, tol=1e-10, max_iter=40):
        """Damped Newton (:func:`.newton_kernels.newton`). Returns (z, iterations, scaled residual); raises
        :class:`~dea_ros.errors.HarmonicBalanceError` on failure.

        Converged when the full Newton step is below ``tol`` (scaled units, so relative to the typical
        size of each state).
        """
        z, it, rnorm, status = newton(
            np.array(z0, dtype=float).reshape(-1), float(omega), np.asarray(u2, dtype=float), self.constants,
            self.scale, self.rate_ref, self.d_theta, float(tol), int(max_iter))
        if status == 0:
            return z, it, rnorm
        raise newton_error(status, it, rnorm, max_iter)


@dataclass
class ModelSetup:
    """Per-parameter-set constants: model, state scales, natural frequency, rest displacement.

    Obtain it with :func:`model_setup` (memoised); ``system(m)`` caches the collocation
    system of m points.
    """

    params: MembraneParameters
    model: DEAModel
    scale: np.ndarray
    omega_n: float
    d_rest_m: float
    systems: dict = field(default_factory=dict)
    equilibria: dict = field(default_factory=dict)

    def system(self, m: int) -> CollocationSystem:
        sys_m = self.systems.get(m)
        if sys_m is None:
            sys_m = self.systems[m] = CollocationSystem(self.model, m, self.scale, self.omega_n)
        return sys_m

    def equilibrium_state(self, u2: float) -> np.ndarray:
        """Static state at constant u^2 by scalar Newton from the rest position (fallback: full search).

        Memoised per u^2 (a sweep at one amplitude needs one equilibrium); returns a copy.
        """
        key = float(u2)
        x = self.equilibria.get(key)
        if x is None:
            x = self._equilibrium_state(key)
            if len(self.equilibria) < 256:
                self.equilibria[key] = x
        return x.copy()

    def _equilibrium_state(self, u2: float) -> np.ndarray:
        model = self.model
        weight = self.params.mass_kg * self.params.gravity_m_per_s2
        d = self.d_rest_m
        for _ in range(30):
            step = (model.static_force_N(d, u2) - weight) / model.static_stiffness_N_per_m(d, u2)
            d -= step
            if not (d > 0.0) or not math.isfinite(d):
                break
            if abs(step) < 1e-13 * self.params.electrode_width_m:
                if model.static_stiffness_N_per_m(d, u2) > 0.0:
                    lam = math.sqrt(1.0 + d * d / model.l0_sq)
                    return np.array([d, lam - 1.0, 0.0])
                break
        eq = static_equilibrium(self.params, math.sqrt(u2))
        return np.asarray(eq.state, float).reshape(3)


@functools.lru_cache(maxsize=32)
def model_setup(params: MembraneParameters) -> ModelSetup:
    """Model constants and scales for a parameter set (memoised: parameters are immutable)."""
    model = DEAModel.from_parameters(params)
    eq = static_equilibrium(params, 0.0)
    d_rest = float(eq.displacement_m)
    d_ref = max(d_rest, 1e-3 * params.electrode_width_m)
    omega_n = math.sqrt(max(float(eq.stiffness_N_per_m), 1e-12) / params.mass_kg)
    eps_ref = max(d_ref**2 / params.electrode_width_m**2, 1e-8)
    scale = np.array([d_ref, eps_ref, d_ref * omega_n])
    return ModelSetup(params, model, scale, omega_n, d_rest)


def response_layout(periodic_input: PeriodicInput, n_harmonics: int, use_symmetry: bool):
    """(period divisor, M points): divisor 2 when u^2 is T/2-periodic and symmetry is used."""
    if int(n_harmonics) != n_harmonics or n_harmonics < 1:
        raise ValueError(f"n_harmonics: must be an integer >= 1, got {n_harmonics}")
    divisor = 2 if (use_symmetry and periodic_input.u2_half_periodic()) else 1
    return divisor, 2 * int(n_harmonics) + 1


def linear_guess(params, periodic_input, divisor, m, setup: ModelSetup) -> np.ndarray:
    """Periodic response (3, M) of the model linearised about the static equilibrium at the mean of u^2
    (compiled: :func:`.collocation_kernels.linearised_response`)."""
    model = setup.model
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = periodic_input.at_phase(phases / divisor) ** 2
    u2_mean = float(np.mean(u2))
    x_eq = setup.equilibrium_state(u2_mean)
    _f, rows = model.rhs_and_jacobian_u2(x_eq[0], x_eq[1], x_eq[2], u2_mean)
    a = np.array(rows, dtype=float)
    omega = periodic_input.omega * divisor
    return linearised_response(x_eq, a, float(model.input_gain_u2(x_eq[0])), u2, u2_mean, float(omega))
