"""Compiled kernels of the Floquet analysis: monodromy by the 4th-order Magnus scheme, 3x3 eigenvalues.

The monodromy of a periodic solution over its response period is the ordered product of
exp(Omega_k) over S steps, Omega_k the 4th-order Magnus expansion on the two Gauss points of step k
(A evaluated on the trigonometric interpolant of the collocation values), exp by the [6/6] Pade
approximant. The eigenvalues of the 3x3 monodromies (the Floquet multipliers) come from the
characteristic cubic (:func:`eigenvalues3`). All in the scaled coordinates S^-1 x (the multipliers
do not depend on the scaling).
"""
from __future__ import annotations

import math

import numpy as np

from ..model.dynamics import state_equation
from .collocation_kernels import state_equation_at
from .jit import jit, jit_inline

__all__ = [
    "GAUSS_NODES", "max_spectral_radius", "spectral_radius3", "eigenvalues3", "PADE6", "monodromy",
    "monodromy_batch",
]

_state_equation_inline = jit_inline(state_equation)   # the same f and df/dx, inlined in the vectorised Magnus loop


#: Gauss-Legendre nodes of the 2-point rule on [0, 1] (4th-order Magnus).
GAUSS_NODES = (0.5 - math.sqrt(3.0) / 6.0, 0.5 + math.sqrt(3.0) / 6.0)


@jit
def _scaled_jacobian(constants, d, e, v, u2, scale, h, out):
    """h S^-1 (df/dx) S at one point into out (3, 3)."""
    state_equation_at(constants, d, e, v, u2, out)
    for i in range(3):
        for j in range(3):
            out[i, j] *= h * scale[j] / scale[i]


@jit
def max_spectral_radius(states, u2_nodes, constants, scale, every):
    """Largest |eigenvalue| of S^-1 (df/dx) S over the nodes 0, every, 2 every, ... of each state.

    ``states`` (B, 3, M), ``u2_nodes`` (B, M); returns (B,) (the step control of the Magnus scheme).
    """
    nb, _three, m = states.shape
    out = np.empty(nb)
    a = np.empty((3, 3))
    for b in range(nb):
        best = 0.0
        for k in range(0, m, every):
            _scaled_jacobian(constants, states[b, 0, k], states[b, 1, k], states[b, 2, k], u2_nodes[b, k],
                             scale, 1.0, a)
            best = max(best, spectral_radius3(a))
        out[b] = best
    return out


@jit
def _cbrt(x):
    return math.copysign(abs(x) ** (1.0 / 3.0), x)


@jit
def _eigenvalues3(a):
    """The eigenvalues of a real 3x3 matrix ``a`` as three complex numbers (unsorted), as LAPACK's dgeev
    gives them: real ones with zero imaginary part, a complex pair exactly conjugate, + imaginary part
    first. From the characteristic cubic: one real root by Cardano / the trigonometric form, polished by
    Newton on the cubic, the other two from the deflated quadratic (measured on 1,741 monodromies of four
    sweeps: within 1.2e-11 of numpy's eigvals, 4e-12 for the largest modulus; clustered roots are the
    least accurate for both)."""
    tr = a[0, 0] + a[1, 1] + a[2, 2]
    minors = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0] + a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
              + a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    # lambda^3 + c2 lambda^2 + c1 lambda + c0
    c2, c1, c0 = -tr, minors, -det
    shift = -c2 / 3.0
    p = c1 - c2 * c2 / 3.0
    q = 2.0 * c2 ** 3 / 27.0 - c2 * c1 / 3.0 + c0
    disc = 0.25 * q * q + p * p * p / 27.0
    if disc > 0.0:
        sq = math.sqrt(disc)
        r = _cbrt(-0.5 * q + sq) + _cbrt(-0.5 * q - sq) + shift
    else:
        rr = math.sqrt(max(-p / 3.0, 0.0))
        if rr == 0.0:
            r = shift
        else:   # the largest of three real roots
            r = 2.0 * rr * math.cos(math.acos(min(1.0, max(-1.0, -0.5 * q / (rr * rr * rr)))) / 3.0) + shift
    for _ in range(3):
        f = ((r + c2) * r + c1) * r + c0
        df = (3.0 * r + 2.0 * c2) * r + c1
        if df == 0.0:
            break
        r -= f / df
    b = c2 + r             # the other two: x^2 + b x + c
    c = c1 + r * b
    half_disc = 0.25 * b * b - c
    if half_disc < 0.0:
        im = math.sqrt(-half_disc)
        return complex(-0.5 * b, im), complex(-0.5 * b, -im), complex(r, 0.0)
    x1 = -0.5 * b - math.copysign(math.sqrt(half_disc), b)
    return complex(x1, 0.0), complex(c / x1 if x1 != 0.0 else 0.0, 0.0), complex(r, 0.0)


