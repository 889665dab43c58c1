"""numpy reference of the collocation system and Newton (the former numpy path of the harmonic balance)."""

import numpy as np

from dea_ros.errors import HarmonicBalanceError
from dea_ros.solvers.collocation import model_setup, response_layout
from dea_ros.solvers.periodic_solution import PeriodicSolution

from . import floquet as ref_floquet


class ReferenceSystem:
    """The collocation equations of a product CollocationSystem, evaluated with whole-array numpy."""

    def __init__(self, system):
        self.system = system
        self.model = system.model
        self.m = m = system.m
        self.d_theta = system.d_theta
        self.scale = system.scale
        self.rate_ref = system.rate_ref
        eye3 = np.eye(3)
        self.kron_d = np.kron(eye3, self.d_theta)
        i, l, k = np.meshgrid(np.arange(3), np.arange(3), np.arange(m), indexing="ij")
        self.block_index = ((i * m + k) * (3 * m) + (l * m + k)).reshape(-1)
        self.block_scale = (self.scale[None, :] / (self.scale[:, None] * self.rate_ref))[:, :, None]
        self.res_scale = (1.0 / (self.scale * self.rate_ref))[:, None]

    def unscale(self, z):
        return z.reshape(3, self.m) * self.scale[:, None]

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

    def d_residual_d_log_omega(self, z, omega):
        x = self.unscale(z)
        return (omega * (x @ self.d_theta.T) * self.res_scale).reshape(-1)

    def newton(self, z0, omega, u2, tol=1e-10, max_iter=40):
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


def linear_guess(params, periodic_input, divisor, m, setup) -> np.ndarray:
    """Periodic response of the model linearised about the static equilibrium at the mean of u^2."""
    model = setup.model
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = periodic_input.at_phase(phases / divisor) ** 2
    u2_mean = float(np.mean(u2))
    x_eq = setup.equilibrium_state(u2_mean)
    _f, rows = model.rhs_and_jacobian_u2(x_eq[0], x_eq[1], x_eq[2], u2_mean)
    a = np.array(rows, dtype=float)
    omega = periodic_input.omega * divisor
    b = np.array([0.0, 0.0, model.input_gain_u2(x_eq[0])])
    w = np.fft.fft(u2 - u2_mean)
    n = np.fft.fftfreq(m, 1.0 / m)
    lhs = 1j * n[:, None, None] * omega * np.eye(3)[None] - a[None]
    dx = np.linalg.solve(lhs, (b[None, :] * w[:, None])[..., None])[..., 0]
    return x_eq[:, None] + np.real(np.fft.ifft(dx.T, axis=1))


def _continue_up_in_frequency(params, system, periodic_input, divisor, m, f, tol, max_iter, setup):
    """Natural continuation from f/4 up to f (the step halves on failure), numpy Newton."""
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = periodic_input.at_phase(phases / divisor) ** 2
    f_cur = 0.25 * f
    start = periodic_input.with_frequency(f_cur)
    z = setup.system(m).to_z(linear_guess(params, start, divisor, m, setup))
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


def solve_native(params, periodic_input, n_harmonics=8, tol=1e-10, max_iter=40, use_symmetry=True, stability=True):
    """The product's solve_native (from the linearised guess, then the amplitude homotopy, then natural
    continuation from f/4) with numpy Newton and numpy Floquet."""
    setup = model_setup(params)
    divisor, m = response_layout(periodic_input, n_harmonics, use_symmetry)
    system = ReferenceSystem(setup.system(m))
    omega = periodic_input.omega * divisor
    u2 = periodic_input.at_phase(setup.system(m).phases / divisor) ** 2
    z0 = setup.system(m).to_z(linear_guess(params, periodic_input, divisor, m, setup))
    total_it = 0
    try:
        z, it, res = system.newton(z0, omega, u2, tol=tol, max_iter=max_iter)
        total_it += it
    except HarmonicBalanceError:
        z = None
        total_it += max_iter
    if z is None:
        mean_u2 = float(np.mean(u2))
        z = z0
        try:
            for frac in (0.25, 0.5, 0.75, 0.9, 1.0):
                z, it, res = system.newton(z, omega, mean_u2 + frac * (u2 - mean_u2), tol=tol, max_iter=max_iter)
                total_it += it
        except HarmonicBalanceError:
            z = None
    if z is None:
        z, it, res = _continue_up_in_frequency(params, system, periodic_input, divisor, m,
                                               periodic_input.frequency_Hz, tol, max_iter, setup)
        total_it += it
    sol = PeriodicSolution(frequency_Hz=periodic_input.frequency_Hz, periodic_input=periodic_input,
                           state=system.unscale(z), period_divisor=divisor, n_harmonics=int(n_harmonics),
                           method="native", iterations=total_it, residual=res, wall_time_s=0.0)
    if stability:
        ref_floquet.attach_floquet(setup.model, sol, scale=setup.scale)
    return sol
