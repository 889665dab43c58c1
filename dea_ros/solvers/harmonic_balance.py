"""Native harmonic balance: time-domain collocation (eq. 16) with Newton and the analytic Jacobian.

The periodic steady state x(theta), theta = omega t, is represented by its
values at M = 2N + 1 equally spaced phases (N harmonics, eq. 13). Its
derivative is the spectral (Fourier) differentiation of those values (eq. 14),
so the collocation residual (eqs. 15-16) is::

    R(X) = omega X D^T - f(X, u(theta_k)),   X of shape (3, M)

with D the M x M Fourier differentiation matrix. Newton's method solves
R = 0 with the exact Jacobian ``omega kron(I3, D) - blockdiag(df/dx)`` in
scaled variables, with a backtracking line search, and stops when the scaled
Newton step is below ``tol``. Failure raises :class:`HarmonicBalanceError`.

Harmonics and symmetry: N counts harmonics of the *response* frequency and
fixes the collocation size, 2N + 1 points per response period (eq. 16). The
model sees the voltage only through u^2 (eq. 6); for a sine without offset u^2
has period T/2, the periodic response contains only even harmonics of the
excitation frequency f, and with ``use_symmetry`` the solver works on the half
period: N harmonics of 2f, i.e. up to 2Nf, on the same 2N + 1 points that the
paper's full-period solve (mousai, N harmonics of f) uses. Equal N therefore
means equal system size and cost, with twice the spectral reach. Stability is
computed over the response period, so a period doubling (odd harmonics of the
excitation appearing) shows up as a Floquet multiplier leaving the unit
circle through -1.

Stability: Floquet multipliers are the eigenvalues of the monodromy matrix,
the product over one period of exp(Omega_k) with the 4th-order Magnus
expansion Omega_k on the trigonometric interpolant of the solution.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..model.dynamics import DEAModel
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from . import hbm_kernels
from .inputs import PeriodicInput
from ..errors import HarmonicBalanceError

__all__ = [
    "HarmonicBalanceError",
    "PeriodicSolution",
    "CollocationSystem",
    "fourier_differentiation_matrix",
    "periodic_interpolation_matrix",
    "solve_native",
    "floquet_multipliers",
    "floquet_multipliers_batch",
    "attach_floquet",
    "classify_stability",
    "ModelSetup",
    "model_setup",
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
    def stable(self) -> bool | None:
        mu = self.stability_multipliers
        if mu is None:
            return None
        return bool(np.max(np.abs(mu)) < 1.0)

    @property
    def stability(self) -> str:
        """See :func:`classify_stability`."""
        return classify_stability(self.stability_multipliers)


def classify_stability(multipliers) -> str:
    """Name the way a periodic solution is (un)stable from its Floquet multipliers.

    * ``stable``: all |mu| < 1.
    * ``unstable (saddle)``: an odd number of real multipliers > 1 (the middle
      branch between two folds of a hysteresis loop).
    * ``unstable (real pair)``: an even number of real multipliers > 1 (no
      turning point; typically a complex pair that met on the real axis).
    * ``unstable (period-doubling)``: a real multiplier < -1 (odd harmonics of
      the excitation grow: the response period doubles).
    * ``unstable (torus)``: a complex pair outside the unit circle (the
      response becomes modulated / quasi-periodic).
    """
    if multipliers is None:
        return "unknown"
    mu = np.asarray(multipliers)
    outside = mu[np.abs(mu) >= 1.0]
    if outside.size == 0:
        return "stable"
    real = np.abs(outside.imag) <= 1e-9 * np.abs(outside)
    if np.any(real & (outside.real < 0)):
        return "unstable (period-doubling)"
    if np.any(~real):
        return "unstable (torus)"
    return "unstable (saddle)" if np.count_nonzero(real) % 2 else "unstable (real pair)"


def newton_error(status: int, iterations: int, residual: float, max_iter: int) -> HarmonicBalanceError:
    """The error for a Newton outcome code of :func:`hbm_kernels.newton` (the numpy path's messages)."""
    if status == 3:
        return HarmonicBalanceError(
            f"line search failed after {iterations} Newton iterations (scaled residual {residual:.3g})")
    if status == 4:
        return HarmonicBalanceError(
            f"no convergence in {max_iter} Newton iterations (scaled residual {residual:.3g}); "
            "try more iterations, a better initial guess, or continuation (sweep)")
    return HarmonicBalanceError(hbm_kernels.STATUS_MESSAGES[status])


class CollocationSystem:
    """The collocation equations for M points, in scaled variables, with cached index arrays.

    Unknown: z = X / scale[:, None] flattened (state-major). Residual scaled by
    scale * rate_ref so that all equations are O(1).
    """

    def __init__(self, model: DEAModel, n_points: int, scale: np.ndarray, rate_ref: float):
        self.model = model
        self.m = n_points
        self.d_theta = fourier_differentiation_matrix(n_points)
        self.scale = np.asarray(scale, dtype=float)
        self.rate_ref = float(rate_ref)
        m = n_points
        eye3 = np.eye(3)
        self.kron_d = np.kron(eye3, self.d_theta)
        i, l, k = np.meshgrid(np.arange(3), np.arange(3), np.arange(m), indexing="ij")
        self.block_index = ((i * m + k) * (3 * m) + (l * m + k)).reshape(-1)
        # Scaling of df/dx block (i, l): scale_l / (scale_i * rate_ref)
        self.block_scale = (self.scale[None, :] / (self.scale[:, None] * self.rate_ref))[:, :, None]
        self.res_scale = (1.0 / (self.scale * self.rate_ref))[:, None]
        self.constants = model.constants
        self.phases = 2.0 * np.pi * np.arange(m) / m    # of the collocation points, rad

    def unscale(self, z: np.ndarray) -> np.ndarray:
        return z.reshape(3, self.m) * self.scale[:, None]

    def to_z(self, x: np.ndarray) -> np.ndarray:
        return (np.asarray(x, float) / self.scale[:, None]).reshape(-1)

    def residual_and_jacobian(self, z, omega, u2, want_jacobian: bool = True):
        """Scaled residual (3M,) and, optionally, its Jacobian (3M, 3M)."""
        x = self.unscale(z)
        f, a = self.model.rhs_and_jacobian_u2(x[0], x[1], x[2], u2)
        r = omega * (x @ self.d_theta.T)
        r[0] -= f[0]
        r[1] -= f[1]
        r[2] -= f[2]
        r = (r * self.res_scale).reshape(-1)
        if not want_jacobian:
            return r, None
        blocks = np.empty((3, 3, self.m))
        for i in range(3):
            for j in range(3):
                blocks[i, j] = a[i][j]
        jac = (omega / self.rate_ref) * self.kron_d
        jac.reshape(-1)[self.block_index] -= (blocks * self.block_scale).reshape(-1)
        return r, jac

    def residual(self, z, omega, u2) -> np.ndarray:
        return self.residual_and_jacobian(z, omega, u2, want_jacobian=False)[0]

    def jacobian(self, z, omega, u2) -> np.ndarray:
        return self.residual_and_jacobian(z, omega, u2)[1]

    def d_residual_d_log_omega(self, z, omega) -> np.ndarray:
        """dR/d(ln omega) = omega X D^T (scaled)."""
        x = self.unscale(z)
        return (omega * (x @ self.d_theta.T) * self.res_scale).reshape(-1)

    def newton(self, z0, omega, u2, tol=1e-10, max_iter=40):
        """Damped Newton. Returns (z, iterations, scaled residual); raises on failure.

        Converged when the full Newton step is below ``tol`` (scaled units, so
        relative to the typical size of each state). Runs the compiled kernel
        (:func:`hbm_kernels.newton`, the same iteration) when numba is enabled.
        """
        if hbm_kernels.enabled():
            z, it, rnorm, status = hbm_kernels.newton(
                np.array(z0, dtype=float).reshape(-1), float(omega), np.asarray(u2, dtype=float),
                self.constants, self.scale, self.rate_ref, self.d_theta, float(tol), int(max_iter))
            if status == 0:
                return z, it, rnorm
            raise newton_error(status, it, rnorm, max_iter)
        z = np.array(z0, dtype=float)
        r, jac = self.residual_and_jacobian(z, omega, u2)
        rnorm = float(np.max(np.abs(r)))
        for it in range(1, max_iter + 1):
            try:
                step = np.linalg.solve(jac, r)
            except np.linalg.LinAlgError:
                raise HarmonicBalanceError("singular harmonic-balance Jacobian (a fold?)") from None
            snorm = float(np.max(np.abs(step)))
            if not np.isfinite(snorm):
                raise HarmonicBalanceError("harmonic-balance Newton step is not finite")
            lam = 1.0
            for _ in range(12):
                z_new = z - lam * step
                r_new, jac_new = self.residual_and_jacobian(z_new, omega, u2)
                rn_new = float(np.max(np.abs(r_new)))
                if np.isfinite(rn_new) and (rn_new < rnorm or rn_new < 1e-13 or lam * snorm < tol):
                    break
                lam *= 0.5
            else:
                raise HarmonicBalanceError(
                    f"line search failed after {it} Newton iterations (scaled residual {rnorm:.3g})"
                )
            z, r, jac, rnorm = z_new, r_new, jac_new, rn_new
            if lam == 1.0 and snorm <= tol:
                return z, it, rnorm
        raise HarmonicBalanceError(
            f"no convergence in {max_iter} Newton iterations (scaled residual {rnorm:.3g}); "
            "try more iterations, a better initial guess, or continuation (sweep)"
        )


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
    """Periodic response of the model linearised about the static equilibrium at the mean of u^2."""
    model = setup.model
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = periodic_input.at_phase(phases / divisor) ** 2
    u2_mean = float(np.mean(u2))
    x_eq = setup.equilibrium_state(u2_mean)
    _f, rows = model.rhs_and_jacobian_u2(x_eq[0], x_eq[1], x_eq[2], u2_mean)
    a = np.array(rows, dtype=float)
    omega = periodic_input.omega * divisor
    if hbm_kernels.enabled():
        return hbm_kernels.linear_guess(x_eq, a, float(model.input_gain_u2(x_eq[0])), u2, u2_mean, float(omega))
    b = np.array([0.0, 0.0, model.input_gain_u2(x_eq[0])])
    w = np.fft.fft(u2 - u2_mean)
    n = np.fft.fftfreq(m, 1.0 / m)
    lhs = 1j * n[:, None, None] * omega * np.eye(3)[None] - a[None]
    dx = np.linalg.solve(lhs, (b[None, :] * w[:, None])[..., None])[..., 0]
    return x_eq[:, None] + np.real(np.fft.ifft(dx.T, axis=1))


AUTO_HARMONICS = (4, 6, 8, 12, 16, 24, 32)


def solve_native(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    n_harmonics: int | str = 8,
    x_guess: np.ndarray | None = None,
    tol: float = 1e-10,
    max_iter: int = 40,
    use_symmetry: bool = True,
    stability: bool = True,
    auto_tol: float = 1e-4,
) -> PeriodicSolution:
    """Periodic steady state by native harmonic balance.

    ``x_guess`` (3, M) in physical units may seed Newton (continuation);
    otherwise the linearised response is used, and on failure an amplitude
    homotopy (the input scaled from 25 % to 100 %) and then a frequency
    continuation from f/4 are tried before giving up.

    ``n_harmonics="auto"`` raises N through 4, 6, 8, 12, 16, 24, 32 (each
    solution seeding the next) until :attr:`PeriodicSolution.truncation_ratio`
    is below ``auto_tol`` (default 1e-4).
    """
    if isinstance(n_harmonics, str):
        if n_harmonics != "auto":
            raise ValueError(f"n_harmonics: an integer >= 1 or 'auto', got {n_harmonics!r}")
        t_auto = time.perf_counter()
        guess, sol, iters = x_guess, None, 0
        for n in AUTO_HARMONICS:
            sol = solve_native(params, periodic_input, n, x_guess=guess, tol=tol, max_iter=max_iter,
                               use_symmetry=use_symmetry, stability=False)
            iters += sol.iterations
            guess = sol.state
            if sol.truncation_ratio < auto_tol:
                break
        if stability:
            setup = model_setup(params)
            attach_floquet(setup.model, sol, scale=setup.scale)
        sol.iterations = iters
        sol.wall_time_s = time.perf_counter() - t_auto
        return sol
    t0 = time.perf_counter()
    setup = model_setup(params)
    divisor, m = response_layout(periodic_input, n_harmonics, use_symmetry)
    system = setup.system(m)
    omega = periodic_input.omega * divisor
    u2 = periodic_input.at_phase(system.phases / divisor) ** 2
    total_it = 0
    attempts = []
    if x_guess is not None:
        x_guess = np.asarray(x_guess, float)
        if x_guess.shape != (3, m):
            x_guess = resample_state(x_guess, m)
        attempts.append(("guess", system.to_z(x_guess)))
    attempts.append(("linear", None))
    z = None
    err = None
    for kind, z0 in attempts:
        if kind == "linear" and hbm_kernels.enabled():  # guess and Newton in one compiled call
            u2_mean = float(np.mean(u2))
            x_eq = setup.equilibrium_state(u2_mean)
            z, it, res, status = hbm_kernels.solve_cold(
                x_eq, float(setup.model.input_gain_u2(x_eq[0])), u2, u2_mean, float(omega), system.constants,
                system.scale, system.rate_ref, system.d_theta, float(tol), int(max_iter))
            if status == 0:
                total_it += it
                break
            z = None
            err = newton_error(status, it, res, max_iter)
            total_it += max_iter
            continue
        if kind == "linear":
            z0 = system.to_z(linear_guess(params, periodic_input, divisor, m, setup))
        try:
            z, it, res = system.newton(z0, omega, u2, tol=tol, max_iter=max_iter)
            total_it += it
            break
        except HarmonicBalanceError as exc:
            err = exc
            total_it += max_iter
    if z is None:  # homotopy in the amplitude of u^2 - mean(u^2)
        mean_u2 = float(np.mean(u2))
        z = system.to_z(linear_guess(params, periodic_input, divisor, m, setup))
        try:
            for frac in (0.25, 0.5, 0.75, 0.9, 1.0):
                z, it, res = system.newton(z, omega, mean_u2 + frac * (u2 - mean_u2), tol=tol,
                                           max_iter=max_iter)
                total_it += it
        except HarmonicBalanceError as exc:
            z = None
            err = f"{err}; amplitude homotopy: {exc}"
    if z is None:  # natural continuation in frequency from a quarter of f (an upward sweep)
        f = periodic_input.frequency_Hz
        try:
            z, it, res = _continue_up_in_frequency(setup, system, periodic_input, divisor, m, f, tol, max_iter)
            total_it += it
        except HarmonicBalanceError as exc:
            raise HarmonicBalanceError(
                f"harmonic balance failed at f = {f:g} Hz with N = {n_harmonics}: {err}; "
                f"frequency continuation: {exc}"
            ) from None
    x = system.unscale(z)
    sol = PeriodicSolution(
        frequency_Hz=periodic_input.frequency_Hz,
        periodic_input=periodic_input,
        state=x,
        period_divisor=divisor,
        n_harmonics=int(n_harmonics),
        method="native",
        iterations=total_it,
        residual=res,
        wall_time_s=0.0,
    )
    if stability:
        attach_floquet(setup.model, sol, scale=setup.scale)
    sol.wall_time_s = time.perf_counter() - t0
    return sol


def _continue_up_in_frequency(setup, system, periodic_input, divisor, m, f, tol, max_iter):
    """Natural continuation from f/4 (linearised guess there) up to f; the step halves on failure.

    Returns (z, iterations, scaled residual) at f. Raises HarmonicBalanceError.
    """
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = periodic_input.at_phase(phases / divisor) ** 2
    f_cur = 0.25 * f
    start = periodic_input.with_frequency(f_cur)
    z = system.to_z(linear_guess(setup.params, start, divisor, m, setup))
    z, iters, res = system.newton(z, 2.0 * np.pi * f_cur * divisor, u2, tol=tol, max_iter=max_iter)
    step = 0.1 * f
    while f_cur < f:
        f_next = min(f, f_cur + step)
        try:
            z_new, it, res = system.newton(z, 2.0 * np.pi * f_next * divisor, u2, tol=tol, max_iter=max_iter)
        except HarmonicBalanceError:
            step *= 0.5
            if step < 1e-4 * f:
                raise HarmonicBalanceError(f"no solution continued past {f_cur:.6g} Hz (a fold?)") from None
            continue
        iters += it
        z, f_cur = z_new, f_next
        step = min(1.5 * step, 0.1 * f)
    return z, iters, res


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


def resample_state(x: np.ndarray, m: int) -> np.ndarray:
    """Trigonometric resampling of (3, M_old) collocation values to m points."""
    x = np.asarray(x, float)
    phases = 2.0 * np.pi * np.arange(m) / m
    return x @ periodic_interpolation_matrix(x.shape[1], phases).T


_GAUSS = (0.5 - math.sqrt(3.0) / 6.0, 0.5 + math.sqrt(3.0) / 6.0)


@functools.lru_cache(maxsize=256)
def _gauss_phases(steps: int) -> tuple:
    """(phases, their cosines, their sines): the phases 2 pi (k + g) / steps (rad) of the two Gauss
    points g of the Magnus steps k = 0..steps-1 over one response period, all first points, then
    all second points (read-only arrays, shared)."""
    phase = np.arange(2 * steps, dtype=float)
    phase[:steps] += _GAUSS[0]
    phase[steps:] += _GAUSS[1] - steps
    phase *= 2.0 * np.pi / steps
    out = (phase, np.cos(phase), np.sin(phase))
    for a in out:
        a.flags.writeable = False
    return out


def _input_groups(inputs, divisors) -> tuple:
    """(codes (B,), [(input, divisor)] per code): items with the same waveform
    (:meth:`PeriodicInput.waveform_key`; an input without one is its own) and divisor share a code, so
    that what depends on the waveform only is evaluated once per code."""
    codes = np.empty(len(inputs), dtype=np.int64)
    reps, index = [], {}
    for b, (inp, divisor) in enumerate(zip(inputs, divisors)):
        key = inp.waveform_key()
        key = (id(inp) if key is None else key, divisor)
        code = index.get(key)
        if code is None:
            code = index[key] = len(reps)
            reps.append((inp, divisor))
        codes[b] = code
    return codes, reps


def _squared_input_rows(groups: tuple, phases_for) -> np.ndarray:
    """u^2 (V^2) of each item of ``groups`` (:func:`_input_groups`) at the phases ``phases_for(divisor)``
    (rad), one row each, evaluated once per code."""
    codes, reps = groups
    return np.stack([inp.at_phase(phases_for(divisor)) ** 2 for inp, divisor in reps])[codes]


#: (input code, step count) pairs are coded as code * _STEPS_CODE + steps (step counts stay far below: at
#: most MAGNUS_MAX_STEPS times the continuation's location factor).
_STEPS_CODE = 1 << 24


def _compiled_monodromies(model: DEAModel, states: np.ndarray, periods_s: np.ndarray, steps: np.ndarray,
                          groups: tuple, scale: np.ndarray) -> np.ndarray:
    """Monodromies (B, 3, 3) by the compiled 4th-order Magnus scheme, one kernel call: solution b
    (collocation values ``states[b]`` over the response period ``periods_s[b]`` of its input in
    ``groups`` (:func:`_input_groups`)) in ``steps[b]`` steps. The input at the Gauss phases is
    evaluated once per distinct waveform, divisor and step count."""
    steps = np.asarray(steps, dtype=np.int64)
    codes, reps = groups
    pairs, inverse = np.unique(codes * _STEPS_CODE + steps, return_inverse=True)
    cos_parts, sin_parts, u2_parts = [], [], []
    for pair in pairs.tolist():
        inp, divisor = reps[pair // _STEPS_CODE]
        phase, cos_phase, sin_phase = _gauss_phases(pair % _STEPS_CODE)
        cos_parts.append(cos_phase)
        sin_parts.append(sin_phase)
        u2_parts.append(inp.at_phase(phase / divisor) ** 2)
    offsets = np.concatenate([[0], np.cumsum(2 * (pairs % _STEPS_CODE))[:-1]]).astype(np.int64)
    return hbm_kernels.monodromy_batch(
        np.ascontiguousarray(states, dtype=float), steps, np.asarray(periods_s, dtype=float) / steps,
        np.concatenate(cos_parts), np.concatenate(sin_parts), np.concatenate(u2_parts), offsets[inverse.ravel()],
        model.constants, np.asarray(scale, dtype=float))


def _mm3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Products of 3x3 matrices stored component-wise, shape (3, 3, ...)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


def _expm3(mats: np.ndarray) -> np.ndarray:
    """exp of component-wise 3x3 matrices (3, 3, ...) with norm <= ~1: the [6/6] Pade approximant
    (V - U)^-1 (V + U) of the compiled :func:`hbm_kernels._expm9` (same coefficients, same formulas)."""
    b0, b1, b2, b3, b4, b5, b6 = hbm_kernels.PADE6
    eye = np.zeros_like(mats)
    eye[0, 0] = eye[1, 1] = eye[2, 2] = 1.0
    x2 = _mm3(mats, mats)
    x4 = _mm3(x2, x2)
    x6 = _mm3(x4, x2)
    u = _mm3(mats, b3 * x2 + b5 * x4 + b1 * eye)
    v = b2 * x2 + b4 * x4 + b6 * x6 + b0 * eye
    q = v - u
    adj = np.empty_like(q)   # (V - U)^-1 by its adjugate
    for i in range(3):
        for j in range(3):
            r1, r2 = (j + 1) % 3, (j + 2) % 3
            c1, c2 = (i + 1) % 3, (i + 2) % 3
            adj[i, j] = q[r1, c1] * q[r2, c2] - q[r1, c2] * q[r2, c1]
    det = q[0, 0] * adj[0, 0] + q[0, 1] * adj[1, 0] + q[0, 2] * adj[2, 0]
    return _mm3(adj / det, v + u)


def _jacobian_stack(model: DEAModel, x: np.ndarray, u2: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """df/dx at many points as (K, 3, 3), in scaled state coordinates S^-1 A S (better balanced)."""
    rows = model.jacobian_u2(x[0], x[1], x[2], u2)
    a = np.empty((x.shape[1], 3, 3))
    for i in range(3):
        for j in range(3):
            a[:, i, j] = rows[i][j] * (scale[j] / scale[i])
    return a


#: Default Magnus step rule of :func:`monodromy_matrix`: h rho(A) <= MAGNUS_H_RHO, from MAGNUS_MIN_STEPS to
#: MAGNUS_MAX_STEPS steps per response period. Measured against single shooting (variational equations,
#: DOP853 at rtol 1e-10): |mu| to ~5e-6 next to the A2 resonance (4.7e-6 at 9.584 Hz, 1.4e-7 at 18.4 Hz),
#: the error falling as h^4.
MAGNUS_H_RHO, MAGNUS_MIN_STEPS, MAGNUS_MAX_STEPS = 0.5, 48, 8192


def _magnus_steps_for(rate, period_s):
    """The default Magnus step count(s) for spectral radius ``rate`` (1/s) over ``period_s`` (scalars or
    arrays)."""
    need = np.ceil(np.asarray(rate) * period_s / MAGNUS_H_RHO)
    return np.clip(need, MAGNUS_MIN_STEPS, MAGNUS_MAX_STEPS).astype(np.int64)


def magnus_steps(model: DEAModel, sol: PeriodicSolution, scale: np.ndarray | None = None) -> int:
    """The default number of Magnus steps of :func:`monodromy_matrix` for ``sol`` (see MAGNUS_H_RHO)."""
    m = sol.n_points
    scale = np.ones(3) if scale is None else np.asarray(scale, dtype=float)
    if hbm_kernels.enabled():
        u2_nodes = sol.periodic_input.at_phase((2.0 * np.pi / (m * sol.period_divisor)) * np.arange(m)) ** 2
        state = np.ascontiguousarray(sol.state, dtype=float)
        rate = float(hbm_kernels.max_spectral_radius(state[None], u2_nodes[None], model.constants, scale, 1)[0])
    else:
        u2_nodes = sol.periodic_input.at_phase(sol.phases / sol.period_divisor) ** 2
        a_nodes = _jacobian_stack(model, sol.state, u2_nodes, scale)
        rate = float(np.max(np.abs(np.linalg.eigvals(a_nodes))))
    return int(_magnus_steps_for(rate, sol.response_period_s))


def monodromy_matrix(model: DEAModel, sol: PeriodicSolution, steps: int | None = None,
                     scale: np.ndarray | None = None) -> np.ndarray:
    """Monodromy over the response period (4th-order Magnus), in scaled coordinates.

    The multipliers are invariant under the scaling. ``steps`` defaults to :func:`magnus_steps`
    (h rho(A) <= 0.5, rho the spectral radius along the orbit, at least 48).
    """
    m = sol.n_points
    period = sol.response_period_s
    omega_resp = 2.0 * np.pi / period
    if scale is None:
        scale = np.ones(3)
    fast = hbm_kernels.enabled()
    if fast:
        state = np.ascontiguousarray(sol.state, dtype=float)
        scale = np.asarray(scale, dtype=float)
    if steps is None:
        steps = magnus_steps(model, sol, scale)
    h = period / steps
    if fast:  # the same Gauss phases, 2 pi (k + g) / steps
        phase, cos_phase, sin_phase = _gauss_phases(steps)
        u2 = sol.periodic_input.at_phase(phase / sol.period_divisor) ** 2
        # (copies: the kernel is compiled for writeable arrays)
        return hbm_kernels.monodromy(state, np.array(cos_phase), np.array(sin_phase), u2, h, model.constants, scale)
    starts = np.arange(steps) * h
    t_gauss = np.concatenate([starts + _GAUSS[0] * h, starts + _GAUSS[1] * h])
    phase = omega_resp * t_gauss
    x = sol.state @ periodic_interpolation_matrix(m, phase).T
    u2 = sol.periodic_input.at_phase(phase / sol.period_divisor) ** 2
    a = _jacobian_stack(model, x, u2, scale)
    a1, a2 = a[:steps], a[steps:]
    omega_mag = 0.5 * h * (a1 + a2) + (math.sqrt(3.0) / 12.0) * h * h * (a2 @ a1 - a1 @ a2)
    mats = np.moveaxis(_expm3(np.moveaxis(omega_mag, 0, -1)), -1, 0)
    while mats.shape[0] > 1:  # ordered product: later steps multiply from the left
        if mats.shape[0] % 2:
            mats = np.concatenate([mats, np.eye(3)[None]], axis=0)
        mats = mats[1::2] @ mats[0::2]
    return mats[0]


def sorted_eigenvalues(mats: np.ndarray) -> np.ndarray:
    """Eigenvalues (B, 3) of monodromies (B, 3, 3), sorted by decreasing modulus: compiled
    (:func:`hbm_kernels.eigenvalues3`, ~1 us a matrix) or numpy's eigvals on the numpy path (the same to
    ~1e-11). Raises numpy.linalg.LinAlgError for matrices with NaN or inf, as eigvals does."""
    mats = np.asarray(mats, dtype=float)
    if hbm_kernels.enabled():
        if not np.all(np.isfinite(mats)):
            raise np.linalg.LinAlgError("Array must not contain infs or NaNs")
        return hbm_kernels.eigenvalues3(np.ascontiguousarray(mats))
    mu = np.linalg.eigvals(mats)
    return np.take_along_axis(mu, np.argsort(-np.abs(mu), axis=-1, kind="stable"), axis=-1)


def floquet_multipliers(model: DEAModel, sol: PeriodicSolution, steps: int | None = None,
                        scale: np.ndarray | None = None) -> np.ndarray:
    """Floquet multipliers over the response period, sorted by decreasing modulus."""
    return sorted_eigenvalues(monodromy_matrix(model, sol, steps, scale)[None])[0]


def half_period_view(sol: PeriodicSolution) -> PeriodicSolution:
    """A full-period solution that is T/2-periodic, seen over T/2 (divisor 2, even harmonics kept)."""
    n_half = max(1, (sol.n_points - 1) // 4)
    m_half = 2 * n_half + 1
    phases = np.pi * np.arange(m_half) / m_half   # phi / 2 for phi on the half-period grid
    state = sol.state @ periodic_interpolation_matrix(sol.n_points, phases).T
    return PeriodicSolution(
        frequency_Hz=sol.frequency_Hz, periodic_input=sol.periodic_input, state=state,
        period_divisor=2 * sol.period_divisor, n_harmonics=n_half, method=sol.method,
        iterations=sol.iterations, residual=sol.residual, wall_time_s=0.0,
    )


#: A full-period solution whose odd harmonics are below this fraction is the symmetric (T/2) orbit.
SYMMETRY_TOL = 1e-5


def attach_floquet(model: DEAModel, sol: PeriodicSolution, scale: np.ndarray | None = None) -> PeriodicSolution:
    """Set ``sol.multipliers`` (over its response period) and, for a full-period solution that is
    the symmetric T/2 orbit of a T/2-periodic u^2, ``sol.half_period_multipliers`` (over T/2).

    Over T a multiplier mu of the half-period map appears squared: the period-doubling
    multiplier -1.05 becomes +1.10 and would read as a saddle; judged over T/2 it is named
    for what it is (``unstable (period-doubling)``).
    """
    sol.multipliers = floquet_multipliers(model, sol, scale=scale)
    sol.half_period_multipliers = None
    if _symmetric_full_period(sol):
        sol.half_period_multipliers = floquet_multipliers(model, half_period_view(sol), scale=scale)
    return sol


def _symmetric_full_period(sol: PeriodicSolution) -> bool:
    """A full-period solution that is the symmetric T/2 orbit of a T/2-periodic u^2 (see attach_floquet)."""
    return bool(sol.period_divisor == 1 and sol.n_points >= 5 and sol.periodic_input.u2_half_periodic()
                and sol.odd_harmonic_ratio() < SYMMETRY_TOL)


def _attach_floquet_all(model: DEAModel, sols: list, scale: np.ndarray) -> None:
    """:func:`attach_floquet` on many solutions, the eigenvalues in one stacked call (same results)."""
    if not sols:
        return
    # step counts as magnus_steps chooses them, all solutions at once
    scale = np.asarray(scale, dtype=float)
    states = np.stack([sol.state for sol in sols])
    m = states.shape[2]
    groups = _input_groups([sol.periodic_input for sol in sols], [sol.period_divisor for sol in sols])
    u2_nodes = _squared_input_rows(groups, lambda divisor: (2.0 * np.pi / (m * divisor)) * np.arange(m))
    rates = hbm_kernels.max_spectral_radius(states, u2_nodes, model.constants, scale, 1)
    periods = np.array([sol.response_period_s for sol in sols])
    mats = _compiled_monodromies(model, states, periods, _magnus_steps_for(rates, periods), groups, scale)
    mu = sorted_eigenvalues(mats)
    for sol, mu_k in zip(sols, mu):
        sol.multipliers = mu_k
        sol.half_period_multipliers = None
        if _symmetric_full_period(sol):
            sol.half_period_multipliers = floquet_multipliers(model, half_period_view(sol), scale=scale)


def floquet_multipliers_batch(model: DEAModel, states, response_periods_s, periodic_input: PeriodicInput,
                              divisor: int, scale: np.ndarray | None = None, h_rho: float = 1.0,
                              min_steps: int = 16) -> np.ndarray:
    """Floquet multipliers of many solutions of one waveform at once: (B, 3), decreasing modulus.

    ``states`` (B, 3, M) are collocation values over the response periods ``response_periods_s``
    (B,) of ``periodic_input`` seen with ``divisor``. Same 4th-order Magnus scheme as
    :func:`monodromy_matrix`, coarser by default (h rho(A) <= 1, at least 16 steps, rounded up
    to one of 8 counts per octave, at most 12.5 % more, so solutions share the quadrature points
    and the numpy path processes them in stacks):
    multipliers to ~1e-5, enough to detect where stability changes (the continuation then
    locates those points with :func:`floquet_multipliers`).
    """
    x_all = np.asarray(states, float)
    periods = np.asarray(response_periods_s, float).reshape(-1)
    nb, _, m = x_all.shape
    if scale is None:
        scale = np.ones(3)
    out = np.empty((nb, 3), dtype=complex)
    if nb == 0:
        return out
    node_phase = 2.0 * np.pi * np.arange(m) / m
    u2_nodes = periodic_input.at_phase(node_phase / divisor) ** 2
    fast = hbm_kernels.enabled()
    if fast:
        scale = np.asarray(scale, dtype=float)
        x_all = np.ascontiguousarray(x_all)
        rate = hbm_kernels.max_spectral_radius(x_all, np.broadcast_to(u2_nodes, (nb, m)), model.constants, scale, 3)
    else:
        rows = model.jacobian_u2(x_all[:, 0], x_all[:, 1], x_all[:, 2], u2_nodes[None, :])
        a_nodes = np.empty((nb, m, 3, 3))
        for i in range(3):
            for j in range(3):
                a_nodes[:, :, i, j] = rows[i][j] * (scale[j] / scale[i])
        rate = np.max(np.abs(np.linalg.eigvals(a_nodes[:, ::3])), axis=(1, 2))  # rho(A) along the orbit
    need = np.clip(np.ceil(rate * periods / h_rho), min_steps, 8192)
    quantum = 2.0 ** np.maximum(np.floor(np.log2(need)) - 3, 0)       # 8 step counts per octave
    steps_of = (np.ceil(need / quantum) * quantum).astype(int)
    if fast:
        one_group = (np.zeros(nb, dtype=np.int64), [(periodic_input, divisor)])
        mats = _compiled_monodromies(model, x_all, periods, steps_of, one_group, scale)
        return sorted_eigenvalues(mats)
    for steps in np.unique(steps_of):
        idx = np.nonzero(steps_of == steps)[0]
        frac = np.arange(steps) / steps
        phase = 2.0 * np.pi * np.concatenate([frac + _GAUSS[0] / steps, frac + _GAUSS[1] / steps])
        pmat = periodic_interpolation_matrix(m, phase)                     # (2S, M)
        x = x_all[idx] @ pmat.T                                            # (b, 3, 2S)
        u2 = periodic_input.at_phase(phase / divisor) ** 2
        jr = model.jacobian_u2(x[:, 0], x[:, 1], x[:, 2], u2[None, :])
        h = (periods[idx] / steps)[:, None]
        # component layout (3, 3, b, S): element-wise 3x3 products are ~15x faster than stacked matmul
        a1 = np.empty((3, 3, idx.size, steps))
        a2 = np.empty((3, 3, idx.size, steps))
        for i in range(3):
            for j in range(3):
                aij = np.broadcast_to(jr[i][j], (idx.size, 2 * steps)) * (h * (scale[j] / scale[i]))
                a1[i, j] = aij[:, :steps]
                a2[i, j] = aij[:, steps:]
        omega_mag = 0.5 * (a1 + a2) + (math.sqrt(3.0) / 12.0) * (_mm3(a2, a1) - _mm3(a1, a2))
        mats = _expm3(omega_mag)
        while mats.shape[3] > 1:  # ordered product: later steps multiply from the left
            if mats.shape[3] % 2:
                pad = np.zeros((3, 3, mats.shape[2], 1))
                pad[0, 0] = pad[1, 1] = pad[2, 2] = 1.0
                mats = np.concatenate([mats, pad], axis=3)
            mats = _mm3(mats[:, :, :, 1::2], mats[:, :, :, 0::2])
        out[idx] = sorted_eigenvalues(np.transpose(mats[:, :, :, 0], (2, 0, 1)))
    return out


__all__ += ["newton_error", "resample_state", "truncation_ratios", "monodromy_matrix", "magnus_steps",
            "sorted_eigenvalues",
            "MAGNUS_H_RHO", "MAGNUS_MIN_STEPS", "MAGNUS_MAX_STEPS", "linear_guess", "response_layout",
            "half_period_view", "SYMMETRY_TOL"]


def _linear_guess_batch(setup: ModelSetup, u2: np.ndarray, omega: np.ndarray, m: int) -> np.ndarray:
    """Vectorised :func:`linear_guess` for a batch (B, M) of u^2 waveforms at angular frequencies omega."""
    model = setup.model
    u2_mean = np.mean(u2, axis=1)
    x_eq = np.empty((u2.shape[0], 3))
    for value in np.unique(u2_mean):  # one equilibrium per distinct mean (one for equal amplitudes)
        x_eq[u2_mean == value] = setup.equilibrium_state(float(value))
    _f, rows = model.rhs_and_jacobian_u2(x_eq[:, 0], x_eq[:, 1], x_eq[:, 2], u2_mean)
    a = np.empty((u2.shape[0], 3, 3))
    for i in range(3):
        for j in range(3):
            a[:, i, j] = rows[i][j]
    b3 = model.input_gain_u2(x_eq[:, 0])
    w = np.fft.fft(u2 - u2_mean[:, None], axis=1)                      # (B, M)
    n = np.fft.fftfreq(m, 1.0 / m)
    lhs = 1j * (omega[:, None] * n[None, :])[..., None, None] * np.eye(3) - a[:, None]
    rhs = np.zeros((u2.shape[0], m, 3, 1), dtype=complex)
    rhs[:, :, 2, 0] = b3[:, None] * w
    dx = np.linalg.solve(lhs, rhs)[..., 0]                               # (B, M, 3)
    return x_eq[:, :, None] + np.real(np.fft.ifft(np.swapaxes(dx, 1, 2), axis=2))


def solve_native_batch(
    params: MembraneParameters,
    periodic_inputs,
    n_harmonics: int = 8,
    x_guesses=None,
    tol: float = 1e-10,
    max_iter: int = 40,
    use_symmetry: bool = True,
    stability: bool = False,
) -> list[PeriodicSolution]:
    """Solve many periodic inputs (e.g. a list of frequencies) in one stacked Newton iteration.

    All inputs must share the symmetry (all sines without offset, or none).
    The linear algebra runs on (B, 3M, 3M) stacks, so the Python overhead is
    paid once for the batch: this is the fast path for identification, where
    every objective evaluation needs the RMS at several frequencies. An item
    that does not converge is re-solved alone with :func:`solve_native` (with
    its fallbacks); errors propagate as :class:`HarmonicBalanceError`.
    """
    t0 = time.perf_counter()
    inputs = list(periodic_inputs)
    if not inputs:
        return []
    setup = model_setup(params)
    layouts = {response_layout(inp, n_harmonics, use_symmetry) for inp in inputs}
    if len(layouts) != 1:
        raise ValueError("periodic_inputs: mix of symmetric and non-symmetric inputs; batch them separately")
    divisor, m = layouts.pop()
    system = setup.system(m)
    nb = len(inputs)
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = _squared_input_rows(_input_groups(inputs, [divisor] * nb), lambda div: phases / div)   # (B, M)
    omega = np.array([inp.omega * divisor for inp in inputs])                       # (B,)
    if x_guesses is None:
        x0 = None if hbm_kernels.enabled() else _linear_guess_batch(setup, u2, omega, m)
    else:
        x0 = np.stack([g if np.shape(g) == (3, m) else resample_state(np.asarray(g, float), m)
                       for g in x_guesses])
    if hbm_kernels.enabled():
        return _solve_batch_compiled(params, setup, system, inputs, n_harmonics, divisor, m, u2, omega, x0, tol,
                                     max_iter, use_symmetry, stability, t0)
    z = x0 / system.scale[None, :, None]                                            # (B, 3, M)
    dmat_t = system.d_theta.T
    res_scale = system.res_scale[None]                                               # (1, 3, 1)
    block_scale = np.broadcast_to(system.block_scale, (3, 3, m)).reshape(-1)
    n = 3 * m

    def evaluate(zb, idx, want_jac=True):
        x = zb * system.scale[None, :, None]
        f, a = setup.model.rhs_and_jacobian_u2(x[:, 0], x[:, 1], x[:, 2], u2[idx])
        r = omega[idx, None, None] * (x @ dmat_t) - np.stack(f, axis=1)
        r = (r * res_scale).reshape(len(idx), n)
        if not want_jac:
            return r, None
        blocks = np.empty((len(idx), 3, 3, m))
        for i in range(3):
            for j in range(3):
                blocks[:, i, j] = a[i][j]
        jac = (omega[idx, None, None] / system.rate_ref) * system.kron_d[None]
        flat = jac.reshape(len(idx), -1)
        flat[:, system.block_index] -= blocks.reshape(len(idx), -1) * block_scale[None]
        return r, jac

    active = np.arange(nb)
    iterations = np.zeros(nb, dtype=int)
    residual = np.full(nb, np.inf)
    zf = z.reshape(nb, n).copy()
    r, jac = evaluate(z, active)
    rnorm = np.max(np.abs(r), axis=1)
    failed = np.zeros(nb, dtype=bool)
    for _ in range(max_iter):
        if active.size == 0:
            break
        try:
            step = np.linalg.solve(jac, r[..., None])[..., 0]
        except np.linalg.LinAlgError:
            failed[active] = True
            break
        snorm = np.max(np.abs(step), axis=1)
        lam = np.ones(active.size)
        z_cur = zf[active]
        accepted = np.zeros(active.size, dtype=bool)
        r_new = np.empty_like(r)
        jac_new = np.empty_like(jac)
        rn_new = np.empty(active.size)
        for _ls in range(12):
            todo = ~accepted
            trial = z_cur[todo] - lam[todo, None] * step[todo]
            rt, jt = evaluate(trial.reshape(-1, 3, m), active[todo])
            rnt = np.max(np.abs(rt), axis=1)
            ok = np.isfinite(rnt) & ((rnt < rnorm[todo]) | (rnt < 1e-13) | (lam[todo] * snorm[todo] < tol))
            idx_todo = np.nonzero(todo)[0]
            good = idx_todo[ok]
            z_cur[good] = trial[ok]
            r_new[good], jac_new[good], rn_new[good] = rt[ok], jt[ok], rnt[ok]
            accepted[good] = True
            lam[idx_todo[~ok]] *= 0.5
            if accepted.all():
                break
        iterations[active] += 1
        zf[active] = z_cur
        failed[active[~accepted]] = True
        done = accepted & (lam == 1.0) & (snorm <= tol)
        residual[active[accepted]] = rn_new[accepted]
        keep = accepted & ~done
        active, r, jac, rnorm = active[keep], r_new[keep], jac_new[keep], rn_new[keep]
    failed[active] = True  # out of iterations
    return _batch_results(params, setup, system, inputs, n_harmonics, divisor, zf, iterations, residual, failed,
                          tol, max_iter, use_symmetry, stability, t0)


def _solve_batch_compiled(params, setup, system, inputs, n_harmonics, divisor, m, u2, omega, x0, tol, max_iter,
                          use_symmetry, stability, t0):
    """:func:`solve_native_batch` with the compiled kernel: the same Newton iteration item by item."""
    nb = len(inputs)
    u2_mean = np.mean(u2, axis=1)
    if x0 is None:
        x_eq = np.empty((nb, 3))
        for value in np.unique(u2_mean):  # one equilibrium per distinct mean (one for equal amplitudes)
            x_eq[u2_mean == value] = setup.equilibrium_state(float(value))
        b3 = np.asarray(setup.model.input_gain_u2(x_eq[:, 0]), dtype=float)
        z0 = np.empty((0, 3 * m))
    else:
        x_eq, b3 = np.empty((0, 3)), np.empty(0)
        z0 = np.ascontiguousarray((x0 / system.scale[None, :, None]).reshape(nb, 3 * m))
    zf, iterations, residual, status = hbm_kernels.solve_batch(
        z0, x_eq, b3, np.ascontiguousarray(u2), u2_mean, np.asarray(omega, dtype=float), system.constants,
        system.scale, system.rate_ref, system.d_theta, float(tol), int(max_iter))
    return _batch_results(params, setup, system, inputs, n_harmonics, divisor, zf, iterations, residual,
                          status != 0, tol, max_iter, use_symmetry, stability, t0)


def _batch_results(params, setup, system, inputs, n_harmonics, divisor, zf, iterations, residual, failed, tol,
                   max_iter, use_symmetry, stability, t0):
    """Solutions of a batch (failed items re-solved alone), with stability on request."""
    nb = len(inputs)
    m = system.m
    states = np.asarray(zf).reshape(nb, 3, m) * system.scale[None, :, None]
    iterations, residual = np.asarray(iterations).tolist(), np.asarray(residual, dtype=float).tolist()
    results = []
    for k, inp in enumerate(inputs):
        if failed[k]:
            sol = solve_native(params, inp, n_harmonics, tol=tol, max_iter=max_iter,
                               use_symmetry=use_symmetry, stability=False)
        else:
            sol = PeriodicSolution(
                frequency_Hz=inp.frequency_Hz, periodic_input=inp, state=states[k], period_divisor=divisor,
                n_harmonics=int(n_harmonics), method="native-batch", iterations=int(iterations[k]),
                residual=float(residual[k]), wall_time_s=0.0,
            )
        results.append(sol)
    if stability:
        if hbm_kernels.enabled():
            _attach_floquet_all(setup.model, results, setup.scale)
        else:
            for sol in results:
                attach_floquet(setup.model, sol, scale=setup.scale)
    wall = time.perf_counter() - t0
    for sol in results:
        sol.extra["batch_wall_time_s"] = wall
        sol.wall_time_s = wall / nb
    return results


__all__ += ["solve_native_batch", "AUTO_HARMONICS"]