@jit
def spectral_radius3(a):
    """max |eigenvalue| of a real 3x3 matrix (:func:`_eigenvalues3`)."""
    w0, w1, w2 = _eigenvalues3(a)
    return max(abs(w0), abs(w1), abs(w2))


@jit
def _eigenvalues3_into(a, out):
    """:func:`_eigenvalues3` into ``out`` (3,), sorted by decreasing modulus (stable: a pair keeps its
    + imaginary part first)."""
    out[0], out[1], out[2] = _eigenvalues3(a)
    for i in range(1, 3):
        j = i
        while j > 0 and abs(out[j]) > abs(out[j - 1]):
            t = out[j]
            out[j] = out[j - 1]
            out[j - 1] = t
            j -= 1


@jit
def eigenvalues3(mats):
    """Eigenvalues (B, 3) of real 3x3 matrices (B, 3, 3), sorted by decreasing modulus
    (:func:`_eigenvalues3_into`)."""
    out = np.empty((mats.shape[0], 3), dtype=np.complex128)
    for b in range(mats.shape[0]):
        _eigenvalues3_into(mats[b], out[b])
    return out


@jit_inline
def _t9(a0, a1, a2, a3, a4, a5, a6, a7, a8):
    return (a0, a1, a2, a3, a4, a5, a6, a7, a8)


