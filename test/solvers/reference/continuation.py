"""numpy reference of the continuation loop (the former Python path of the tracer): dense bordered solves."""
import functools
import math

import numpy as np

from dea_ros.errors import ContinuationError, HarmonicBalanceError
from dea_ros.solvers.arclength_kernels import converges_below, hermite_seed

from .collocation import ReferenceSystem


class ReferenceTracer:
    """The continuation of a product BranchTracer's branch, step by step in Python with numpy."""

    def __init__(self, tracer):
        self.t = tracer
        self.n = tracer.n
        self.m = tracer.m
        self.wz = tracer.wz
        self.tol = tracer.tol
        self.h_max = tracer.h_max
        self.p_grid = tracer.p_grid
        self.u2 = tracer.u2
        self.system = ReferenceSystem(tracer.system)

    def inner(self, a_z, a_p, b_z, b_p):
        return self.wz * float(a_z @ b_z) + a_p * b_p

    def _bordered(self, z, p, tz, tp):
        omega = math.exp(p)
        sy = self.system
        r, jac = sy.residual_and_jacobian(z, omega, self.u2)
        dr = sy.d_residual_d_log_omega(z, omega)
        big = np.empty((self.n + 1, self.n + 1))
        big[:self.n, :self.n] = jac
        big[:self.n, self.n] = dr
        big[self.n, :self.n] = self.wz * tz
        big[self.n, self.n] = tp
        return r, big

    def _normalised(self, t):
        tz, tp = t[:self.n], t[self.n]
        norm = math.sqrt(self.inner(tz, tp, tz, tp))
        return tz / norm, tp / norm

    def _unit_tangent(self, big):
        rhs = np.zeros(self.n + 1)
        rhs[-1] = 1.0
        return self._normalised(np.linalg.solve(big, rhs))

    def tangent(self, z, p, prev_tz, prev_tp):
        _r, big = self._bordered(z, p, prev_tz, prev_tp)
        return self._unit_tangent(big)

    def correct(self, z_pred, p_pred, tz, tp, max_iter=12):
        zc, pc = z_pred.copy(), p_pred
        prev_snorm = 0.0
        for it in range(1, max_iter + 1):
            r, big = self._bordered(zc, pc, tz, tp)
            g = self.inner(tz, tp, zc - z_pred, pc - p_pred)
            try:
                step = np.linalg.solve(big, np.concatenate([r, [g]]))
            except np.linalg.LinAlgError:
                return None
            zc = zc - step[:self.n]
            pc = pc - step[self.n]
            snorm = float(np.max(np.abs(step)))
            if not np.isfinite(snorm) or snorm > 10.0:
                return None
            done = snorm < max(self.tol, 1e-9)
            if done or converges_below(snorm, prev_snorm, max(self.tol, 1e-9)):
                # within tol (or predicted: counted with the step it makes unneeded, as the compiled
                # corrector); the next tangent's matrix is this last one
                self.last_tangent = functools.partial(self._unit_tangent, big)
                return zc, pc, (it if done else it + 1)
            prev_snorm = snorm
        return None

    def tangent_from_last(self):
        """Unit tangent from the bordered system of the last converged corrector."""
        return self.last_tangent()

    def solve_at(self, p_target, z_seed):
        return self.system.newton(z_seed, math.exp(p_target), self.u2, tol=self.tol, max_iter=30)

    def excitation_Hz(self, p):
        return self.t.excitation_Hz(p)

    def odd_flipped(self, z_prev, z_new, odd_projector):
        a = (z_prev.reshape(3, self.m) @ odd_projector.T).reshape(-1)
        b = (z_new.reshape(3, self.m) @ odd_projector.T).reshape(-1)
        na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
        return na > 1e-6 * math.sqrt(self.n) and float(a @ b) < -0.5 * na * nb

    def trace(self, z, p, tz, tp, p_lo, p_hi, max_steps, odd_projector=None, h0=None):
        h = 0.5 * self.h_max if h0 is None else h0
        zs, ps, tzs, tps, hs = [z], [p], [tz], [tp], []
        grid = []     # (g, z, p, iterations, segment, step k, fraction)
        fold_steps = []
        segment = 0
        segs = [0]
        max_turn_cos = math.cos(math.radians(10.0))
        steps = 0
        stopped = False
        while steps < max_steps:
            if (p >= p_hi and tp > 0) or (p <= p_lo and tp < 0):
                break
            steps += 1
            corrected = self.correct(z + h * tz, p + h * tp, tz, tp)
            if corrected is None:
                h *= 0.5
                if h < 1e-7:
                    raise ContinuationError(
                        f"continuation step underflow near f = {self.excitation_Hz(p):.6g} Hz")
                continue
            z_new, p_new, iters = corrected
            tz_new, tp_new = self.tangent_from_last()
            # Reject steps that turn the tangent by more than ~10 degrees: a large step could
            # otherwise jump across a narrow S-shaped hysteresis loop.
            if self.inner(tz, tp, tz_new, tp_new) < max_turn_cos and h > 1e-6:
                h *= 0.5
                continue
            k = len(zs) - 1
            ds = self.inner(tz, tp, z_new - z, p_new - p)     # the step's arclength
            if p_new != p:
                lo, hi = min(p, p_new), max(p, p_new)
                if p_new > p:
                    crossed = np.nonzero((self.p_grid > lo) & (self.p_grid <= hi))[0]
                else:
                    crossed = np.nonzero((self.p_grid >= lo) & (self.p_grid < hi))[0][::-1]
                for g in crossed:
                    frac = (self.p_grid[g] - p) / (p_new - p)
                    seed = np.empty_like(z)
                    hermite_seed(z, tz, p, tp, z_new, tz_new, p_new, tp_new, ds, float(self.p_grid[g]),
                                 seed)
                    try:
                        zg, it_g, _ = self.solve_at(self.p_grid[g], seed)
                    except HarmonicBalanceError:
                        continue
                    grid.append((int(g), zg, float(self.p_grid[g]), it_g, segment, k, float(frac)))
            if np.sign(tp_new) != np.sign(tp) and tp != 0.0:
                fold_steps.append(k)
                segment += 1
            hs.append(ds)
            zs.append(z_new)
            ps.append(p_new)
            tzs.append(tz_new)
            tps.append(tp_new)
            segs.append(segment)
            if odd_projector is not None and self.odd_flipped(z, z_new, odd_projector):
                stopped = True
                z, p, tz, tp = z_new, p_new, tz_new, tp_new
                break
            z, p, tz, tp = z_new, p_new, tz_new, tp_new
            h = min(h * (1.5 if iters <= 3 else (1.0 if iters <= 5 else 0.6)), self.h_max)
        else:
            raise ContinuationError(f"more than {max_steps} branch steps; the branch may be closed")
        return {"z": np.array(zs), "p": np.array(ps), "tz": np.array(tzs), "tp": np.array(tps),
                "h": np.array(hs), "segment": np.array(segs), "grid": grid, "fold_steps": fold_steps,
                "steps": steps, "stopped": stopped}
