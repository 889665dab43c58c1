"""Fast transient solver: whole-trajectory Hermite-Simpson collocation with exact sensitivities.

Why: the dynamic identification (paper eqs. 22-23) simulates a ~2-5 s voltage step
sampled at 1 kHz at every objective evaluation. Adaptive forward integration
(:func:`~dea_ros.solvers.integrate.simulate`, ~0.15 s per step response) would
dominate the cost of the fit; this solver needs ~10 ms warm-started and also
returns the exact forward sensitivities dx/d(ln k1, ln eta1, ln eta2) (and, on
request, along directions of the Ogden coefficients) that a Jacobian-based
optimizer (``scipy.optimize.least_squares``) needs.

Method
------
The grid is the sampling grid of the experiment, t_0 < t_1 < ... < t_K-1 (one
interval per sample interval; ``substeps`` > 1 splits each sample interval
further). On every interval [t_n, t_n+1] of length h the state equation
x' = f(x, u) (eqs. 17-18) is discretised by Hermite-Simpson collocation (the
3-stage Lobatto IIIA method: order 4, A-stable, phase error ~ (omega h)^5 / 720
per step for the lightly damped oscillation) in its compressed form, the
midpoint state being explicit::

    x_m     = (x_n + x_n+1) / 2 + h/8 (f_n - f_n+1)
    R_n     = x_n+1 - x_n - h/6 (f_n + 4 f(x_m) + f_n+1) = 0

with x_0 the static equilibrium at u(t_0) (eq. 20: the rig at rest before the
experiment). All 3 K node states are solved at once by Newton's method with a
backtracking line search. The Jacobian (chain rule through x_m, from the
vectorised analytic df/dx of :class:`~dea_ros.model.DEAModel`) is block
bidiagonal; it is stored in LAPACK band format (kl = 5, ku = 2) and factorised
by ``dgbtrf`` in O(K). Warm start: the previous solution plus a first-order
predictor from its sensitivities (theta changed by d theta: x + S d theta), so
an optimizer step converges in 2-3 Newton iterations. Convergence: the scaled
Newton step is below ``tol`` = 1e-5 (Newton converges quadratically with an
observed constant ~0.2, so the remaining error is ~1e-11 of the state scale).

Forward sensitivities: at the converged solution R(X, theta) = 0, so
dX/dtheta = -J^-1 dR/dtheta: one more factorisation at the solution and a few
band back-substitutions (``dgbtrs``). theta = (ln k1, ln eta1, ln eta2), plus
optional stress directions (the initial rest state moves with those).

Voltage between samples: ``hold="zoh"`` (default; what a DAQ output does, the
voltage sample u_n holds on [t_n, t_n+1)) or ``"linear"`` (interpolated).

Accuracy (``test/identify/test_transient.py``, ``bench/bench_identify.py``): for a
2.2 kV step sampled at 1 kHz over 4.2 s, the max difference to DOP853 at rtol 1e-11 is
0.97 nm (LP1), 1.2 nm (A1, A2); halving h gains the expected ~16x.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgbtrf, dgbtrs

from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from .inputs import check_voltage
from ..errors import TransientError

__all__ = [
    "TransientSolution",
    "TransientCollocation",
    "record_substeps",
    "MAX_OMEGA_H",
    "TransientError",
    "simulate_collocation",
    "DYNAMIC_PARAMETERS",
    "rhs_log_parameter_derivative",
    "rhs_stress_derivative",
    "stress_direction_basis",
    "rest_state_derivative",
    "rhs_permittivity_derivative",
    "rest_state_permittivity_derivative",
]

#: Parameters whose (logarithmic) sensitivities are computed, in this order.
DYNAMIC_PARAMETERS = ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")

_KL = 5  # lower bandwidth of the collocation Jacobian: rows 3 + 3n + i, columns 3n + j .. 3n + 5
_KU = 2  # upper bandwidth


@dataclass
class TransientSolution:
    """Trajectory on the sample grid.

    ``state`` (3, K) at the sample times; ``sensitivity`` (3 + q, 3, K) with
    ``sensitivity[p, i, k] = d state_i(t_k) / d ln(theta_p)`` for theta =
    (k1, eta1, eta2), then d state_i / d c_j for q stress directions, or None
    when not requested.
    """

    time_s: np.ndarray
    state: np.ndarray
    sensitivity: np.ndarray | None
    newton_iterations: int
    wall_time_s: float
    nodes: np.ndarray  # (3, N+1) states at all grid nodes (warm start for the next solve)

    @property
    def displacement_m(self) -> np.ndarray:
        return self.state[0]

    @property
    def displacement_sensitivity_m(self) -> np.ndarray | None:
        """d d(t_k) / d ln(k1, eta1, eta2) (then stress directions), shape (3 + q, K), m."""
        return None if self.sensitivity is None else self.sensitivity[:, 0, :]


def rhs_log_parameter_derivative(model: DEAModel, x) -> np.ndarray:
    """d f(x, u) / d ln(k1, eta1, eta2) at states x (3, ...): shape (3 params, 3 components, ...).

    From eqs. 11-12 and 18: only the viscoelastic strain rate (k1/eta1 (lambda - 1 - eps1))
    and the acceleration (k1 strain and eta2 phi d' terms) depend on them; u does not enter.
    """
    d, e, v = (np.asarray(c, dtype=float) for c in x)
    s = 1.0 + d * d / model.l0_sq
    lam = np.sqrt(s)
    strain = lam - 1.0 - e
    phi = d / (model.l0_sq * lam)
    d_over_s = d / s
    kg = model.force_gain
    out = np.zeros((3, 3) + d.shape)
    out[0, 1] = model.relax_rate * strain
    out[0, 2] = -kg * d_over_s * model.k1 * strain
    out[1, 1] = -model.relax_rate * strain
    out[2, 2] = -kg * d_over_s * model.eta2 * phi * v
    return out


def stress_direction_basis(s, directions) -> np.ndarray:
    """d sigma_h(s) / d c_j for Ogden coefficient directions (beta, gamma) = c_j directions[j] (eq. 10).

    ``directions`` (q, 6): beta_1..3 then gamma_1..3 per direction. Returns (q,) + s.shape, Pa per unit.
    """
    dirs = np.atleast_2d(np.asarray(directions, float))
    s = np.asarray(s, float)
    out = np.zeros((dirs.shape[0],) + s.shape)
    for i in range(3):
        out += dirs[:, i].reshape((-1,) + (1,) * s.ndim) * s ** (i + 1)
        out -= dirs[:, 3 + i].reshape((-1,) + (1,) * s.ndim) * s ** (-(i + 1))
    return out


def rhs_stress_derivative(model: DEAModel, x, directions) -> np.ndarray:
    """d f / d c_j for hyperelastic-stress directions (see :func:`stress_direction_basis`):
    shape (q, 3, ...); only the acceleration (eq. 18) depends on sigma_h."""
    d = np.asarray(x[0], float)
    s = 1.0 + d * d / model.l0_sq
    h = stress_direction_basis(s, directions)
    out = np.zeros((h.shape[0], 3) + d.shape)
    out[:, 2] = -model.force_gain * (d / s) * h
    return out


def rhs_permittivity_derivative(model: DEAModel, x, u2) -> np.ndarray:
    """d f / d eps_r at states x (3, ...) under u^2 (broadcastable): shape (1, 3, ...).

    Only the Maxwell stress c2 s u^2 depends on it (eq. 6, c2 proportional to eps_r)."""
    d = np.asarray(x[0], float)
    eps_r = model.params.relative_permittivity
    out = np.zeros((1, 3) + np.broadcast_shapes(d.shape, np.shape(u2)))
    out[0, 2] = -model.force_gain * d * np.asarray(u2, float) * (model.c2 / eps_r)
    return out


def rest_state_permittivity_derivative(params: MembraneParameters, voltage_V: float,
                                       displacement_m: float | None = None) -> np.ndarray:
    """d(rest state [d, eps1, d'])/d eps_r by implicit differentiation of eq. 20. Shape (1, 3)."""
    if displacement_m is None:
        displacement_m = float(static_equilibrium(params, float(voltage_V)).displacement_m)
    d = float(displacement_m)
    u2 = float(voltage_V) ** 2
    if d <= 0.0 or u2 == 0.0:
        return np.zeros((1, 3))
    model = DEAModel.from_parameters(params)
    s = 1.0 + d * d / model.l0_sq
    dforce = params.c1bar_m * d * u2 * (model.c2 / params.relative_permittivity)
    dd = -dforce / float(model.static_stiffness_N_per_m(d, u2))
    phi = d / (model.l0_sq * np.sqrt(s))
    return np.array([[dd, phi * dd, 0.0]])


def rest_state_derivative(params: MembraneParameters, voltage_V: float, directions,
                          displacement_m: float | None = None) -> np.ndarray:
    """d(rest state [d, eps1, d'])/d c_j for stress directions, by implicit differentiation of
    eq. 20 at the static equilibrium (eps1 relaxed). Shape (q, 3)."""
    if displacement_m is None:
        displacement_m = float(static_equilibrium(params, float(voltage_V)).displacement_m)
    d = float(displacement_m)
    dirs = np.atleast_2d(np.asarray(directions, float))
    if d <= 0.0:
        return np.zeros((dirs.shape[0], 3))
    model = DEAModel.from_parameters(params)
    s = 1.0 + d * d / model.l0_sq
    h = stress_direction_basis(s, dirs)
    stiffness = float(model.static_stiffness_N_per_m(d, float(voltage_V) ** 2))
    dd = -params.c1bar_m * (d / s) * h / stiffness
    phi = d / (model.l0_sq * np.sqrt(s))
    return np.column_stack([dd, phi * dd, np.zeros_like(dd)])


def _static_key(params: MembraneParameters) -> tuple:
    """The fields the static equilibrium depends on (everything but k1, eta1, eta2)."""
    return (
        params.prestretch, params.thickness_m, params.plate_radius_m, params.electrode_width_m,
        params.mass_kg, params.relative_permittivity, params.beta_Pa, params.gamma_Pa,
        params.gravity_m_per_s2, params.vacuum_permittivity_F_per_m,
    )


#: The largest omega h of a collocation interval (omega: the fastest linearised mode of the membrane over the
#: record, h: the interval). A record sampled at a tenth of the oscillation's period is far from converged with
#: one interval per sample: the mock membrane's step (its linear oscillation at 19 Hz, omega = 120 rad/s) sampled
#: at 250 Hz (omega h = 0.48) was 0.19 um RMS from converged integration, which biased eta1 by +2 % (2.5 standard
#: errors, 1 um noise) in identification from 250 Hz records (issue 21, session 17); at omega h = 0.24 (two
#: intervals per sample, or 500 Hz) 0.012 um RMS, at 0.12 0.0007 um (Hermite-Simpson's error ~ (omega h)^4).
MAX_OMEGA_H = 0.25
#: At most this many collocation intervals per sample interval.
MAX_SUBSTEPS = 8


def record_substeps(params: MembraneParameters, time_s, voltage_V, max_omega_h: float = MAX_OMEGA_H) -> int:
    """Substeps per sample interval for :class:`TransientCollocation` on the record (``time_s``, ``voltage_V``)
    of the membrane ``params``: the fewest that keep omega h within ``max_omega_h`` (:data:`MAX_OMEGA_H`) for
    the fastest linearised mode (at the equilibria of the record's first and largest voltage), at most
    :data:`MAX_SUBSTEPS`."""
    t = np.asarray(time_s, dtype=float).reshape(-1)
    u = np.asarray(voltage_V, dtype=float).reshape(-1)
    if t.size < 2:
        return 1
    model = DEAModel.from_parameters(params)
    omega = 0.0
    for level in {float(u[0]), float(np.max(np.abs(u)))}:
        x = np.asarray(static_equilibrium(params, level).state, dtype=float).reshape(3)
        omega = max(omega, float(np.max(np.abs(np.linalg.eigvals(model.jacobian(x, level))))))
    substeps = math.ceil(omega * float(np.max(np.diff(t))) / max_omega_h - 1e-9)
    return int(min(max(substeps, 1), MAX_SUBSTEPS))


class TransientCollocation:
    """Hermite-Simpson whole-trajectory solver for one sampled voltage record.

    Build once per experiment (grid, voltages, band structure); call
    :meth:`solve` for each parameter set. The last solution is kept as the
    warm start of the next call unless ``warm_start=False``.
    """

    @classmethod
    def for_record(cls, params: MembraneParameters, time_s, voltage_V, hold: str = "zoh", **options):
        """The solver of a record, its grid fine enough for the membrane ``params``
        (:func:`record_substeps`; the parameters of later solves may differ: the grid is kept)."""
        return cls(time_s, voltage_V, hold=hold, substeps=record_substeps(params, time_s, voltage_V), **options)

    def __init__(self, time_s, voltage_V, hold: str = "zoh", substeps: int = 1,
                 tol: float = 1e-5, max_iter: int = 25):
        t = np.asarray(time_s, dtype=float).reshape(-1)
        u = check_voltage(voltage_V, "voltage_V").reshape(-1)
        if t.size != u.size:
            raise ValueError(f"time_s and voltage_V: lengths differ ({t.size} vs {u.size})")
        if t.size < 3:
            raise ValueError("time_s: a transient needs at least 3 samples")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("time_s: must be finite and strictly increasing")
        if hold not in ("zoh", "linear"):
            raise ValueError(f"hold: 'zoh' or 'linear', got {hold!r}")
        substeps = int(substeps)
        if substeps < 1:
            raise ValueError(f"substeps: must be >= 1, got {substeps}")
        self.time_s = t
        self.voltage_V = u
        self.hold = hold
        self.substeps = substeps
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        # Collocation grid: every sample interval split into `substeps` equal intervals.
        frac = np.arange(substeps) / substeps
        grid = (t[:-1, None] + np.diff(t)[:, None] * frac[None, :]).reshape(-1)
        self.grid_s = np.append(grid, t[-1])
        self.sample_nodes = np.arange(t.size) * substeps
        h = np.diff(self.grid_s)
        self.h = h
        n_int = h.size
        self.n_intervals = n_int
        # u^2 at the left end, midpoint and right end of every interval.
        if hold == "zoh":
            u_int = np.repeat(u[:-1], substeps)
            self.u2_left = self.u2_mid = self.u2_right = u_int * u_int
        else:
            u_grid = np.interp(self.grid_s, t, u)
            u_mid = np.interp(self.grid_s[:-1] + 0.5 * h, t, u)
            self.u2_left = u_grid[:-1] ** 2
            self.u2_right = u_grid[1:] ** 2
            self.u2_mid = u_mid**2
        self.n_unknowns = 3 * (n_int + 1)
        self._ab = np.zeros((2 * _KL + _KU + 1, self.n_unknowns))
        self._ab[_KL + _KU, :3] = 1.0  # initial-condition rows: identity (the rest is refilled)
        self._h = h[:, None, None]  # for (N, 3, 3) block arithmetic
        self._last_nodes: np.ndarray | None = None
        self._last_sens: np.ndarray | None = None
        self._last_theta = np.zeros(3)
        self._last_static = None
        self._rest_cache: tuple | None = None

    # ----------------------------------------------------------------- helpers
    @staticmethod
    def state_scale(params: MembraneParameters, x0: np.ndarray) -> np.ndarray:
        """Typical sizes of [d, eps1, d'] for scaling the unknowns and residuals."""
        d_ref = max(abs(float(x0[0])), 1e-3 * params.electrode_width_m)
        eps_ref = max((d_ref / params.electrode_width_m) ** 2, 1e-8)
        m = max(params.mass_kg, 1e-9)
        k_ref = max(params.c1bar_m * abs(params.prestress_Pa) / params.electrode_width_m, 1e-6)
        omega_ref = np.sqrt(k_ref / m)
        return np.array([d_ref, eps_ref, d_ref * omega_ref])

    def quasi_static_guess(self, params: MembraneParameters, x0: np.ndarray) -> np.ndarray:
        """Initial guess (3, N+1): the static equilibrium at every grid voltage (eps1 relaxed, d' = 0)."""
        u_grid = np.sqrt(np.append(self.u2_left, self.u2_right[-1]))
        try:
            nodes = np.asarray(static_equilibrium(params, u_grid).state, float).reshape(3, -1)
        except Exception:  # noqa: BLE001 - no equilibrium somewhere: constant guess
            nodes = np.repeat(x0[:, None], u_grid.size, axis=1)
        nodes[:, 0] = x0
        return nodes

    def _rest_state(self, params: MembraneParameters) -> np.ndarray:
        """Static equilibrium at u(t_0) (eq. 20); cached while the static parameters do not change."""
        key = _static_key(params)
        if self._rest_cache is None or self._rest_cache[0] != key:
            state = static_equilibrium(params, float(self.voltage_V[0])).state
            self._rest_cache = (key, np.asarray(state, float).reshape(3))
        return self._rest_cache[1].copy()

    @staticmethod
    def _rhs_jac(model: DEAModel, x, u2):
        """f as (3, N) and df/dx as (N, 3, 3) at the points x (3, N)."""
        f, rows = model.rhs_and_jacobian_u2(x[0], x[1], x[2], u2)
        f = np.stack(np.broadcast_arrays(*f))
        n = x.shape[1]
        a = np.empty((n, 3, 3))
        for i in range(3):
            for j in range(3):
                a[:, i, j] = rows[i][j]
        return f, a

    # ------------------------------------------------------------------ system
    def _evaluate(self, model: DEAModel, nodes, x0, scale, want_jacobian=True):
        """Scaled residual (3 (N+1),) and, optionally, the band matrix of its Jacobian.

        Compressed Hermite-Simpson: the midpoint state is eliminated explicitly,
        x_m = (x_n + x_n+1)/2 + h/8 (f_n - f_n+1), and the unknowns are the node states.
        """
        h = self.h
        xl, xr = nodes[:, :-1], nodes[:, 1:]
        fl, al = self._rhs_jac(model, xl, self.u2_left)
        fr, ar = self._rhs_jac(model, xr, self.u2_right)
        xm = 0.5 * (xl + xr) + (h / 8.0) * (fl - fr)
        fm, am = self._rhs_jac(model, xm, self.u2_mid)
        r_end = xr - xl - (h / 6.0) * (fl + 4.0 * fm + fr)
        res = np.empty((self.n_intervals + 1, 3))
        res[0] = (nodes[:, 0] - x0) / scale
        res[1:] = (r_end / scale[:, None]).T
        res = res.reshape(-1)
        if not want_jacobian:
            return res, None, None
        hb = self._h
        eye = np.eye(3)[None]
        dxm_dl = 0.5 * eye + (hb / 8.0) * al      # d x_m / d x_n
        dxm_dr = 0.5 * eye - (hb / 8.0) * ar      # d x_m / d x_n+1
        left = -eye - (hb / 6.0) * (al + 4.0 * (am @ dxm_dl))     # d R_n / d x_n
        right = eye - (hb / 6.0) * (ar + 4.0 * (am @ dxm_dr))     # d R_n / d x_n+1
        ratio = scale[None, :] / scale[:, None]
        ab = self._ab
        n = self.n_intervals
        # Band position of block entry (i, j): row KL + KU + 3 + i - 3 b - j, column 3 n + 3 b + j.
        for b, block in ((0, left), (1, right)):
            for i in range(3):
                for j in range(3):
                    col0 = 3 * b + j
                    ab[_KL + _KU + 3 + i - 3 * b - j, col0:col0 + 3 * n:3] = block[:, i, j] * ratio[i, j]
        return res, ab, (xm, am)

    def _parameter_derivative(self, model: DEAModel, nodes, mid, scale, directions=None,
                              dx0=None, permittivity: bool = False) -> np.ndarray:
        """dR/d(ln k1, ln eta1, ln eta2[, stress directions][, eps_r]), shape (n_unknowns, 3 + q), scaled."""
        xm, am = mid
        h = self.h

        def g(x, u2):
            out = rhs_log_parameter_derivative(model, x)
            if directions is not None:
                out = np.concatenate([out, rhs_stress_derivative(model, x, directions)], axis=0)
            if permittivity:
                out = np.concatenate([out, rhs_permittivity_derivative(model, x, u2)], axis=0)
            return out

        gl, gm, gr = g(nodes[:, :-1], self.u2_left), g(xm, self.u2_mid), g(nodes[:, 1:], self.u2_right)
        n_par = gl.shape[0]
        # total derivative of f(x_m) through the explicit midpoint: g_m + A_m dx_m/dtheta
        dxm = (h / 8.0) * (gl - gr)                               # (P, 3, N)
        gm_total = gm + np.einsum("nij,pjn->pin", am, dxm)
        d_end = -(h / 6.0) * (gl + 4.0 * gm_total + gr)           # (P, 3, N)
        out = np.zeros((n_par, self.n_intervals + 1, 3))
        out[:, 1:, :] = np.transpose(d_end / scale[None, :, None], (0, 2, 1))
        if dx0 is not None:  # initial-condition rows: R_0 = (x_0 - x0(theta)) / scale
            out[3:, 0, :] = -np.asarray(dx0, float) / scale[None, :]
        return out.reshape(n_par, -1).T

    # ------------------------------------------------------------------- solve
    def solve(
        self,
        params: MembraneParameters,
        x0=None,
        nodes_guess: np.ndarray | None = None,
        sensitivities: bool = False,
        warm_start: bool = True,
        stress_directions=None,
        permittivity: bool = False,
    ) -> TransientSolution:
        """Trajectory for ``params`` from ``x0`` (default: static equilibrium at u(t_0)).

        ``nodes_guess`` (3, N+1) overrides the warm start (the previous
        solution of this object). ``stress_directions`` (q, 6): with
        ``sensitivities``, also d state / d c_j for (beta, gamma) moving along
        c_j * direction_j (the initial rest state moves too, when x0 is None);
        ``permittivity``: then also d state / d eps_r (last).
        Raises :class:`TransientError` when Newton fails from the warm start
        *and* from the quasi-static guess.
        """
        t_start = time.perf_counter()
        model = DEAModel.from_parameters(params)
        rest = x0 is None
        if rest:
            x0 = self._rest_state(params)
        x0 = np.asarray(x0, float).reshape(3)
        scale = self.state_scale(params, x0)
        theta = np.log([params.k1_Pa, params.eta1_Pa_s, max(params.eta2_Pa_s, 1e-300)])
        failure = ""
        for kind, nodes in self._guesses(params, x0, theta, nodes_guess, warm_start):
            if nodes is None:
                nodes = self.quasi_static_guess(params, x0)
            try:
                nodes, ab, mid, iterations = self._newton(model, nodes, x0, scale)
                break
            except TransientError as exc:
                failure += f" from the {kind} guess: {exc};"
        else:
            raise TransientError(
                f"collocation Newton failed{failure} refine the grid (substeps > 1) "
                "or check that the parameters give a bounded response"
            )
        sens = None
        if sensitivities:
            sens_nodes = self._node_sensitivities(params, model, nodes, ab, mid, x0, scale, stress_directions,
                                                  permittivity, rest)
            sens = sens_nodes[:, :, self.sample_nodes]
        self._last_nodes = nodes
        self._last_sens = sens_nodes[:3] if sensitivities else None
        self._last_theta = theta
        self._last_static = _static_key(params)
        return TransientSolution(
            time_s=self.time_s,
            state=nodes[:, self.sample_nodes],
            sensitivity=sens,
            newton_iterations=iterations,
            wall_time_s=time.perf_counter() - t_start,
            nodes=nodes,
        )

    def _guesses(self, params, x0, theta, nodes_guess, warm_start) -> list:
        """The starting trajectories to try, in order: [(kind, nodes (3, N+1) or None for quasi-static)]."""
        guesses = []
        if nodes_guess is not None:
            guesses.append(("given", np.asarray(nodes_guess, float).reshape(3, -1)))
        elif warm_start and self._last_nodes is not None:
            guess = self._last_nodes
            if self._last_sens is not None and self._last_static == _static_key(params):
                # First-order predictor from the last sensitivities: Newton then needs ~2 iterations.
                dtheta = theta - self._last_theta
                if np.all(np.abs(dtheta) < 1.0):
                    guess = guess + np.tensordot(dtheta, self._last_sens, axes=1)
                    guess[:, 0] = x0
            guesses.append(("warm", guess))
        guesses.append(("quasi-static", None))
        return guesses

    def _node_sensitivities(self, params, model, nodes, ab, mid, x0, scale, stress_directions, permittivity,
                            rest) -> np.ndarray:
        """d nodes / d theta (3 + q [+ 1], 3, N+1) at the converged trajectory: the Jacobian factorised there,
        dX/dtheta = -J^-1 dR/dtheta (the rest state moves with the stress directions and eps_r when ``rest``)."""
        lu, piv, info = dgbtrf(ab, _KL, _KU)
        if info != 0:
            raise TransientError(f"singular collocation Jacobian (LAPACK info {info})")
        dx0 = None
        if (stress_directions is not None or permittivity) and rest:
            parts = []
            if stress_directions is not None:
                parts.append(rest_state_derivative(params, float(self.voltage_V[0]), stress_directions,
                                                   displacement_m=float(x0[0])))
            if permittivity:
                parts.append(rest_state_permittivity_derivative(params, float(self.voltage_V[0]),
                                                                displacement_m=float(x0[0])))
            dx0 = np.concatenate(parts, axis=0)
        rhs = self._parameter_derivative(model, nodes, mid, scale, stress_directions, dx0, permittivity)
        dz, info = dgbtrs(lu, _KL, _KU, -rhs, piv)
        if info != 0:
            raise TransientError(f"band back-substitution failed (LAPACK info {info})")
        dz = dz.reshape(self.n_intervals + 1, 3, -1)  # node, component, param
        return np.transpose(dz, (2, 1, 0)) * scale[None, :, None]

    def _newton(self, model, nodes, x0, scale):
        res, ab, mid = self._evaluate(model, nodes, x0, scale)
        rnorm = float(np.max(np.abs(res)))
        n = self.n_intervals + 1
        for it in range(1, self.max_iter + 1):
            lu, piv, info = dgbtrf(ab, _KL, _KU)
            if info != 0:
                raise TransientError(f"singular collocation Jacobian (LAPACK info {info})")
            step, info = dgbtrs(lu, _KL, _KU, res, piv)
            snorm = float(np.max(np.abs(step)))
            if not np.isfinite(snorm):
                raise TransientError("Newton step is not finite")
            step = step.reshape(n, 3).T * scale[:, None]
            lam = 1.0
            for _ in range(10):
                trial = nodes - lam * step
                res_new, ab_new, mid_new = self._evaluate(model, trial, x0, scale)
                rn_new = float(np.max(np.abs(res_new)))
                if np.isfinite(rn_new) and (rn_new < rnorm or lam * snorm < self.tol):
                    break
                lam *= 0.5
            else:
                raise TransientError(f"line search failed at iteration {it} (residual {rnorm:.3g})")
            nodes, res, ab, mid, rnorm = trial, res_new, ab_new, mid_new, rn_new
            if lam == 1.0 and snorm <= self.tol:
                return nodes, ab, mid, it
        raise TransientError(
            f"no convergence in {self.max_iter} iterations (last scaled residual {rnorm:.3g})"
        )


def simulate_collocation(
    params: MembraneParameters,
    time_s,
    voltage_V,
    hold: str = "zoh",
    substeps: int = 1,
    x0=None,
    sensitivities: bool = False,
) -> TransientSolution:
    """One-shot convenience wrapper: the response to a sampled voltage on its sample grid."""
    return TransientCollocation(time_s, voltage_V, hold=hold, substeps=substeps).solve(
        params, x0=x0, sensitivities=sensitivities
    )
