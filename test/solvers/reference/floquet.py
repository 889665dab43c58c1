"""numpy reference of the Floquet analysis (the former numpy path): Magnus monodromy, eigvals."""
import math

import numpy as np

from dea_ros.solvers.collocation import periodic_interpolation_matrix
from dea_ros.solvers.floquet import MAGNUS_H_RHO, MAGNUS_MAX_STEPS, MAGNUS_MIN_STEPS, half_period_view, \
    symmetric_full_period
from dea_ros.solvers.floquet_kernels import GAUSS_NODES, PADE6

_GAUSS = GAUSS_NODES


def _mm3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Products of 3x3 matrices stored component-wise, shape (3, 3, ...)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]
    return out


def _expm3(mats: np.ndarray) -> np.ndarray:
    """exp of component-wise 3x3 matrices (3, 3, ...) with norm <= ~1: the [6/6] Pade approximant
    (V - U)^-1 (V + U) of the compiled ``floquet_kernels._expm9`` (same coefficients, same formulas)."""
    b0, b1, b2, b3, b4, b5, b6 = PADE6
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


def _jacobian_stack(model, x: np.ndarray, u2: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """df/dx at many points as (K, 3, 3), in scaled state coordinates S^-1 A S (better balanced)."""
    rows = model.jacobian_u2(x[0], x[1], x[2], u2)
    a = np.empty((x.shape[1], 3, 3))
    for i in range(3):
        for j in range(3):
            a[:, i, j] = rows[i][j] * (scale[j] / scale[i])
    return a


def magnus_steps(model, sol, scale=None):
    scale = np.ones(3) if scale is None else np.asarray(scale, dtype=float)
    u2_nodes = sol.periodic_input.at_phase(sol.phases / sol.period_divisor) ** 2
    a_nodes = _jacobian_stack(model, sol.state, u2_nodes, scale)
    rate = float(np.max(np.abs(np.linalg.eigvals(a_nodes))))
    need = np.ceil(rate * sol.response_period_s / MAGNUS_H_RHO)
    return int(np.clip(need, MAGNUS_MIN_STEPS, MAGNUS_MAX_STEPS))


def monodromy_matrix(model, sol, steps=None, scale=None):
    """Monodromy over the response period (4th-order Magnus) with whole-array numpy."""
    m = sol.n_points
    period = sol.response_period_s
    omega_resp = 2.0 * np.pi / period
    if scale is None:
        scale = np.ones(3)
    if steps is None:
        steps = magnus_steps(model, sol, scale)
    h = period / steps
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


def sorted_eigenvalues(mats):
    """numpy's eigvals sorted by decreasing modulus."""
    mu = np.linalg.eigvals(np.asarray(mats, dtype=float))
    return np.take_along_axis(mu, np.argsort(-np.abs(mu), axis=-1, kind="stable"), axis=-1)


def floquet_multipliers(model, sol, steps=None, scale=None):
    return sorted_eigenvalues(monodromy_matrix(model, sol, steps, scale)[None])[0]


def attach_floquet(model, sol, scale=None):
    sol.multipliers = floquet_multipliers(model, sol, scale=scale)
    sol.half_period_multipliers = None
    if symmetric_full_period(sol):
        sol.half_period_multipliers = floquet_multipliers(model, half_period_view(sol), scale=scale)
    return sol


def floquet_multipliers_batch(model, states, response_periods_s, periodic_input,
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
    rows = model.jacobian_u2(x_all[:, 0], x_all[:, 1], x_all[:, 2], u2_nodes[None, :])
    a_nodes = np.empty((nb, m, 3, 3))
    for i in range(3):
        for j in range(3):
            a_nodes[:, :, i, j] = rows[i][j] * (scale[j] / scale[i])
    rate = np.max(np.abs(np.linalg.eigvals(a_nodes[:, ::3])), axis=(1, 2))  # rho(A) along the orbit
    need = np.clip(np.ceil(rate * periods / h_rho), min_steps, 8192)
    quantum = 2.0 ** np.maximum(np.floor(np.log2(need)) - 3, 0)       # 8 step counts per octave
    steps_of = (np.ceil(need / quantum) * quantum).astype(int)
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
