"""Branch switching at period doubling, and the response a measurement realises at each frequency.

Branch switching. At a period-doubling point of the T/2 branch the full-period collocation
Jacobian (2N harmonics of f, the same spectral reach) is singular along an odd-harmonic vector,
the critical Floquet vector of multiplier -1 seen over T. The period-doubled branch ``"T"``
leaves the T/2 orbit along it (a pitchfork in the full-period equations) and is continued like any
branch until it returns to the T/2 branch (its odd harmonics change sign) or leaves the frequency
range (:func:`period_doubled_branches`).

The realised response (:func:`realised_responses`). For every requested frequency the stable
solutions of all branches are collected: one gives its kind (``periodic`` on T/2,
``period-doubled`` on T), several are ``coexisting`` (which one the rig shows depends on its
history; the sweep reports the one a slow upward sweep stays on, the others as alternatives), none
means no stable periodic response: the motion is integrated
(:func:`~dea_ros.solvers.realised.realised_response`) and reported as ``quasi-periodic`` with its
window-mean RMS and min/max envelope.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import ContinuationError, HarmonicBalanceError
from .branch_analysis import analyse_branch, make_branch
from .branch_tracer import BranchTracer
from .collocation import periodic_interpolation_matrix
from .realised import realised_response
from .sweep_results import PRIMARY, Response

__all__ = ["odd_projector", "period_doubled_start", "period_doubled_branches", "realised_responses"]


# --------------------------------------------------------------------------- switching
def odd_projector(m: int) -> np.ndarray:
    """Real M x M matrix keeping the odd harmonics of m equispaced samples over the period."""
    k = np.fft.fftfreq(m, 1.0 / m)
    mask = (np.abs(np.round(k)) % 2 == 1).astype(float)
    f = np.fft.fft(np.eye(m), axis=0)
    return np.real(np.fft.ifft(mask[:, None] * f, axis=0))


@functools.lru_cache(maxsize=16)
def _odd_basis(m: int) -> np.ndarray:
    """Orthonormal basis (3M, K) of the odd-harmonic subspace of the 3 states on m points (read-only)."""
    w, v = np.linalg.eigh(np.kron(np.eye(3), odd_projector(m)))
    basis = np.ascontiguousarray(v[:, w > 0.5])
    basis.flags.writeable = False
    return basis


def period_doubled_start(half: BranchTracer, full: BranchTracer, z_half, p_half):
    """(z, p, null vector) on the full-period grid at a period-doubling point of the T/2 branch."""
    m2, m1 = half.m, full.m
    x_half = half.system.unscale(z_half)
    theta = 2.0 * np.pi * np.arange(m1) / m1
    x_full = x_half @ periodic_interpolation_matrix(m2, np.mod(2.0 * theta, 2.0 * np.pi)).T
    z_full = full.system.to_z(x_full)
    p_full = p_half - math.log(2.0)
    _r, jac = full.system.residual_and_jacobian(z_full, math.exp(p_full), full.u2)
    basis = _odd_basis(m1)
    _u, _s, vt = np.linalg.svd(jac @ basis)
    phi = basis @ vt[-1]
    return z_full, p_full, phi


def period_doubled_branches(setup, prim: BranchTracer, events: list, periodic_input, n_harmonics: int, tol: float,
                            h_max: float, p_grid: np.ndarray, d0, stability: bool, max_branch_steps: int) -> tuple:
    """The period-doubled branches that start at the period-doubling ``events`` of the T/2 branch traced by
    ``prim`` (one branch per pair of period-doubling points it connects): (branches, branch steps)."""
    pd_events = [e for e in events if e["kind"] == "period-doubling"]
    visited = [False] * len(pd_events)
    m_full = 2 * (2 * n_harmonics) + 1
    p_grid_full = p_grid - math.log(2.0)
    full = BranchTracer(setup, periodic_input, 1, m_full, tol, h_max, p_grid_full, odd_projector(m_full))
    branches, steps = [], 0
    for i, ev in enumerate(pd_events):
        if visited[i]:
            continue
        visited[i] = True
        try:
            z1, p1, phi = period_doubled_start(prim, full, ev["z"], ev["p"])
            norm = math.sqrt(full.inner(phi, 0.0, phi, 0.0))
            trf = full.trace(z1, p1, phi / norm, 0.0, p_lo=p_grid_full[0], p_hi=p_grid_full[-1],
                             max_steps=max_branch_steps, h0=min(0.02, h_max))
        except (ContinuationError, HarmonicBalanceError, np.linalg.LinAlgError):
            continue
        steps += trf.steps
        if trf.stopped:  # came back to the T/2 branch: at which period-doubling point?
            p_end = float(trf.p[-1]) + math.log(2.0)
            for j, ev2 in enumerate(pd_events):
                if not visited[j] and abs(ev2["p"] - p_end) < 5e-3:
                    visited[j] = True
        name = "T" if not branches else f"T#{len(branches) + 1}"
        anf = analyse_branch(full, trf, d0, name, stability, ignore_ends=True)
        branches.append(make_branch(full, trf, anf, name, "period-doubled", d0, stability, 0.0))
    return branches, steps


def realised_responses(params, periodic_input, freqs, branches, ref, d0_static, stability, realised,
                       settle_periods, window_periods) -> list:
    """The realised response per requested frequency (module docstring)."""
    by_f: dict = {}
    pts_all = [pt for br in branches for pt in br.points]
    if pts_all:   # the nearest requested frequency of every point
        f_pts = np.array([pt.frequency_Hz for pt in pts_all])
        nearest = np.argmin(np.abs(freqs[None, :] - f_pts[:, None]), axis=1).tolist()
        for pt, g in zip(pts_all, nearest):
            by_f.setdefault(g, []).append(pt)
    out = []
    current = None       # (branch, segment) followed by the upward sweep
    last_value = None
    for g, f in enumerate(freqs):
        pts = by_f.get(g, [])
        stable = [p for p in pts if p.stable] if stability else [p for p in pts if p.branch == PRIMARY]
        if stable:
            same = [p for p in stable if (p.branch, p.segment) == current]
            if same:
                chosen = same[0]
            elif len(stable) == 1 or last_value is None:
                chosen = stable[0]
            else:
                chosen = min(stable, key=lambda p: abs(p.d_rms_m - last_value))
            current = (chosen.branch, chosen.segment)
            last_value = chosen.d_rms_m
            kinds = {("periodic" if p.branch == PRIMARY else "period-doubled") for p in stable}
            if len(stable) > 1:
                kind = "coexisting"
            else:
                kind = kinds.pop()
            vals = [p.d_rms_m for p in stable]
            alts = [{"branch": p.branch, "segment": p.segment, "d_rms_m": p.d_rms_m} for p in stable
                    if p is not chosen]
            out.append(Response(float(f), kind, chosen.d_rms_m, float(min(vals)), float(max(vals)),
                                chosen.branch, alts))
            continue
        current = None
        seed = min(pts, key=lambda p: p.max_multiplier) if pts else None
        if not realised or seed is None:
            nan = float("nan")
            val = seed.d_rms_m if seed is not None else nan
            out.append(Response(float(f), "quasi-periodic", nan, nan, nan, "none",
                                [{"branch": seed.branch, "d_rms_m": val, "stable": False}] if seed else [],
                                {"note": "not integrated (realised=False)"}))
            continue
        inp = periodic_input.with_frequency(float(f))
        x0 = seed.solution.evaluate(0.0)[:, 0]
        x0 = x0 + np.array([1e-3 * max(abs(x0[0]), 1e-6), 0.0, 0.0])   # leave the unstable orbit
        d0_ref = d0_static if ref is not None else float(seed.solution.mean_displacement_m)
        try:
            rr = realised_response(params, inp, x0, d0_ref, settle_periods, window_periods)
        except FloatingPointError as exc:
            nan = float("nan")
            out.append(Response(float(f), "quasi-periodic", nan, nan, nan, "integration", [],
                                {"error": str(exc)}))
            continue
        kind = "quasi-periodic" if rr.kind == "quasi-periodic" else (
            "period-doubled" if rr.kind == "period-doubled" else "periodic")
        last_value = rr.d_rms_m
        out.append(Response(float(f), kind, rr.d_rms_m, rr.d_rms_min_m, rr.d_rms_max_m, "integration",
                            [{"branch": p.branch, "d_rms_m": p.d_rms_m, "stable": False} for p in pts],
                            rr.to_dict()))
    return out
