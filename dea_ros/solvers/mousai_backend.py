"""The paper's harmonic-balance solver: ``mousai.hb_time`` (first-order form, Newton-Krylov).

Kept to reproduce the paper's method and to compare against the native
solver. mousai evaluates the model one time point at a time through a Python
callback and needs a column vector back (shape (n, 1)); it solves on the full
excitation period with N harmonics of omega, as in the paper. The states are
scaled (d, eps1 and d' to O(1)) so that its absolute tolerance means the same
as the native solver's. ``mousai.hb_time`` has a mutable default ``params={}``;
we always pass a fresh dict.
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from ..errors import HarmonicBalanceError
from ..model.parameters import MembraneParameters
from .collocation import linear_guess, model_setup, resample_state
from .floquet import attach_floquet
from .inputs import PeriodicInput
from .periodic_solution import PeriodicSolution

__all__ = ["solve_mousai", "mousai_available"]


def mousai_available() -> bool:
    try:
        import mousai  # noqa: F401
    except Exception:  # noqa: BLE001
        return False
    return True


def solve_mousai(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    n_harmonics: int = 8,
    x_guess: np.ndarray | None = None,
    tol: float = 1e-9,
    max_iter: int = 200,
    stability: bool = True,
) -> PeriodicSolution:
    """Periodic steady state with ``mousai.hb_time`` (N harmonics of the excitation frequency).

    ``tol`` is the absolute tolerance on the scaled residual divided by the
    natural angular frequency (comparable to the native ``tol``).
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import matplotlib

            matplotlib.use("Agg", force=False)
            import mousai
    except Exception as exc:  # noqa: BLE001
        raise HarmonicBalanceError(f"mousai is not importable ({exc}); pip install mousai==0.3.1") from None
    if n_harmonics < 1:
        raise ValueError(f"n_harmonics: must be >= 1, got {n_harmonics}")
    t0 = time.perf_counter()
    setup = model_setup(params)
    model, scale = setup.model, setup.scale
    m = 2 * n_harmonics + 1
    omega = periodic_input.omega
    if x_guess is None:
        x_guess = linear_guess(params, periodic_input, 1, m, setup)
    elif np.shape(x_guess) != (3, m):
        x_guess = resample_state(np.asarray(x_guess, float), m)
    z0 = np.asarray(x_guess, float) / scale[:, None]
    counter = {"calls": 0}

    def sdfunc(z, p):
        counter["calls"] += 1
        u = periodic_input.at_phase(p["omega"] * p["cur_time"])
        x = z * scale
        f = model.rhs_u2(x[0], x[1], x[2], u * u)
        return np.array([[f[0] / scale[0]], [f[1] / scale[1]], [f[2] / scale[2]]])

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _t, z, e, _amps, _phases = mousai.hb_time(
                sdfunc, z0, omega=omega, num_harmonics=n_harmonics, eqform="first_order",
                params={}, f_tol=tol * setup.omega_n, maxiter=max_iter,
            )
    except Exception as exc:  # noqa: BLE001 - scipy.optimize.NoConvergence and friends
        raise HarmonicBalanceError(
            f"mousai.hb_time did not converge at f = {periodic_input.frequency_Hz:g} Hz "
            f"with N = {n_harmonics}: {type(exc).__name__}: {exc}"
        ) from None
    x = np.real(np.asarray(z)) * scale[:, None]
    sol = PeriodicSolution(
        frequency_Hz=periodic_input.frequency_Hz,
        periodic_input=periodic_input,
        state=x,
        period_divisor=1,
        n_harmonics=n_harmonics,
        method="mousai",
        iterations=counter["calls"],
        residual=float(np.max(np.abs(e))) / setup.omega_n,
        wall_time_s=0.0,
        extra={"rhs_calls": counter["calls"]},
    )
    if stability:
        attach_floquet(model, sol, scale=scale)
    sol.wall_time_s = time.perf_counter() - t0
    return sol
