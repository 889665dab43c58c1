"""Static fit (paper section IV-B, eqs. 19-20): Ogden beta_i, gamma_i and eps_r from rest displacements.

At rest the viscoelastic strain has relaxed and the force balance of eq. 20 holds::

    m g = c1bar d / s(d) * (sigma_h(s) + c2 s u^2),   s = 1 + d^2 / l0^2,   c2 = -eps0 eps_r / z0^2

Identifiability. The deflections are below ~1.3 mm against l0 = 14-17 mm, so
s - 1 < 1e-2: the data probe sigma_h only through its value and slope at s = 1,

    sigma_0 = sigma_h(1)   = sum_i (beta_i - gamma_i)                (membrane pre-tension)
    sigma_1 = sigma_h'(1)  = sum_i i (beta_i + gamma_i)               (its slope in s)
    sigma_2 = sigma_h''(1) = sum_i i(i-1) beta_i - i(i+1) gamma_i     (curvature: invisible)

and the six Ogden coefficients trade off freely along a 4-dimensional null
space (eqs. 8-9 leave three mu_i and still one free combination). Fitting the
seven (beta, gamma, eps_r) therefore converges anywhere on a valley floor,
which is what the paper's Nelder-Mead does.

Methods
-------
``method="lsq"`` (default): bounded least squares (``scipy.optimize.least_squares``,
trust-region reflective) on the *displacement* residuals in metres,
d_model(m_k, u_k) - d_measured, over the identifiable parameters
(sigma_0, sigma_1, eps_r) -- ``stress_terms=3`` adds sigma_2. The model
displacement solves eq. 20 with the polynomial sigma_h(s) = sigma_0 + sigma_1 (s-1)
+ sigma_2 (s-1)^2 / 2, and the Jacobian is analytic by the implicit-function
theorem (dd/dtheta = -(dF/dtheta) / (dF/dd)). Starts: the linear equation-error
solution (eq. 20 is linear in (sigma_0, sigma_1, sigma_2, eps_r) at the measured d)
and two more with eps_r halved and doubled; the best is kept.
The fitted combinations are then written as Ogden coefficients by
:func:`ogden_from_combinations`: the closest (beta, gamma) to the base file's
values (or, without a base file, the mu_i of eqs. 8-9) reproducing
sigma_0, sigma_1 and sigma_2 exactly. Every other beta/gamma with the same
combinations fits the data equally well; the report says so.

``method="paper"``: Nelder-Mead on eq. 19 over (beta_1..3, gamma_1..3, eps_r),
force residuals of eq. 20 at the measured displacements, weights
w_m = 0.1 / N_k (zero-voltage points) and w_u = 1 / N_j (voltage points).
Variables are normalised (beta, gamma by 1e5 Pa) and the cost by (m g)^2 of
the heaviest mass, so the tolerances are meaningful.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import stats as scipy_stats
from scipy.optimize import least_squares, minimize

from ..model.dynamics import DEAModel
from ..model.equilibrium import NoEquilibriumError, static_equilibrium
from ..model.parameters import MembraneParameters
from .experiments import StaticData
from .metrics import ParameterStatistics, parameter_statistics, static_errors_um
from ..errors import StaticFitError

__all__ = [
    "StaticFitResult",
    "StaticFitError",
    "fit_static",
    "CurvatureTest",
    "static_curvature_test",
    "stress_combinations",
    "ogden_from_combinations",
    "OgdenRepresentation",
    "generic_start",
    "ogden_warning",
    "COMBINATION_MATRIX",
    "STATIC_METHODS",
    "static_displacement_jacobian",
    "THIRD_DERIVATIVE_ROW",
    "EXTENDED_COMBINATION_MATRIX",
    "HIGHER_DERIVATIVE_ROWS",
    "SHAPE_COMBINATION_MATRIX",
    "STRESS_NAMES",
]

STATIC_METHODS = ("lsq", "paper")
LOG = logging.getLogger("dea_ros.identify")

#: Rows: sigma_h(1), sigma_h'(1), sigma_h''(1) as linear forms of (beta_1..3, gamma_1..3) (eq. 10).
COMBINATION_MATRIX = np.array([
    [1.0, 1.0, 1.0, -1.0, -1.0, -1.0],
    [1.0, 2.0, 3.0, 1.0, 2.0, 3.0],
    [0.0, 2.0, 6.0, -2.0, -6.0, -12.0],
])
#: d^3 sigma_h / ds^3 at s = 1 as a linear form of (beta_1..3, gamma_1..3) (eq. 10): the next term
#: after sigma_h''(1), seen by the largest oscillations only (the joint refinement's nuisance parameter).
THIRD_DERIVATIVE_ROW = np.array([0.0, 0.0, 6.0, 6.0, 24.0, 60.0])
#: COMBINATION_MATRIX with the third derivative appended (4 x 6).
EXTENDED_COMBINATION_MATRIX = np.vstack([COMBINATION_MATRIX, THIRD_DERIVATIVE_ROW])
#: The fourth and fifth derivatives at s = 1 (eq. 10; the beta_i s^i terms have none beyond the third):
#: with EXTENDED_COMBINATION_MATRIX the whole Ogden shape (6 x 6, invertible) -- the two directions the
#: four-combination representation holds at the base parameters' (the joint refinement's "shape" mode).
HIGHER_DERIVATIVE_ROWS = np.array([
    [0.0, 0.0, 0.0, -24.0, -120.0, -360.0],
    [0.0, 0.0, 0.0, 120.0, 720.0, 2520.0],
])
SHAPE_COMBINATION_MATRIX = np.vstack([EXTENDED_COMBINATION_MATRIX, HIGHER_DERIVATIVE_ROWS])
#: The names of SHAPE_COMBINATION_MATRIX's rows (Pa; derivatives in s).
STRESS_NAMES = ("sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa", "sigma_h'''(1)_Pa", "sigma_h''''(1)_Pa",
                "sigma_h'''''(1)_Pa")
_SIGMA_REF_PA = 1e5  # scale of the stress parameters in the optimizers


def stress_combinations(beta_Pa, gamma_Pa) -> np.ndarray:
    """(sigma_h(1), sigma_h'(1), sigma_h''(1)) in Pa of Ogden coefficients (eq. 10, derivatives in s)."""
    return COMBINATION_MATRIX @ np.concatenate([np.asarray(beta_Pa, float), np.asarray(gamma_Pa, float)])


def _mu_basis(prestretch: float) -> np.ndarray:
    """(6, 3) matrix mapping mu_i to (beta, gamma) by eqs. 8-9."""
    lam = float(prestretch)
    b = np.zeros((6, 3))
    for i in range(3):
        b[i, i] = lam ** (2 * (i + 1))
        b[3 + i, i] = lam ** (-4 * (i + 1))
    return b


class OgdenRepresentation:
    """Affine map from the fitted stress combinations to Ogden (beta, gamma).

    ``n_constraints`` combinations (sigma_h(1), sigma_h'(1)[, sigma_h''(1)]) are
    matched exactly. With a prior (beta, gamma): the closest point to the prior
    (Euclidean, Pa). Without: the minimum-norm mu_i of eqs. 8-9. The
    combinations that are not fitted (e.g. sigma_h''(1)) follow from the
    representation, so the fitted polynomial and the written Ogden law agree
    to O((s-1)^3) over the data.
    """

    def __init__(self, prestretch: float, n_constraints: int, prior_beta_gamma=None, matrix=None):
        full = COMBINATION_MATRIX if matrix is None else np.asarray(matrix, float)
        if n_constraints > 3 and prior_beta_gamma is None:
            raise ValueError("more than 3 constraints need prior (beta, gamma): the mu_i of eqs. 8-9 have 3 dims")
        a = full[:n_constraints]
        if prior_beta_gamma is not None:
            p0 = np.asarray(prior_beta_gamma, float).reshape(6)
            gain = a.T @ np.linalg.inv(a @ a.T)                  # (6, n)
            self._offset = p0 - gain @ (a @ p0)
            self._gain = gain
            self.kind = "closest to the base parameters' beta/gamma"
        else:
            b = _mu_basis(prestretch)
            self._gain = b @ np.linalg.pinv(a @ b)              # minimum-norm mu
            self._offset = np.zeros(6)
            self.kind = "minimum-norm mu_i of eqs. 8-9"
        self.n_constraints = n_constraints

    def beta_gamma(self, sigma_fitted) -> np.ndarray:
        """(6,) beta then gamma for the fitted combinations."""
        return self._offset + self._gain @ np.asarray(sigma_fitted, float)[: self.n_constraints]

    def combinations(self, sigma_fitted) -> np.ndarray:
        """All three combinations (sigma_h(1), sigma_h'(1), sigma_h''(1)) of the representation."""
        return COMBINATION_MATRIX @ self.beta_gamma(sigma_fitted)

    @property
    def gain(self) -> np.ndarray:
        """d(beta, gamma)/d(fitted combinations), (6, n): the (beta, gamma) direction of each one."""
        return self._gain.copy()

    def combination_gain(self) -> np.ndarray:
        """d(all three combinations)/d(fitted combinations), (3, n)."""
        return COMBINATION_MATRIX @ self._gain


def ogden_from_combinations(sigma_Pa, prestretch: float, prior_beta_gamma=None):
    """Ogden (beta, gamma) reproducing the given combinations exactly (see :class:`OgdenRepresentation`).

    ``sigma_Pa``: sigma_h(1), sigma_h'(1) and optionally sigma_h''(1).
    """
    sigma = np.asarray(sigma_Pa, float).reshape(-1)
    rep = OgdenRepresentation(prestretch, sigma.size, prior_beta_gamma)
    x = rep.beta_gamma(sigma)
    return tuple(float(v) for v in x[:3]), tuple(float(v) for v in x[3:])


@dataclass
class StaticFitResult:
    """Outcome of :func:`fit_static` (SI units; errors also in micrometres)."""

    parameters: MembraneParameters
    method: str
    statistics: ParameterStatistics          # of the parameters the optimizer moved
    ogden_statistics: ParameterStatistics    # of (beta_1..3, gamma_1..3, eps_r) at the optimum
    mass_kg: np.ndarray
    voltage_V: np.ndarray
    measured_m: np.ndarray
    predicted_m: np.ndarray                  # static_equilibrium of the final parameters
    combinations_Pa: np.ndarray              # sigma_h(1), sigma_h'(1), sigma_h''(1)
    cost: float
    n_evaluations: int
    wall_time_s: float
    starts: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    representation: str = "as fitted (Nelder-Mead on beta, gamma, eps_r)"
    prior_beta_gamma: np.ndarray | None = None

    def curvature_direction(self) -> np.ndarray:
        """d(beta, gamma)/d sigma_h''(1) keeping sigma_h(1) and sigma_h'(1) (same representation
        as the fit: closest to the prior, or the mu_i of eqs. 8-9): the direction along which
        the dynamic fit may move the curvature the static data cannot see."""
        rep = OgdenRepresentation(self.parameters.prestretch, 3, self.prior_beta_gamma)
        return rep.gain[:, 2].copy()

    @property
    def errors_um(self) -> dict:
        return static_errors_um(self.measured_m, self.predicted_m)

    @property
    def residuals_m(self) -> np.ndarray:
        return self.predicted_m - self.measured_m


# --------------------------------------------------------------------------- static model
class _StaticProblem:
    """Eq. 20 at the data points with a polynomial or Ogden sigma_h; vectorised over points."""

    def __init__(self, template: MembraneParameters, data: StaticData):
        self.template = template
        self.l0 = template.electrode_width_m
        self.l0_sq = self.l0**2
        self.c1bar = template.c1bar_m
        self.kappa = template.vacuum_permittivity_F_per_m / template.thickness_m**2  # c2 = -kappa eps_r
        self.g = template.gravity_m_per_s2
        self.mass = data.mass_kg
        self.u2 = data.voltage_V**2
        self.d_meas = data.displacement_m
        self.weight = self.mass * self.g

    # sigma_h as a polynomial in (s - 1): coefficients (sigma_0, sigma_1, sigma_2)
    @staticmethod
    def poly_stress(s, sig):
        x = s - 1.0
        return sig[0] + x * (sig[1] + 0.5 * x * sig[2])

    @staticmethod
    def poly_stress_ds(s, sig):
        return sig[1] + (s - 1.0) * sig[2]

    def force(self, d, sig, eps_r):
        s = 1.0 + d * d / self.l0_sq
        return self.c1bar * d / s * (self.poly_stress(s, sig) - self.kappa * eps_r * s * self.u2)

    def stiffness(self, d, sig, eps_r):
        s = 1.0 + d * d / self.l0_sq
        q = d * d / self.l0_sq
        tension = self.poly_stress(s, sig) - self.kappa * eps_r * s * self.u2
        dtension = (self.poly_stress_ds(s, sig) - self.kappa * eps_r * self.u2) * 2.0 * d / self.l0_sq
        return self.c1bar * ((1.0 - q) / (s * s) * tension + d / s * dtension)

    def equilibrium(self, sig, eps_r):
        """First d > 0 with force = m g per point (d = 0 for m = 0 under positive tension).

        Returns (d, ok): ok False where no equilibrium exists up to d = l0.
        """
        n = self.mass.size
        grid = self.l0 * np.logspace(-7, 0, 400)[:, None]
        resid = self.force(grid, sig, eps_r) - self.weight[None, :]
        crossed = resid > 0.0
        ok = crossed.any(axis=0)
        zero_mass = self.weight <= 0.0
        tension0 = sig[0] - self.kappa * eps_r * self.u2
        flat = zero_mass & (tension0 > 0.0)
        ok = ok | flat
        k = np.argmax(crossed, axis=0)
        lo = np.where(k > 0, grid[np.maximum(k - 1, 0), 0], 0.0)
        hi = grid[k, 0]
        for _ in range(30):  # bisection to a tight bracket
            mid = 0.5 * (lo + hi)
            fm = self.force(mid, sig, eps_r) - self.weight
            lo = np.where(fm > 0.0, lo, mid)
            hi = np.where(fm > 0.0, mid, hi)
        d = 0.5 * (lo + hi)
        for _ in range(4):  # Newton polish, kept inside the bracket
            f = self.force(d, sig, eps_r) - self.weight
            kk = self.stiffness(d, sig, eps_r)
            trial = d - f / np.where(kk != 0.0, kk, 1.0)
            d = np.where((trial > lo) & (trial < hi), trial, d)
        d = np.where(flat | ~ok, 0.0, d)
        return d.reshape(n), ok

    def displacement_jacobian(self, d, sig, eps_r, n_sigma):
        """dd/d(sigma_0..sigma_{n-1}, eps_r) by implicit differentiation of eq. 20 (zero where d = 0)."""
        s = 1.0 + d * d / self.l0_sq
        x = s - 1.0
        base = self.c1bar * d / s
        cols = [base, base * x, base * 0.5 * x * x][:n_sigma]
        cols.append(-self.c1bar * d * self.kappa * self.u2)  # dF/d eps_r
        dfdd = self.stiffness(d, sig, eps_r)
        dfdd = np.where(d > 0.0, dfdd, np.inf)
        return -np.column_stack(cols) / dfdd[:, None]

    def ogden_jacobian(self, params: MembraneParameters, d) -> np.ndarray:
        """dd/d(beta_1..3, gamma_1..3, eps_r) at the equilibrium d of ``params`` (Pa^-1 m, m)."""
        s = 1.0 + d * d / self.l0_sq
        base = self.c1bar * d / s
        cols = [base * s ** (i + 1) for i in range(3)] + [-base * s ** (-(i + 1)) for i in range(3)]
        cols.append(-self.c1bar * d * self.kappa * self.u2)
        model = DEAModel.from_parameters(params.replace(mass_kg=max(params.mass_kg, 1e-6)))
        dfdd = model.static_stiffness_N_per_m(d, self.u2)
        dfdd = np.where(d > 0.0, dfdd, np.inf)
        return -np.column_stack(cols) / dfdd[:, None]


def static_displacement_jacobian(params: MembraneParameters, data: StaticData, displacement_m) -> np.ndarray:
    """d(rest displacement)/d(beta_1..3, gamma_1..3, eps_r) at the static points ``data`` whose
    equilibria under ``params`` are ``displacement_m`` (eq. 20, implicit differentiation), (n, 7)."""
    return _StaticProblem(params, data).ogden_jacobian(params, np.asarray(displacement_m, float))


def _check_static_data(data: StaticData, n_params: int) -> None:
    loaded = data.mass_kg > 0
    n_loaded = int(np.count_nonzero(loaded))
    if n_loaded < n_params:
        raise StaticFitError(
            f"{data.source}: {n_loaded} static point(s) with a mass; the static fit of {n_params} "
            f"parameters needs at least {n_params}, better {n_params + 2} or more (e.g. 0-5 g at 0 V "
            "and 2.0-2.5 kV at 3 g)"
        )
    volt = loaded & (np.abs(data.voltage_V) > 0)
    if not np.any(volt):
        raise StaticFitError(
            f"{data.source}: no static point with a voltage; eps_r (eq. 6) needs points at "
            "several voltages with a mass (the paper uses 2.0-2.5 kV at 3 g)"
        )
    states = {(round(float(m), 12), round(float(u) ** 2, 3))
              for m, u in zip(data.mass_kg[loaded], data.voltage_V[loaded])}
    if len(states) < n_params:
        raise StaticFitError(
            f"{data.source}: only {len(states)} distinct (mass, voltage) state(s) with a mass; "
            f"{n_params} parameters need at least {n_params} different states"
        )


def ogden_warning(stats: ParameterStatistics, fitted: tuple = ("sigma_h(1)", "sigma_h'(1)", "eps_r")) -> str:
    """One-line summary of the (beta, gamma, eps_r) identifiability analysis (the known trade-off).

    Pairwise correlations understate a multi-dimensional degeneracy, so the summary gives the
    singular values of the column-normalised Jacobian: the number above 1e-3 of the largest is
    the number of combinations the data determine; ``fitted``: what the fit determines instead.
    """
    sv = stats.singular_values / stats.singular_values[0]
    determined = int(np.count_nonzero(sv > 1e-3))
    unbounded = [n for n, r in zip(stats.names, stats.relative_ci) if not math.isfinite(r) or r > 1.0]
    return (
        f"static fit: beta_i and gamma_i are not individually identifiable (the deflections probe sigma_h "
        f"only near stretch 1): of the {len(stats.names)} parameters (beta_1..3, gamma_1..3, eps_r) the data "
        f"determine {determined} combination(s) (normalised singular values "
        + ", ".join(f"{x:.2g}" for x in sv) + "); "
        + (f"{', '.join(unbounded)} have unbounded 95 % CIs; " if unbounded else "")
        + f"only {', '.join(fitted[:-1])} and {fitted[-1]} are determined, the written beta/gamma are one "
        "representative"
    )


def _finish(template, beta, gamma, eps_r, data, problem, method, stats, cost, nfev, t0,
            starts, warnings, combos) -> StaticFitResult:
    params = template.replace(beta_Pa=beta, gamma_Pa=gamma, relative_permittivity=float(eps_r))
    predicted = np.zeros(data.n_points)
    for m in np.unique(data.mass_kg):
        sel = data.mass_kg == m
        try:
            predicted[sel] = static_equilibrium(params, data.voltage_V[sel], mass_kg=float(m)).displacement_m
        except NoEquilibriumError as exc:
            raise StaticFitError(f"{method} static fit ended without an equilibrium: {exc}") from None
    ogden_jac = problem.ogden_jacobian(params, predicted)
    ogden_stats = parameter_statistics(
        ogden_jac, predicted - data.displacement_m,
        ("beta_1", "beta_2", "beta_3", "gamma_1", "gamma_2", "gamma_3", "eps_r"),
        np.r_[beta, gamma, eps_r], context="Ogden coefficients (beta, gamma) and eps_r",
    )
    fitted = tuple(n.removesuffix("_Pa") for n in stats.names) if stats is not None else ()
    warnings = list(warnings) + [ogden_warning(ogden_stats, *([fitted] if fitted else []))]
    return StaticFitResult(
        parameters=params, method=method, statistics=stats, ogden_statistics=ogden_stats,
        mass_kg=data.mass_kg, voltage_V=data.voltage_V, measured_m=data.displacement_m,
        predicted_m=predicted, combinations_Pa=np.asarray(combos, float), cost=float(cost),
        n_evaluations=int(nfev), wall_time_s=time.perf_counter() - t0, starts=starts,
        warnings=warnings,
    )


# --------------------------------------------------------------------------- least squares
class _CombinationFit:
    """Eq. 20's displacement residuals over the fitted stress combinations and eps_r (optimizer units:
    the combinations in _SIGMA_REF_PA), their Jacobian, bounds and the linear starts."""

    def __init__(self, problem: _StaticProblem, template: MembraneParameters, n_sigma: int, prior_bg,
                 curvature_Pa: float | None):
        self.problem, self.n_sigma = problem, n_sigma
        if curvature_Pa is None:
            # sigma_h''(1) follows the representation of the fitted combinations
            self.rep = OgdenRepresentation(template.prestretch, n_sigma, prior_bg)
            self.gain = self.rep.combination_gain()      # (3, n_sigma): all combinations vs fitted ones
            self.offset = self.rep.combinations(np.zeros(n_sigma))
            self.fixed_tail = np.zeros(0)
        else:
            # sigma_h''(1) given (e.g. identified by the dynamic fit): match all three exactly
            if n_sigma != 2:
                raise ValueError("curvature_Pa: only with stress_terms=2")
            self.rep = OgdenRepresentation(template.prestretch, 3, prior_bg)
            self.gain = np.eye(3)[:, :2]
            self.offset = np.array([0.0, 0.0, float(curvature_Pa)])
            self.fixed_tail = np.array([float(curvature_Pa)])
        self.lower = np.r_[1e-2, np.full(n_sigma - 1, -np.inf), 1.0]
        self.upper = np.r_[np.full(n_sigma, np.inf), 50.0]
        self.nfev = 0
        # the linear equation-error system of eq. 20 at the measured displacements
        # (m g s / (c1bar d) = sigma_h(s) - kappa eps_r s u^2 is linear in the parameters)
        use = (problem.mass > 0) & (problem.d_meas > 0.05 * np.max(problem.d_meas))
        d = problem.d_meas[use]
        s = 1.0 + d * d / problem.l0_sq
        y = problem.weight[use] * s / (problem.c1bar * d)
        x1 = s - 1.0
        basis = np.column_stack([np.ones_like(d), x1, 0.5 * x1 * x1])
        self._a_sigma = basis @ self.gain                          # (n, n_sigma)
        self._rhs = y - basis @ self.offset
        self._maxwell = -problem.kappa * s * problem.u2[use]

    def unpack(self, x):
        """(sigma_0, sigma_1, sigma_2) in Pa and eps_r of the optimizer vector ``x``."""
        fitted = x[:self.n_sigma] * _SIGMA_REF_PA
        return self.offset + self.gain @ fitted, x[self.n_sigma]

    def residuals(self, x):
        sig, eps_r = self.unpack(x)
        d, ok = self.problem.equilibrium(sig, eps_r)
        self.nfev += 1
        # No equilibrium (the membrane collapses): a residual of l0 per point.
        return np.where(ok, d - self.problem.d_meas, self.problem.l0)

    def jacobian(self, x):
        sig, eps_r = self.unpack(x)
        d, _ok = self.problem.equilibrium(sig, eps_r)
        jac3 = self.problem.displacement_jacobian(d, sig, eps_r, 3)      # vs sigma_0..2, eps_r
        return np.column_stack([jac3[:, :3] @ self.gain * _SIGMA_REF_PA, jac3[:, 3]])

    def linear_start(self, eps_r=None):
        """The linear equation-error solution (eps_r fitted, or given), as an optimizer vector."""
        if eps_r is None:
            a = np.column_stack([self._a_sigma, self._maxwell])
            cs = np.linalg.norm(a, axis=0)
            c, *_ = np.linalg.lstsq(a / cs, self._rhs, rcond=None)
            c /= cs
        else:
            cs = np.linalg.norm(self._a_sigma, axis=0)
            c, *_ = np.linalg.lstsq(self._a_sigma / cs, self._rhs - self._maxwell * eps_r, rcond=None)
            c = np.r_[c / cs, eps_r]
        c[-1] = float(np.clip(c[-1], 1.05, 45.0))
        c[0] = max(c[0], 1e3)
        return np.r_[c[:self.n_sigma] / _SIGMA_REF_PA, c[-1]]

    def beta_gamma(self, x) -> tuple:
        """(beta, gamma) of the representation for the optimizer vector ``x``."""
        bg = self.rep.beta_gamma(np.r_[x[:self.n_sigma] * _SIGMA_REF_PA, self.fixed_tail])
        return tuple(float(v) for v in bg[:3]), tuple(float(v) for v in bg[3:])


def _best_of_starts(fit: _CombinationFit, progress) -> tuple:
    """(solution, cost, starts): least squares from the linear start and with eps_r halved and doubled."""
    x_lin = fit.linear_start()
    eps_lin = float(x_lin[-1])
    best = None
    starts = []
    for label, x0 in (("linear", x_lin),
                      ("eps_r/2", fit.linear_start(max(eps_lin / 2, 1.05))),
                      ("eps_r*2", fit.linear_start(min(eps_lin * 2, 45.0)))):
        x0 = np.clip(x0, fit.lower + 1e-9, fit.upper - 1e-9)
        sol = least_squares(fit.residuals, x0, jac=fit.jacobian, bounds=(fit.lower, fit.upper), method="trf",
                            x_scale="jac", ftol=1e-14, xtol=1e-14, gtol=1e-14, max_nfev=200)
        cost = float(sol.fun @ sol.fun)
        starts.append({"start": label, "eps_r_start": float(x0[-1]), "eps_r": float(sol.x[-1]),
                       "sum_sq_m2": cost, "nfev": int(sol.nfev)})
        LOG.debug("static fit (lsq) start %s: sum of squares %.6g m^2, eps_r %.5g", label, cost, sol.x[-1])
        if progress:
            progress({"stage": "static", "method": "lsq", "start": label, "cost": cost,
                      "rms_um": math.sqrt(cost / sol.fun.size) * 1e6, "evaluations": fit.nfev})
        if best is None or cost < best[1]:
            best = (sol, cost)
    return best[0], best[1], starts


def _fit_lsq(template, data, problem, stress_terms, prior, progress, t0, curvature_Pa=None):
    n_sigma = stress_terms
    _check_static_data(data, n_sigma + 1)
    prior_bg = None if prior is None else np.r_[prior[0], prior[1]]
    fit = _CombinationFit(problem, template, n_sigma, prior_bg, curvature_Pa)
    sol, cost, starts = _best_of_starts(fit, progress)
    sig, eps_r = fit.unpack(sol.x)
    names = ("sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa")[:n_sigma] + ("eps_r",)
    values = np.r_[sol.x[:n_sigma] * _SIGMA_REF_PA, eps_r]
    jac = fit.jacobian(sol.x)
    jac[:, :n_sigma] /= _SIGMA_REF_PA
    stats = parameter_statistics(jac, sol.fun, names, values, context="static fit")
    warnings = list(stats.warnings)
    spread = [st["eps_r"] for st in starts]
    if max(spread) - min(spread) > 0.01 * eps_r and max(st["sum_sq_m2"] for st in starts) < 1.01 * cost:
        warnings.append(f"static fit: starts ended at different eps_r ({', '.join(f'{e:.3g}' for e in spread)}) "
                        "with equal cost: eps_r is not determined by these data")
    beta, gamma = fit.beta_gamma(sol.x)
    result = _finish(template, beta, gamma, eps_r, data, problem, "lsq", stats, cost, fit.nfev, t0,
                     starts, warnings, sig)
    result.representation = fit.rep.kind
    result.prior_beta_gamma = prior_bg
    return result


# --------------------------------------------------------------------------- paper
def _fit_paper(template, data, problem, start, progress, t0, options):
    _check_static_data(data, 3)
    d = problem.d_meas
    s = 1.0 + d * d / problem.l0_sq
    zero_v = problem.u2 == 0.0
    n_k = max(int(np.count_nonzero(zero_v)), 1)
    n_j = max(int(np.count_nonzero(~zero_v)), 1)
    w_m, w_u = 0.1 / n_k, 1.0 / n_j      # section IV-B: w_m = 0.1/N_k, w_u = 1/N_j
    norm = (np.max(problem.weight) if np.max(problem.weight) > 0 else 1.0) ** 2
    powers = np.arange(1, 4)
    s_pow = s[:, None] ** powers[None, :]
    s_neg = s[:, None] ** (-powers[None, :])
    geom = problem.c1bar * d / s
    maxwell = problem.c1bar * problem.kappa * d * problem.u2  # = -c1bar c2 d u^2 / eps_r
    nfev = [0]

    def cost_fn(x):
        beta = x[:3] * _SIGMA_REF_PA
        gamma = x[3:6] * _SIGMA_REF_PA
        eps_r = x[6]
        sigma_e = s_pow @ beta - s_neg @ gamma                        # eq. 10
        resid = problem.weight + maxwell * eps_r - geom * sigma_e      # eq. 20 (c2 = -kappa eps_r)
        j_m = np.sum(resid[zero_v] ** 2)
        j_u = np.sum(resid[~zero_v] ** 2)
        nfev[0] += 1
        if progress and nfev[0] % 2000 == 0:
            progress({"stage": "static", "method": "paper", "evaluations": nfev[0],
                      "cost": float((w_m * j_m + w_u * j_u) / norm)})
        return (w_m * j_m + w_u * j_u) / norm                         # eq. 19

    x0 = np.r_[np.asarray(start[0]) / _SIGMA_REF_PA, np.asarray(start[1]) / _SIGMA_REF_PA, start[2]]
    opts = {"xatol": 1e-6, "fatol": 1e-16, "maxfev": 20000, "maxiter": 20000}
    opts.update(options or {})
    sol = minimize(cost_fn, x0, method="Nelder-Mead", options=opts)
    beta = tuple(float(v) for v in sol.x[:3] * _SIGMA_REF_PA)
    gamma = tuple(float(v) for v in sol.x[3:6] * _SIGMA_REF_PA)
    eps_r = float(sol.x[6])
    warnings = []
    if not sol.success:
        warnings.append(f"paper static fit (Nelder-Mead): {sol.message}")
    if eps_r <= 1.0:
        raise StaticFitError(f"paper static fit ended at eps_r = {eps_r:.3g} <= 1 (non-physical); "
                             "use method='lsq' or a better start")
    combos = stress_combinations(beta, gamma)
    # Statistics in the space the optimizer moved: (beta, gamma, eps_r), displacement residuals.
    result = _finish(template, beta, gamma, eps_r, data, problem, "paper", None, float(sol.fun),
                     nfev[0], t0, [{"start": "given", "cost": float(sol.fun), "nfev": nfev[0]}],
                     warnings, combos)
    result.statistics = result.ogden_statistics
    return result


def generic_start(template: MembraneParameters, data: StaticData, eps_r: float = 3.0):
    """A neutral start: sigma_h(1) carrying the heaviest zero-voltage load at its measured d,
    sigma_h'(1) = sigma_h''(1) = 0, written as mu_i (eqs. 8-9); eps_r = 3."""
    loaded = (data.mass_kg > 0) & (data.displacement_m > 0)
    if not np.any(loaded):
        raise StaticFitError(f"{data.source}: no static point with a mass and a positive displacement")
    zero_v = loaded & (data.voltage_V == 0)
    pick = zero_v if np.any(zero_v) else loaded
    k = np.nonzero(pick)[0][np.argmax(data.mass_kg[pick])]
    d = data.displacement_m[k]
    l0 = template.electrode_width_m
    s = 1.0 + d * d / l0**2
    sigma0 = data.mass_kg[k] * template.gravity_m_per_s2 * s / (template.c1bar_m * d)
    beta, gamma = ogden_from_combinations([sigma0, 0.0], template.prestretch)
    return beta, gamma, eps_r


def fit_static(
    data: StaticData,
    template: MembraneParameters,
    method: str = "lsq",
    stress_terms: int = 2,
    prior_from_template: bool = True,
    start=None,
    progress: Callable[[dict], None] | None = None,
    nelder_mead_options: dict | None = None,
    curvature_Pa: float | None = None,
) -> StaticFitResult:
    """Fit the static parameters to rest displacements (eqs. 19-20).

    ``template`` supplies geometry and constants (and, with
    ``prior_from_template``, the Ogden prior used to write the fitted
    combinations as beta/gamma). ``method``: ``"lsq"`` (default) or ``"paper"``.
    ``stress_terms`` (lsq): 2 fits sigma_h(1), sigma_h'(1) and eps_r; 3 adds sigma_h''(1).
    ``start`` (paper): (beta, gamma, eps_r); default :func:`generic_start`.
    ``curvature_Pa`` (lsq): fix sigma_h''(1) (otherwise it follows the representation).
    """
    if method not in STATIC_METHODS:
        raise ValueError(f"method: choose one of {STATIC_METHODS}, got {method!r}")
    if stress_terms not in (1, 2, 3):
        raise ValueError(f"stress_terms: 1, 2 or 3, got {stress_terms}")
    t0 = time.perf_counter()
    problem = _StaticProblem(template, data)
    if method == "lsq":
        prior = (template.beta_Pa, template.gamma_Pa) if prior_from_template else None
        return _fit_lsq(template, data, problem, stress_terms, prior, progress, t0, curvature_Pa)
    start = generic_start(template, data) if start is None else start
    return _fit_paper(template, data, problem, start, progress, t0, nelder_mead_options)


@dataclass(frozen=True)
class CurvatureTest:
    """Whether the rest displacements determine sigma_h''(1) (eq. 10) beyond sigma_h(1), sigma_h'(1) and
    eps_r (:func:`static_curvature_test`)."""

    needed: bool                 # the fit with sigma_h''(1) free is the one to use
    f_statistic: float           # extra sum of squares F(1, dof) of freeing sigma_h''(1)
    p_value: float
    sum_sq_ratio: float          # sum of squares held / free
    relative_ci: float           # 95 % half-width / |value| of sigma_h''(1) in the free fit
    dof: int                     # residual degrees of freedom of the free fit

    def note(self) -> str:
        """One sentence for the identification's warnings."""
        return (f"static fit: the rest displacements determine sigma_h''(1) (sum of squares {self.sum_sq_ratio:.3g}x "
                f"smaller with it free, F(1, {self.dof}) = {self.f_statistic:.3g}, p = {self.p_value:.2g}; 95 % "
                f"interval +-{100 * self.relative_ci:.2g} %): it is fitted with sigma_h(1), sigma_h'(1) and eps_r "
                "instead of held at the representation's value, which would bias them")


def static_curvature_test(held: StaticFitResult, free: StaticFitResult, alpha: float = 1e-3,
                          rel_ci_limit: float = 0.5) -> CurvatureTest:
    """Compare the least-squares static fit with sigma_h''(1) held (``stress_terms=2``: it follows the
    representation of the fitted combinations) and free (``stress_terms=3``) on the same points: the
    nested models' extra-sum-of-squares F test at level ``alpha``, and sigma_h''(1) determined (95 %
    half-width at most ``rel_ci_limit`` of its value). Large deflections probe the stress curve away from
    stretch 1, so a membrane whose curvature differs from the representation's is fitted with a wrong
    slope and eps_r when it is held (issue 21, item 1)."""
    n = int(free.measured_m.size)
    dof = n - 4
    held_ss, free_ss = float(held.cost), float(free.cost)
    names = free.statistics.names if free.statistics is not None else ()
    k = names.index("sigma_h''(1)_Pa") if "sigma_h''(1)_Pa" in names else None
    rel = float(free.statistics.relative_ci[k]) if k is not None else math.inf
    if dof < 1 or not (math.isfinite(held_ss) and math.isfinite(free_ss)) or free_ss > held_ss:
        return CurvatureTest(False, 0.0, 1.0, 1.0, rel, max(dof, 0))
    f_stat = (held_ss - free_ss) / max(free_ss / dof, 1e-300)
    p_value = float(scipy_stats.f.sf(f_stat, 1, dof))
    ratio = held_ss / free_ss if free_ss > 0 else math.inf
    return CurvatureTest(bool(p_value < alpha and rel <= rel_ci_limit), float(f_stat), p_value, ratio, rel, dof)
