"""Frequency sweeps by pseudo-arclength continuation of the harmonic-balance solution.

The branch of periodic solutions y = (z, p), with z the scaled collocation
values and p = ln(omega), is followed by predictor (tangent) / corrector
(Newton on the collocation equations plus the arclength condition) steps with
adaptive step length, so turning points (folds, where the branch turns back in
frequency and the response jumps in an experiment) are passed, not stopped at.

Every requested frequency the branch crosses is solved exactly (Newton at fixed
frequency seeded from the two neighbouring branch points); inside a hysteresis
band the same frequency therefore appears once per branch segment (e.g. upper
stable, middle unstable, lower stable). Each reported point carries its Floquet
multipliers and stability. Folds are located where d(ln omega)/ds changes sign.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from .harmonic_balance import (
    HarmonicBalanceError,
    PeriodicSolution,
    _setup,
    classify_stability,
    floquet_multipliers,
    response_layout,
    solve_native,
)
from .inputs import PeriodicInput

__all__ = ["SweepPoint", "Fold", "SweepResult", "frequency_sweep", "ContinuationError"]


class ContinuationError(RuntimeError):
    """The continuation could not follow the branch (step size underflow)."""


@dataclass
class SweepPoint:
    """One periodic solution on the branch at a requested frequency."""

    frequency_Hz: float
    d_rms_m: float              # eq. 21 with the sweep's d0
    mean_displacement_m: float
    peak_to_peak_m: float
    stable: bool
    stability: str
    max_multiplier: float       # largest |Floquet multiplier| over the response period
    iterations: int
    wall_time_s: float
    segment: int                # branch segment index (changes at every fold)
    solution: PeriodicSolution = field(repr=False)

    @property
    def truncation_ratio(self) -> float:
        """See :attr:`PeriodicSolution.truncation_ratio` (NaN for a failed point)."""
        return self.solution.truncation_ratio if self.solution is not None else float("nan")

    def to_dict(self) -> dict:
        return {
            "frequency_Hz": self.frequency_Hz,
            "d_rms_m": self.d_rms_m,
            "mean_displacement_m": self.mean_displacement_m,
            "peak_to_peak_m": self.peak_to_peak_m,
            "stable": self.stable,
            "stability": self.stability,
            "max_multiplier": self.max_multiplier,
            "iterations": self.iterations,
            "wall_time_s": self.wall_time_s,
            "segment": self.segment,
            "truncation_ratio": self.truncation_ratio,
        }


@dataclass
class Fold:
    """A turning point of the branch (saddle-node): where the response jumps in a slow sweep."""

    frequency_Hz: float
    d_rms_m: float
    direction: str  # "forward->backward" (branch turns back to lower f) or the reverse


@dataclass
class SweepResult:
    points: list[SweepPoint]
    folds: list[Fold]
    d0_m: float
    d0_choice: str
    n_harmonics: int
    method: str
    wall_time_s: float
    branch_steps: int

    @property
    def frequencies_Hz(self) -> np.ndarray:
        return np.array([p.frequency_Hz for p in self.points])

    @property
    def d_rms_m(self) -> np.ndarray:
        return np.array([p.d_rms_m for p in self.points])

    @property
    def stable(self) -> np.ndarray:
        return np.array([p.stable for p in self.points])

    def resonance_peak(self, stable_only: bool = True) -> dict:
        """Frequency and d_rms of the largest response (parabolic refinement on the branch).

        With ``stable_only`` the peak of what a slow upward sweep in the lab
        would show (the largest stable response); otherwise the branch maximum
        (the tip near the fold).
        """
        pts = [p for p in self.points if p.stable or not stable_only]
        if not pts:
            return {"frequency_Hz": float("nan"), "d_rms_m": float("nan")}
        k = int(np.argmax([p.d_rms_m for p in pts]))
        f_peak, d_peak = pts[k].frequency_Hz, pts[k].d_rms_m
        if 0 < k < len(pts) - 1 and pts[k - 1].segment == pts[k].segment == pts[k + 1].segment:
            f = np.array([pts[k - 1].frequency_Hz, f_peak, pts[k + 1].frequency_Hz])
            d = np.array([pts[k - 1].d_rms_m, d_peak, pts[k + 1].d_rms_m])
            c = np.polyfit(f - f_peak, d, 2)
            if c[0] < 0:
                shift = -c[1] / (2 * c[0])
                if abs(shift) <= max(abs(f[2] - f[1]), abs(f[1] - f[0])):
                    f_peak = f_peak + shift
                    d_peak = float(np.polyval(c, shift))
        for fold in self.folds:  # the branch tip at a fold is a sharper estimate when larger
            if not stable_only and fold.d_rms_m > d_peak:
                f_peak, d_peak = fold.frequency_Hz, fold.d_rms_m
        return {"frequency_Hz": float(f_peak), "d_rms_m": float(d_peak)}

    @property
    def max_truncation_ratio(self) -> float:
        vals = [p.truncation_ratio for p in self.points if p.solution is not None]
        return float(max(vals)) if vals else float("nan")

    def to_dict(self) -> dict:
        return {
            "n_harmonics": self.n_harmonics,
            "max_truncation_ratio": self.max_truncation_ratio,
            "method": self.method,
            "d0_m": self.d0_m,
            "d0_choice": self.d0_choice,
            "wall_time_s": self.wall_time_s,
            "branch_steps": self.branch_steps,
            "resonance_peak": self.resonance_peak(True),
            "resonance_peak_branch": self.resonance_peak(False),
            "folds": [f.__dict__ for f in self.folds],
            "points": [p.to_dict() for p in self.points],
        }


def _d0(params: MembraneParameters, choice: str, sol: PeriodicSolution) -> float:
    if choice == "static":
        return float(static_equilibrium(params, 0.0).displacement_m)
    if choice == "mean":
        return sol.mean_displacement_m
    raise ValueError(f"d0: 'static' (equilibrium at u = 0, the paper's eq. 21) or 'mean', got {choice!r}")


def _sweep_point(sol: PeriodicSolution, d0_m: float, iterations: int, wall_time_s: float, segment: int,
                 stability: bool) -> SweepPoint:
    """A SweepPoint from a periodic solution (d_rms around d0_m, eq. 21)."""
    mu = np.abs(sol.multipliers) if sol.multipliers is not None else np.array([np.nan])
    return SweepPoint(
        frequency_Hz=float(sol.frequency_Hz),
        d_rms_m=sol.displacement_rms(d0_m),
        mean_displacement_m=sol.mean_displacement_m,
        peak_to_peak_m=float(np.ptp(sol.state[0])),
        stable=bool(sol.stable) if stability else True,
        stability=classify_stability(sol.multipliers),
        max_multiplier=float(np.max(mu)),
        iterations=iterations,
        wall_time_s=wall_time_s,
        segment=segment,
        solution=sol,
    )


def frequency_sweep(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    frequencies_Hz,
    n_harmonics: int = 8,
    d0: str = "static",
    use_symmetry: bool = True,
    tol: float = 1e-10,
    max_branch_steps: int = 20000,
    stability: bool = True,
) -> SweepResult:
    """Sweep the excitation frequency over ``frequencies_Hz`` (sorted ascending) by continuation.

    ``periodic_input`` fixes the waveform (e.g. ``SinePeriodic(2500, f)``);
    its frequency is replaced along the sweep. ``d0`` chooses the reference of
    eq. 21: ``"static"`` (static equilibrium at u = 0, the paper) or ``"mean"``
    (the mean of each response: then d_rms is the standard deviation).
    """
    t_start = time.perf_counter()
    freqs = np.unique(np.asarray(frequencies_Hz, dtype=float))
    if freqs.size < 1 or not np.all(np.isfinite(freqs)) or freqs[0] <= 0:
        raise ValueError("frequencies_Hz: need positive, finite frequencies")
    setup = _setup(params)
    model = setup.model
    first_input = periodic_input.with_frequency(freqs[0])
    divisor, m = response_layout(first_input, n_harmonics, use_symmetry)
    system = setup.system(m)
    phases = 2.0 * np.pi * np.arange(m) / m
    u2 = first_input.at_phase(phases / divisor) ** 2  # waveform in phase: frequency independent
    n = 3 * m
    d0_static = float(static_equilibrium(params, 0.0).displacement_m)

    # Starting point: a cold solve at the lowest frequency (quasi-static there).
    start = solve_native(params, first_input, n_harmonics, use_symmetry=use_symmetry,
                         stability=False, tol=tol)
    z = system.to_z(start.state)
    p = math.log(first_input.omega * divisor)
    p_grid = np.log(2.0 * np.pi * freqs * divisor)
    p_end = p_grid[-1]
    dp_grid = float(np.min(np.diff(p_grid))) if freqs.size > 1 else 0.1
    h_max = max(min(0.5 * (p_end - p) / 4.0 + 1e-3, 0.25), 1e-3)
    h_max = min(h_max, max(dp_grid, 0.02))
    h = 0.5 * h_max
    weight_z = 1.0 / n  # arclength norm: |dz|^2 / n + dp^2
    max_turn_cos = math.cos(math.radians(10.0))

    def inner(a_z, a_p, b_z, b_p):
        return weight_z * float(a_z @ b_z) + a_p * b_p

    def tangent(z_, p_, prev_tz, prev_tp):
        r, jac = system.residual_and_jacobian(z_, math.exp(p_), u2)
        rp = system.d_residual_d_log_omega(z_, math.exp(p_))
        big = np.zeros((n + 1, n + 1))
        big[:n, :n] = jac
        big[:n, n] = rp
        big[n, :n] = weight_z * prev_tz
        big[n, n] = prev_tp
        rhs = np.zeros(n + 1)
        rhs[n] = 1.0
        t = np.linalg.solve(big, rhs)
        tz, tp = t[:n], t[n]
        norm = math.sqrt(inner(tz, tp, tz, tp))
        return tz / norm, tp / norm

    def correct(z_pred, p_pred, tz, tp, max_iter=12):
        zc, pc = z_pred.copy(), p_pred
        for it in range(1, max_iter + 1):
            omega = math.exp(pc)
            r, jac = system.residual_and_jacobian(zc, omega, u2)
            rp = system.d_residual_d_log_omega(zc, omega)
            g = inner(tz, tp, zc - z_pred, pc - p_pred)
            big = np.empty((n + 1, n + 1))
            big[:n, :n] = jac
            big[:n, n] = rp
            big[n, :n] = weight_z * tz
            big[n, n] = tp
            step = np.linalg.solve(big, np.concatenate([r, [g]]))
            zc -= step[:n]
            pc -= step[n]
            snorm = float(np.max(np.abs(step)))
            if not np.isfinite(snorm) or snorm > 10.0:
                return None
            if snorm < max(tol, 1e-9):
                return zc, pc, it
        return None

    def solve_at(p_target, z_seed):
        omega = math.exp(p_target)
        return system.newton(z_seed, omega, u2, tol=tol, max_iter=30)

    def make_point(zp, p_val, iters, t0, segment):
        omega_resp = math.exp(p_val)
        f_exc = omega_resp / divisor / (2.0 * np.pi)
        inp = periodic_input.with_frequency(f_exc)
        sol = PeriodicSolution(
            frequency_Hz=f_exc, periodic_input=inp, state=system.unscale(zp),
            period_divisor=divisor, n_harmonics=int(n_harmonics), method="native",
            iterations=iters, residual=0.0, wall_time_s=0.0,
        )
        if stability:
            sol.multipliers = floquet_multipliers(model, sol, scale=setup.scale)
        ref = d0_static if d0 == "static" else _d0(params, d0, sol)
        sol.wall_time_s = time.perf_counter() - t0
        return _sweep_point(sol, ref, iters, sol.wall_time_s, segment, stability)

    points: list[SweepPoint] = []
    folds: list[Fold] = []
    segment = 0
    t0 = time.perf_counter()
    points.append(make_point(z, p, start.iterations, t0, segment))
    tz, tp = tangent(z, p, np.zeros(n), 1.0)
    steps = 0
    while steps < max_branch_steps:
        if p >= p_end - 1e-12 and tp > 0:
            break
        steps += 1
        corrected = correct(z + h * tz, p + h * tp, tz, tp)
        if corrected is None:
            h *= 0.5
            if h < 1e-7:
                raise ContinuationError(
                    f"continuation step underflow near f = {math.exp(p) / divisor / (2 * np.pi):.4g} Hz"
                )
            continue
        z_new, p_new, iters = corrected
        tz_new, tp_new = tangent(z_new, p_new, tz, tp)
        # Reject steps that turn the tangent by more than ~10 degrees: a large
        # step could otherwise jump across a narrow S-shaped hysteresis loop.
        if inner(tz, tp, tz_new, tp_new) < max_turn_cos and h > 1e-6:
            h *= 0.5
            continue
        # Grid frequencies crossed by this step (in either direction).
        lo, hi = min(p, p_new), max(p, p_new)
        crossed = np.nonzero((p_grid > lo) & (p_grid <= hi))[0] if p_new > p else \
            np.nonzero((p_grid >= lo) & (p_grid < hi))[0]
        order = crossed if p_new > p else crossed[::-1]
        for g in order:
            if g == 0 and p_new > p and points and abs(points[0].frequency_Hz - freqs[0]) < 1e-12 \
                    and segment == 0:
                continue
            frac = (p_grid[g] - p) / (p_new - p)
            seed = z + frac * (z_new - z)
            t_pt = time.perf_counter()
            try:
                zg, it_g, _ = solve_at(p_grid[g], seed)
            except HarmonicBalanceError:
                continue
            points.append(make_point(zg, p_grid[g], it_g, t_pt, segment))
        if np.sign(tp_new) != np.sign(tp) and tp != 0.0:
            # Fold between the two points: take the one nearer the turning point (smaller |tp|).
            zf, pf = (z_new, p_new) if abs(tp_new) < abs(tp) else (z, p)
            xf = system.unscale(zf)
            folds.append(Fold(
                frequency_Hz=math.exp(pf) / divisor / (2 * np.pi),
                d_rms_m=float(np.sqrt(np.mean((xf[0] - (d0_static if d0 == "static" else np.mean(xf[0]))) ** 2))),
                direction="forward->backward" if tp > 0 else "backward->forward",
            ))
            segment += 1
        z, p, tz, tp = z_new, p_new, tz_new, tp_new
        h = min(h * (1.5 if iters <= 3 else (1.0 if iters <= 5 else 0.6)), h_max)
    else:
        raise ContinuationError(f"more than {max_branch_steps} branch steps; the branch may be closed")
    return SweepResult(
        points=points,
        folds=folds,
        d0_m=d0_static if d0 == "static" else float("nan"),
        d0_choice=d0,
        n_harmonics=int(n_harmonics),
        method="native",
        wall_time_s=time.perf_counter() - t_start,
        branch_steps=steps,
    )


def sweep_independent(
    params: MembraneParameters,
    periodic_input: PeriodicInput,
    frequencies_Hz,
    method: str = "mousai",
    n_harmonics: int = 8,
    d0: str = "static",
    stability: bool = True,
) -> SweepResult:
    """Sweep by solving each frequency in turn (natural continuation: each solution seeds the next).

    For the ``mousai`` and ``integration`` methods, which have no arclength
    continuation; a point that fails to converge is reported with
    ``stability = "failed"`` and NaN values rather than aborting the sweep.
    """
    from .steady_state import solve_periodic

    t_start = time.perf_counter()
    freqs = np.unique(np.asarray(frequencies_Hz, dtype=float))
    d0_static = float(static_equilibrium(params, 0.0).displacement_m)
    points: list[SweepPoint] = []
    guess = None
    for f in freqs:
        inp = periodic_input.with_frequency(f)
        t0 = time.perf_counter()
        try:
            kwargs = {} if method == "integration" else {"x_guess": guess}
            sol = solve_periodic(params, inp, method=method, n_harmonics=n_harmonics,
                                 stability=stability, **kwargs)
        except Exception as exc:  # noqa: BLE001 - reported per point, sweep goes on
            nan = float("nan")
            points.append(SweepPoint(f, nan, nan, nan, False, f"failed: {exc}"[:200], nan, 0,
                                     time.perf_counter() - t0, 0, None))
            guess = None
            continue
        guess = sol.state if method != "integration" else None
        ref = d0_static if d0 == "static" else _d0(params, d0, sol)
        points.append(_sweep_point(sol, ref, sol.iterations, time.perf_counter() - t0, 0, stability))
    return SweepResult(points, [], d0_static if d0 == "static" else float("nan"), d0,
                       int(n_harmonics), method, time.perf_counter() - t_start, len(freqs))


__all__ += ["sweep_independent"]