@jit_inline
def _mul9(a, b):
    """Product of 3x3 matrices held as row-major 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (a0 * b0 + a1 * b3 + a2 * b6, a0 * b1 + a1 * b4 + a2 * b7, a0 * b2 + a1 * b5 + a2 * b8,
            a3 * b0 + a4 * b3 + a5 * b6, a3 * b1 + a4 * b4 + a5 * b7, a3 * b2 + a4 * b5 + a5 * b8,
            a6 * b0 + a7 * b3 + a8 * b6, a6 * b1 + a7 * b4 + a8 * b7, a6 * b2 + a7 * b5 + a8 * b8)


@jit_inline
def _lin9(alpha, a, beta, b):
    """alpha a + beta b for 9-tuples."""
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = a
    b0, b1, b2, b3, b4, b5, b6, b7, b8 = b
    return (alpha * a0 + beta * b0, alpha * a1 + beta * b1, alpha * a2 + beta * b2,
            alpha * a3 + beta * b3, alpha * a4 + beta * b4, alpha * a5 + beta * b5,
            alpha * a6 + beta * b6, alpha * a7 + beta * b7, alpha * a8 + beta * b8)


#: Coefficients b_k of the [6/6] Pade approximant of exp: p(x) = sum b_k x^k, exp(x) ~ p(x) / p(-x).
PADE6 = (1.0, 1.0 / 2.0, 5.0 / 44.0, 1.0 / 66.0, 1.0 / 792.0, 1.0 / 15840.0, 1.0 / 665280.0)


@jit_inline
def _expm9(x):
    """exp(x) of a 3x3 matrix (9-tuple) of norm <= ~1 by the [6/6] Pade approximant (V - U)^-1 (V + U),
    U = x (b1 + b3 x^2 + b5 x^4), V = b0 + b2 x^2 + b4 x^4 + b6 x^6. Relative error against
    scipy.linalg.expm: rounding at norm 0.5, ~2e-13 at norm 1 (the 12th-order Taylor polynomial used
    before: ~1e-10). Its numpy reference is in ``test/solvers/reference/floquet.py``."""
    b0, b1, b2, b3, b4, b5, b6 = PADE6
    x2 = _mul9(x, x)
    x4 = _mul9(x2, x2)
    x6 = _mul9(x4, x2)
    u_in = _lin9(b3, x2, b5, x4)
    u_in = (u_in[0] + b1, u_in[1], u_in[2], u_in[3], u_in[4] + b1, u_in[5], u_in[6], u_in[7], u_in[8] + b1)
    u = _mul9(x, u_in)
    v = _lin9(1.0, _lin9(b2, x2, b4, x4), b6, x6)
    v = (v[0] + b0, v[1], v[2], v[3], v[4] + b0, v[5], v[6], v[7], v[8] + b0)
    q0, q1, q2, q3, q4, q5, q6, q7, q8 = _lin9(1.0, v, -1.0, u)
    # (V - U)^-1 by its adjugate (V - U ~ I: well conditioned)
    c0 = q4 * q8 - q5 * q7
    c3 = q5 * q6 - q3 * q8
    c6 = q3 * q7 - q4 * q6
    inv_det = 1.0 / (q0 * c0 + q1 * c3 + q2 * c6)
    inv = (c0 * inv_det, (q2 * q7 - q1 * q8) * inv_det, (q1 * q5 - q2 * q4) * inv_det,
           c3 * inv_det, (q0 * q8 - q2 * q6) * inv_det, (q2 * q3 - q0 * q5) * inv_det,
           c6 * inv_det, (q1 * q6 - q0 * q7) * inv_det, (q0 * q4 - q1 * q3) * inv_det)
    return _mul9(inv, _lin9(1.0, v, 1.0, u))


@jit_inline
def _jac9(constants, d, e, v, u2, rt):
    """(df/dx)_ij rt_ij at one point as a 9-tuple (rt_ij = h scale_j / scale_i)."""
    _f, a = _state_equation_inline(constants, d, e, v, u2)
    (j0, j1, j2), (j3, j4, j5), (j6, j7, j8) = a
    return (j0 * rt[0], j1 * rt[1], j2 * rt[2], j3 * rt[3], j4 * rt[4], j5 * rt[5], j6 * rt[6], j7 * rt[7],
            j8 * rt[8])


@jit
def _gauss_point_states(state, cos_phases, sin_phases):
    """(3, P) values at the phases with cosines / sines ``cos_phases``, ``sin_phases`` (P,) of the
    trigonometric interpolant through the M collocation values ``state`` (3, M): mean + sum over the
    harmonics n of a_n cos(n theta) + b_n sin(n theta), cos / sin (n theta) by rotation (the loops over
    the points are innermost: they vectorise)."""
    m = state.shape[1]
    nh = (m - 1) // 2
    npt = cos_phases.shape[0]
    cos_table = np.empty(m)
    sin_table = np.empty(m)
    for j in range(m):
        cos_table[j] = math.cos(2.0 * math.pi * j / m)
        sin_table[j] = math.sin(2.0 * math.pi * j / m)
    coef = np.zeros((nh + 1, 6))   # per harmonic n: a_n of (d, eps1, v), then b_n
    w = 2.0 / m
    for n in range(1, nh + 1):
        j = 0                      # (n k) mod m
        for k in range(m):
            ck = cos_table[j] * w
            sk = sin_table[j] * w
            for i in range(3):
                coef[n, i] += state[i, k] * ck
                coef[n, 3 + i] += state[i, k] * sk
            j += n
            if j >= m:
                j -= m
    mean_d = 0.0
    mean_e = 0.0
    mean_v = 0.0
    for k in range(m):
        mean_d += state[0, k]
        mean_e += state[1, k]
        mean_v += state[2, k]
    out = np.empty((3, npt))
    d = out[0]
    e = out[1]
    v = out[2]
    for g in range(npt):
        d[g] = mean_d / m
        e[g] = mean_e / m
        v[g] = mean_v / m
    cn = cos_phases.copy()
    sn = sin_phases.copy()
    for n in range(1, nh + 1):
        a0, a1, a2, b0, b1, b2 = coef[n, 0], coef[n, 1], coef[n, 2], coef[n, 3], coef[n, 4], coef[n, 5]
        for g in range(npt):
            c = cn[g]
            s = sn[g]
            d[g] += a0 * c + b0 * s
            e[g] += a1 * c + b1 * s
            v[g] += a2 * c + b2 * s
            cn[g] = c * cos_phases[g] - s * sin_phases[g]
            sn[g] = s * cos_phases[g] + c * sin_phases[g]
    return out


@jit
def monodromy(state, cos_phases, sin_phases, u2, h, constants, scale):
    """Monodromy (3, 3) over one period by the 4th-order Magnus scheme, in scaled coordinates.

    ``cos_phases``, ``sin_phases`` (2S,) are the cosines and sines of the phases of the two Gauss
    points of the S steps (first points of all steps, then second points), ``u2`` the input squared
    there, ``h`` the step (s). The state is evaluated by its trigonometric interpolant through the M
    collocation values; exp(Omega) by the [6/6] Pade approximant (:func:`_expm9`).
    """
    steps = cos_phases.shape[0] // 2
    xg = _gauss_point_states(state, cos_phases, sin_phases)
    rt = _t9(h * scale[0] / scale[0], h * scale[1] / scale[0], h * scale[2] / scale[0],
             h * scale[0] / scale[1], h * scale[1] / scale[1], h * scale[2] / scale[1],
             h * scale[0] / scale[2], h * scale[1] / scale[2], h * scale[2] / scale[2])
    c3 = math.sqrt(3.0) / 12.0
    # exp(Omega_s) of all steps first (independent: this loop vectorises), then their ordered product
    ex = np.empty((9, steps))
    for s in range(steps):
        a1 = _jac9(constants, xg[0, s], xg[1, s], xg[2, s], u2[s], rt)
        q = s + steps
        a2 = _jac9(constants, xg[0, q], xg[1, q], xg[2, q], u2[q], rt)
        om = _lin9(0.5, _lin9(1.0, a1, 1.0, a2), c3, _lin9(1.0, _mul9(a2, a1), -1.0, _mul9(a1, a2)))
        e = _expm9(om)
        ex[0, s] = e[0]
        ex[1, s] = e[1]
        ex[2, s] = e[2]
        ex[3, s] = e[3]
        ex[4, s] = e[4]
        ex[5, s] = e[5]
        ex[6, s] = e[6]
        ex[7, s] = e[7]
        ex[8, s] = e[8]
    total = _t9(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    for s in range(steps):   # later steps multiply from the left
        total = _mul9(_t9(ex[0, s], ex[1, s], ex[2, s], ex[3, s], ex[4, s], ex[5, s], ex[6, s], ex[7, s], ex[8, s]),
                      total)
    out = np.empty((3, 3))
    out[0, 0], out[0, 1], out[0, 2], out[1, 0], out[1, 1], out[1, 2], out[2, 0], out[2, 1], out[2, 2] = total
    return out


@jit
def monodromy_batch(states, steps, h, cos_flat, sin_flat, u2_flat, start, constants, scale):
    """Monodromies (B, 3, 3) of many solutions in one call: :func:`monodromy` of item b with
    ``steps[b]`` steps of ``h[b]`` s, the cosines and sines of its Gauss phases and its input squared
    read from ``cos_flat`` / ``sin_flat`` / ``u2_flat`` at ``start[b]`` (2 steps[b] values: shared by
    items with the same waveform and step count)."""
    nb = states.shape[0]
    out = np.empty((nb, 3, 3))
    for b in range(nb):
        lo = start[b]
        hi = lo + 2 * steps[b]
        out[b] = monodromy(states[b], cos_flat[lo:hi], sin_flat[lo:hi], u2_flat[lo:hi], h[b], constants, scale)
    return out
