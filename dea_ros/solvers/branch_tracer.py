"""One branch of the frequency response, followed by the arclength engine (:class:`BranchTracer`).

A branch is a family of periodic solutions of one waveform and period divisor, continued in
y = (z, p): z the scaled collocation values (:class:`~dea_ros.solvers.collocation.CollocationSystem`)
and p = ln(omega) of the response. :meth:`BranchTracer.trace` runs the compiled engine
(:func:`~dea_ros.solvers.arclength_kernels.trace_branch`, the problem
:class:`~dea_ros.solvers.sweep_kernels.CollocationBranch`) in one call and returns a
:class:`BranchTrace`; the tracer also gives the points between two branch steps (corrector from a
step), tangents and Floquet multipliers there, which the analysis of the branch
(:mod:`.branch_analysis`) needs to locate folds and bifurcations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..errors import ContinuationError
from . import arclength_kernels as engine
from .collocation import ModelSetup
from .floquet import floquet_multipliers, magnus_steps
from .inputs import PeriodicInput
from .periodic_solution import PeriodicSolution
from .sweep_kernels import bordered_corrector, bordered_tangent, collocation_branch

__all__ = ["GridPoint", "BranchTrace", "BranchTracer"]


class GridPoint(NamedTuple):
    """A solution at a requested frequency a branch step crossed."""

    index: int          # of the requested frequency
    z: np.ndarray       # scaled collocation values
    p: float            # ln omega of the response
    iterations: int     # Newton iterations of its solve
    segment: int        # branch segment (changes at every fold)
    step: int           # the branch step k it lies after
    fraction: float     # of the way in p from step k to k + 1


@dataclass
class BranchTrace:
    """A traced branch: points, unit tangents, step lengths, folds and the grid solutions."""

    z: np.ndarray               # (K + 1, n) branch points
    p: np.ndarray               # (K + 1,) ln omega
    tz: np.ndarray              # (K + 1, n) unit tangents
    tp: np.ndarray              # (K + 1,)
    h: np.ndarray               # (K,) arclength of each step
    segment: np.ndarray         # (K + 1,) segment of each point
    grid: list = field(default_factory=list)        # GridPoint
    fold_steps: list = field(default_factory=list)  # steps k after which the tangent's p-component changes sign
    steps: int = 0
    stopped: bool = False       # the branch turned back (period-doubled branch back at the T/2 orbit)


class BranchTracer:
    """Pseudo-arclength continuation of one family of periodic solutions (module docstring)."""

    def __init__(self, setup: ModelSetup, periodic_input: PeriodicInput, divisor: int, m: int, tol: float,
                 h_max: float, p_grid: np.ndarray, odd_projector: np.ndarray | None = None):
        self.setup = setup
        self.periodic_input = periodic_input
        self.divisor = divisor
        self.m = m
        self.n = 3 * m
        self.system = setup.system(m)
        phases = 2.0 * np.pi * np.arange(m) / m
        self.u2 = periodic_input.at_phase(phases / divisor) ** 2   # waveform in phase: any frequency
        self.tol = tol
        self.h_max = h_max
        self.p_grid = p_grid
        self.wz = 1.0 / self.n                                       # arclength norm: |dz|^2/n + dp^2
        sy = self.system
        self.problem = collocation_branch(self.u2, sy.constants, sy.scale, sy.rate_ref, sy.d_theta, odd_projector)

    def inner(self, a_z, a_p, b_z, b_p) -> float:
        """The arclength inner product wz a_z.b_z + a_p b_p."""
        return self.wz * float(a_z @ b_z) + a_p * b_p

    def _normalised(self, t):
        tz, tp = t[:self.n], t[self.n]
        norm = math.sqrt(self.inner(tz, tp, tz, tp))
        return tz / norm, tp / norm

    def tangent(self, z, p, prev_tz, prev_tp):
        """The unit tangent at (z, p), oriented by the previous one (bordered system, structured solve; the
        problem's own kernel with flat arguments: a call costs ~3 us less than through the engine's)."""
        sy = self.system
        t, ok = bordered_tangent(np.asarray(z, dtype=float), float(p), np.asarray(prev_tz, dtype=float),
                                 float(prev_tp), self.wz, self.u2, sy.constants, sy.scale, sy.rate_ref, sy.d_theta)
        if not ok:
            raise np.linalg.LinAlgError("Singular matrix")
        return self._normalised(t)

    def correct(self, z_pred, p_pred, tz, tp, max_iter: int = 12):
        """The corrector from a predicted point: (z, p, iterations), or None when it fails (the problem's own
        kernel, flat arguments)."""
        sy = self.system
        ok, zc, pc, it, _t = bordered_corrector(
            np.asarray(z_pred, dtype=float), float(p_pred), np.asarray(tz, dtype=float), float(tp), self.wz,
            self.u2, sy.constants, sy.scale, sy.rate_ref, sy.d_theta, float(self.tol), int(max_iter))
        return (zc, pc, it) if ok else None

    def solve_at(self, p_target, z_seed):
        """Newton at p = p_target from ``z_seed``: (z, iterations, scaled residual)."""
        return self.system.newton(z_seed, math.exp(p_target), self.u2, tol=self.tol, max_iter=30)

    def excitation_Hz(self, p) -> float:
        """The excitation frequency (Hz) of the response's ln omega p."""
        return math.exp(p) / self.divisor / (2.0 * np.pi)

    def solution(self, z, p, iterations: int = 0, state=None) -> PeriodicSolution:
        """The periodic solution at (z, p); ``state`` (3, M): z unscaled, when already at hand."""
        f_exc = self.excitation_Hz(p)
        return PeriodicSolution(
            frequency_Hz=f_exc, periodic_input=self.periodic_input.with_frequency(f_exc),
            state=self.system.unscale(z) if state is None else state, period_divisor=self.divisor,
            n_harmonics=(self.m - 1) // 2, method="native", iterations=iterations, residual=0.0, wall_time_s=0.0,
        )

    def multipliers(self, z, p, steps: int | None = None) -> np.ndarray:
        """Floquet multipliers at (z, p); ``steps`` Magnus steps (default: :func:`.floquet.magnus_steps`)."""
        return floquet_multipliers(self.setup.model, self.solution(z, p), steps=steps, scale=self.setup.scale)

    def magnus_steps(self, z, p) -> int:
        """The default Magnus step count at (z, p)."""
        return magnus_steps(self.setup.model, self.solution(z, p), scale=self.setup.scale)

    def trace(self, z, p, tz, tp, p_lo, p_hi, max_steps: int, h0=None) -> BranchTrace:
        """Follow the branch from (z, p) along (tz, tp) until it leaves [p_lo, p_hi] moving outwards, its
        odd-harmonic part turns back (with an odd projector), or ``max_steps`` (then
        :class:`~dea_ros.errors.ContinuationError`). Grid frequencies crossed are solved."""
        h = 0.5 * self.h_max if h0 is None else h0
        status, p_end, steps, stopped, zs, tzs, table, fold_steps, g_z, g_table = engine.trace_branch(
            self.problem, np.array(z, dtype=float), float(p), np.array(tz, dtype=float), float(tp), float(p_lo),
            float(p_hi), int(max_steps), float(h), float(self.h_max), np.asarray(self.p_grid, dtype=float), self.wz,
            float(self.tol))
        if status == engine.TRACE_STEP_UNDERFLOW:
            raise ContinuationError(f"continuation step underflow near f = {self.excitation_Hz(p_end):.6g} Hz")
        if status == engine.TRACE_MAX_STEPS:
            raise ContinuationError(f"more than {max_steps} branch steps; the branch may be closed")
        grid = [GridPoint(int(r[engine.GRID_INDEX]), g_z[j], r[engine.GRID_P], int(r[engine.GRID_ITERATIONS]),
                          int(r[engine.GRID_SEGMENT]), int(r[engine.GRID_STEP]), r[engine.GRID_FRACTION])
                for j, r in enumerate(g_table.tolist())]
        return BranchTrace(z=zs, p=table[:, engine.STEP_P], tz=tzs, tp=table[:, engine.STEP_TP],
                           h=table[:-1, engine.STEP_H], segment=table[:, engine.STEP_SEGMENT].astype(int), grid=grid,
                           fold_steps=fold_steps.tolist(), steps=int(steps), stopped=bool(stopped))

    def at(self, tr: BranchTrace, k: int, tau: float):
        """The branch point a fraction tau of the way from step k to k+1 (corrector from step k)."""
        if tau <= 0.0:
            return tr.z[k], float(tr.p[k])
        if tau >= 1.0:
            return tr.z[k + 1], float(tr.p[k + 1])
        h = tau * tr.h[k]
        z0, p0, tz, tp = tr.z[k], tr.p[k], tr.tz[k], tr.tp[k]
        res = self.correct(z0 + h * tz, p0 + h * tp, tz, tp)
        if res is None:  # straight interpolation, then Newton at its frequency
            zi = (1.0 - tau) * tr.z[k] + tau * tr.z[k + 1]
            pi = (1.0 - tau) * tr.p[k] + tau * tr.p[k + 1]
            zi, _it, _r = self.solve_at(pi, zi)
            return zi, float(pi)
        return res[0], float(res[1])
