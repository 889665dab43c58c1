"""Frequency sweeps: what a measurement sees at every frequency, by continuation and branch switching.

Branches. The periodic solutions are followed by pseudo-arclength continuation in
y = (z, p), z the scaled collocation values and p = ln(omega) of the response, with
predictor (tangent) / corrector (Newton on the collocation equations plus the arclength
condition) steps of adaptive length, so turning points (folds, where the response jumps in
an experiment) are passed, not stopped at. With the compiled kernels the whole loop runs in
one call (:func:`~dea_ros.solvers.hbm_kernels.trace_branch`, the same steps as the Python loop
of the numpy path). The primary branch ``"T/2"`` has the period of
u^2 (T/2 for a sine without offset, eq. 6). Every requested frequency a branch crosses is
solved exactly (Newton at fixed frequency seeded from the two neighbouring branch points);
inside a hysteresis band the same frequency appears once per branch segment.

Stability and bifurcations. Floquet multipliers are computed at every branch step and grid
point (stacked, :func:`~dea_ros.solvers.harmonic_balance.floquet_multipliers_batch`). Where
the number of multipliers outside the unit circle changes, the bifurcation is located along
the branch where the crossing multiplier has modulus 1 (Illinois method on |mu| - 1, to 1e-10;
folds likewise on the p-component of the tangent) and named by the critical multiplier:
``fold`` (+1, where the branch turns), ``period-doubling`` (-1) or ``torus`` (a complex pair,
Neimark-Sacker).

Branch switching. At a period-doubling point of the T/2 branch the full-period collocation
Jacobian (2N harmonics of f, the same spectral reach) is singular along an odd-harmonic
vector, the critical Floquet vector of multiplier -1 seen over T. The period-doubled branch
``"T"`` leaves the T/2 orbit along it (a pitchfork in the full-period equations) and is
continued like any branch until it returns to the T/2 branch (its odd harmonics change
sign) or leaves the frequency range.

The realised response. For every requested frequency the stable solutions of all branches
are collected: one gives its kind (``periodic`` on T/2, ``period-doubled`` on T), several are
``coexisting`` (which one the rig shows depends on its history; the sweep reports the one a
slow upward sweep stays on, the others as alternatives), none means no stable periodic
response: the motion is integrated (:func:`~dea_ros.solvers.realised.realised_response`)
and reported as ``quasi-periodic`` with its window-mean RMS and min/max envelope.
:attr:`SweepResult.bands` summarises the frequency range in bands of one kind, with edges at
the located bifurcations.

Resonance peak: the extremum of d_rms along the branch (where d(d_rms)/ds = 0 between two
branch steps, located by a bracketed secant on the directional derivative), so it does not
depend on the frequency grid.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from . import hbm_kernels
from .harmonic_balance import (
    HarmonicBalanceError,
    PeriodicSolution,
    classify_stability,
    floquet_multipliers,
    floquet_multipliers_batch,
    magnus_steps,
    model_setup,
    periodic_interpolation_matrix,
    response_layout,
    solve_native,
    truncation_ratios,
)
from .inputs import PeriodicInput
from .realised import SETTLE_PERIODS, WINDOW_PERIODS, realised_response
from .steady_state import SteadyStateError, solve_periodic
from ..errors import ContinuationError

__all__ = [
    "SweepPoint", "Fold", "Bifurcation", "Response", "Band", "Branch", "SweepResult", "frequency_sweep",
    "ContinuationError", "sweep_independent", "KINDS", "period_doubled_solution", "PRIMARY", "END_TOL",
    "stability_segments",
]

#: Kinds of realised response, in the order of the band summary.
KINDS = ("periodic", "period-doubled", "quasi-periodic", "coexisting")

PRIMARY = "T/2"
#: Folds and stability changes of a period-doubled branch closer than this (in ln f) to its ends
#: are the pitchforks it leaves and rejoins the T/2 branch at, not features of the branch.
END_TOL = 1e-4
#: Largest arclength step (ln omega and scaled collocation values): steps also halve when the
#: tangent turns by more than 10 degrees, and every requested frequency is a station of the
#: stability analysis, so bands are not stepped over.
H_MAX = 0.05

#: Bifurcations are located with this many times the default Magnus steps (:func:`magnus_steps`).
LOCATE_STEP_FACTOR = 4


@dataclass
class SweepPoint:
    """One periodic solution on a branch at a requested frequency."""

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
    branch: str = PRIMARY       # "T/2" (period of u^2) or "T" (period-doubled)

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
            "branch": self.branch,
            "truncation_ratio": self.truncation_ratio,
        }


@dataclass
class Fold:
    """A turning point of a branch (saddle-node): where the response jumps in a slow sweep."""

    frequency_Hz: float
    d_rms_m: float
    direction: str  # "forward->backward" (branch turns back to lower f) or the reverse
    branch: str = PRIMARY


@dataclass
class Bifurcation:
    """A point of a branch where its stability changes (or it turns)."""

    kind: str                   # "fold", "period-doubling", "torus" or "branch point"
    frequency_Hz: float
    d_rms_m: float
    branch: str
    multiplier: complex         # the critical Floquet multiplier (over the branch's period)
    stable_before: bool         # stability on the side of smaller arclength

    def to_dict(self) -> dict:
        return {"kind": self.kind, "frequency_Hz": self.frequency_Hz, "d_rms_m": self.d_rms_m,
                "branch": self.branch, "multiplier": [float(np.real(self.multiplier)),
                                                      float(np.imag(self.multiplier))],
                "stable_before": self.stable_before}


@dataclass
class Response:
    """What a measurement sees at one requested frequency (see the module docstring)."""

    frequency_Hz: float
    kind: str                   # one of KINDS
    d_rms_m: float              # the realised response (slow upward sweep)
    d_rms_min_m: float          # envelope: per-period min (quasi-periodic) or over the stable branches
    d_rms_max_m: float
    branch: str                 # "T/2", "T" or "integration"
    alternatives: list = field(default_factory=list)   # other stable responses [{branch, d_rms_m}]
    integration: dict | None = None                     # window and details of a quasi-periodic response

    def to_dict(self) -> dict:
        return {"frequency_Hz": self.frequency_Hz, "kind": self.kind, "d_rms_m": self.d_rms_m,
                "d_rms_min_m": self.d_rms_min_m, "d_rms_max_m": self.d_rms_max_m, "branch": self.branch,
                "alternatives": list(self.alternatives), "integration": self.integration}


@dataclass
class Band:
    """A frequency interval with one kind of realised response (edges at located bifurcations)."""

    f_start_Hz: float
    f_end_Hz: float
    kind: str
    branches: list              # stable branches in the band, e.g. ["T/2"], ["T/2", "T"]
    start_edge: str             # what bounds it: "range", "fold", "period-doubling", "torus", ...
    end_edge: str

    def to_dict(self) -> dict:
        return dict(self.__dict__)

    def describe(self) -> str:
        what = {"periodic": "periodic (period of u^2)", "period-doubled": "period-doubled (period T)",
                "quasi-periodic": "quasi-periodic (no stable periodic orbit; by integration)",
                "coexisting": "coexisting stable responses (" + ", ".join(self.branches) + ")"}[self.kind]
        return f"{self.f_start_Hz:.4f}-{self.f_end_Hz:.4f} Hz: {what}"


@dataclass
class Branch:
    """A continued family of periodic solutions: grid points, folds, bifurcations, the whole curve."""

    name: str
    kind: str                   # "periodic" or "period-doubled"
    period_divisor: int
    points: list
    folds: list
    bifurcations: list
    curve_frequency_Hz: np.ndarray
    curve_d_rms_m: np.ndarray
    curve_stable: np.ndarray
    maxima: list                # local maxima of d_rms along the branch [{frequency_Hz, d_rms_m, stable}]
    stable_intervals: list      # [(f_lo, f_hi, segment, lo_edge, hi_edge)]
    steps: int = 0

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "period_divisor": self.period_divisor,
                "steps": self.steps, "folds": [f.__dict__ for f in self.folds],
                "bifurcations": [b.to_dict() for b in self.bifurcations], "maxima": self.maxima,
                "stable_intervals": [{"f_lo_Hz": a, "f_hi_Hz": b, "segment": s, "lo_edge": e1, "hi_edge": e2}
                                     for a, b, s, e1, e2 in self.stable_intervals],
                "points": [p.to_dict() for p in self.points]}


@dataclass
class SweepResult:
    points: list                # the primary (T/2) branch at the requested frequencies
    folds: list                 # folds of the primary branch
    d0_m: float
    d0_choice: str
    n_harmonics: int
    method: str
    wall_time_s: float
    branch_steps: int
    branches: list = field(default_factory=list)
    responses: list = field(default_factory=list)
    bands: list = field(default_factory=list)
    bifurcations: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)

    @property
    def frequencies_Hz(self) -> np.ndarray:
        return np.array([p.frequency_Hz for p in self.points])

    @property
    def d_rms_m(self) -> np.ndarray:
        return np.array([p.d_rms_m for p in self.points])

    @property
    def stable(self) -> np.ndarray:
        return np.array([p.stable for p in self.points])

    @property
    def response_frequencies_Hz(self) -> np.ndarray:
        return np.array([r.frequency_Hz for r in self.responses])

    @property
    def realised_d_rms_m(self) -> np.ndarray:
        """The realised response at every requested frequency (see :class:`Response`)."""
        return np.array([r.d_rms_m for r in self.responses])

    def branch(self, name: str):
        for b in self.branches:
            if b.name == name:
                return b
        return None

    def resonance_peak(self, stable_only: bool = True) -> dict:
        """Largest d_rms of the primary (T/2) branch, located on the branch itself.

        ``stable_only``: the largest stable response (a local maximum on a stable part, or the
        end of a stable part at a fold or a loss of stability); otherwise the branch maximum,
        stable or not.
        """
        prim = self.branch(PRIMARY)
        if prim is None or not prim.maxima:
            pts = [p for p in self.points if p.stable or not stable_only]
            if not pts:
                return {"frequency_Hz": float("nan"), "d_rms_m": float("nan")}
            k = int(np.argmax([p.d_rms_m for p in pts]))
            return {"frequency_Hz": pts[k].frequency_Hz, "d_rms_m": pts[k].d_rms_m, "stable": pts[k].stable}
        cand = [m for m in prim.maxima if m["stable"] or not stable_only]
        if not cand:
            return {"frequency_Hz": float("nan"), "d_rms_m": float("nan")}
        best = max(cand, key=lambda m: m["d_rms_m"])
        return {"frequency_Hz": float(best["frequency_Hz"]), "d_rms_m": float(best["d_rms_m"]),
                "stable": bool(best["stable"])}

    def largest_response(self) -> dict:
        """The largest realised response over the requested frequencies (any kind)."""
        if not self.responses:
            return self.resonance_peak(True)
        r = max(self.responses, key=lambda x: x.d_rms_m if np.isfinite(x.d_rms_m) else -1.0)
        return {"frequency_Hz": r.frequency_Hz, "d_rms_m": r.d_rms_m, "kind": r.kind, "branch": r.branch}

    @property
    def max_truncation_ratio(self) -> float:
        sols = [p.solution for b in (self.branches or []) for p in b.points if p.solution is not None]
        sols += [p.solution for p in self.points if p.solution is not None]
        return float(np.max(truncation_ratios(sols))) if sols else float("nan")

    def band_summary(self) -> list:
        return [b.describe() for b in self.bands]

    def to_dict(self) -> dict:
        return {
            "n_harmonics": self.n_harmonics,
            "max_truncation_ratio": self.max_truncation_ratio,
            "method": self.method,
            "d0_m": self.d0_m,
            "d0_choice": self.d0_choice,
            "wall_time_s": self.wall_time_s,
            "timings_s": dict(self.timings_s),
            "branch_steps": self.branch_steps,
            "bands": [b.to_dict() for b in self.bands],
            "band_summary": self.band_summary(),
            "resonance_peak": self.resonance_peak(True),
            "resonance_peak_branch": self.resonance_peak(False),
            "largest_response": self.largest_response(),
            "folds": [f.__dict__ for f in self.folds],
            "bifurcations": [b.to_dict() for b in self.bifurcations],
            "responses": [r.to_dict() for r in self.responses],
            "points": [p.to_dict() for p in self.points],
            "branches": [b.to_dict() for b in self.branches if b.name != PRIMARY],
        }


def _d0(params: MembraneParameters, choice: str, sol: PeriodicSolution) -> float:
    if choice == "static":
        return float(static_equilibrium(params, 0.0).displacement_m)
    if choice == "mean":
        return sol.mean_displacement_m
    raise ValueError(f"d0: 'static' (equilibrium at u = 0, the paper's eq. 21) or 'mean', got {choice!r}")


def _d_rms_rows(d: np.ndarray, d0_m) -> tuple:
    """(d_rms (eq. 21), d - d0, mean) of displacement rows d (K, M) around d0_m (None: each row's mean)."""
    mean = d.sum(axis=1) / d.shape[1]
    dev = d - (mean[:, None] if d0_m is None else d0_m)
    return np.sqrt(np.einsum("ij,ij->i", dev, dev) / d.shape[1]), dev, mean


def _sweep_points(sols: list, d0_m, iterations, wall_time_s: float, segments, stability: bool,
                  branch: str = PRIMARY) -> list:
    """SweepPoints of periodic solutions with the same number of points: d_rms around d0_m (eq. 21;
    None: around each one's mean), stability from each one's stability multipliers."""
    if not sols:
        return []
    d = np.stack([sol.state[0] for sol in sols])
    d_rms, _dev, mean = _d_rms_rows(d, d0_m)
    d_rms = d_rms.tolist()
    peak_to_peak = (d.max(axis=1) - d.min(axis=1)).tolist()
    mus = [sol.stability_multipliers for sol in sols]
    max_mu = [float(np.abs(mu).max()) if mu is not None else float("nan") for mu in mus]
    return [SweepPoint(
        frequency_Hz=float(sol.frequency_Hz), d_rms_m=d_rms[i], mean_displacement_m=float(mean[i]),
        peak_to_peak_m=peak_to_peak[i],
        stable=bool(max_mu[i] < 1.0) if stability else True,   # as PeriodicSolution.stable
        stability=classify_stability(mus[i]), max_multiplier=max_mu[i], iterations=int(iterations[i]),
        wall_time_s=wall_time_s, segment=int(segments[i]), solution=sol, branch=branch,
    ) for i, sol in enumerate(sols)]


# ----------------------------------------------------------------------------------- tracer
class _Tracer:
    """Pseudo-arclength continuation of one family of periodic solutions (module docstring)."""

    def __init__(self, setup, periodic_input: PeriodicInput, divisor: int, m: int, tol: float,
                 h_max: float, p_grid: np.ndarray):
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

    def inner(self, a_z, a_p, b_z, b_p) -> float:
        return self.wz * float(a_z @ b_z) + a_p * b_p

    def _bordered(self, z, p, tz, tp):
        """(R, dense bordered matrix) of the numpy path."""
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

    def tangent(self, z, p, prev_tz, prev_tp):
        if hbm_kernels.enabled():  # the same bordered system, solved by the structured reduction
            return self._compiled_tangent(z, p, prev_tz, prev_tp)
        _r, big = self._bordered(z, p, prev_tz, prev_tp)
        return self._unit_tangent(big)

    def _compiled_tangent(self, z, p, prev_tz, prev_tp):
        sy = self.system
        t, ok = hbm_kernels.bordered_tangent(np.asarray(z, dtype=float), float(p), np.asarray(prev_tz, dtype=float),
                                             float(prev_tp), self.wz, self.u2, sy.constants, sy.scale, sy.rate_ref,
                                             sy.d_theta)
        if not ok:
            raise np.linalg.LinAlgError("Singular matrix")
        return self._normalised(t)

    def _normalised(self, t):
        tz, tp = t[:self.n], t[self.n]
        norm = math.sqrt(self.inner(tz, tp, tz, tp))
        return tz / norm, tp / norm

    def _unit_tangent(self, big):
        """The unit tangent: solution of the bordered system with right-hand side e_n, normalised."""
        rhs = np.zeros(self.n + 1)
        rhs[-1] = 1.0
        return self._normalised(np.linalg.solve(big, rhs))

    def correct(self, z_pred, p_pred, tz, tp, max_iter: int = 12):
        if hbm_kernels.enabled():  # the same corrector, compiled
            sy = self.system
            ok, zc, pc, it, t = hbm_kernels.bordered_corrector(
                np.asarray(z_pred, dtype=float), float(p_pred), np.asarray(tz, dtype=float), float(tp), self.wz,
                self.u2, sy.constants, sy.scale, sy.rate_ref, sy.d_theta, float(self.tol), int(max_iter))
            if not ok:
                return None
            # the next tangent: the bordered system where the corrector built its last matrix (solved there)
            self.last_tangent = functools.partial(self._normalised, t)
            return zc, pc, it
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
            if done or hbm_kernels.converges_below(snorm, prev_snorm, max(self.tol, 1e-9)):
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

    def excitation_Hz(self, p) -> float:
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
        """Floquet multipliers at (z, p); ``steps`` Magnus steps (default: :func:`magnus_steps`)."""
        return floquet_multipliers(self.setup.model, self.solution(z, p), steps=steps, scale=self.setup.scale)

    def magnus_steps(self, z, p) -> int:
        return magnus_steps(self.setup.model, self.solution(z, p), scale=self.setup.scale)

    def odd_flipped(self, z_prev, z_new, odd_projector) -> bool:
        """The odd-harmonic part (``odd_projector`` per state) of the solution turned back from z_prev
        to z_new: a period-doubled branch came back through the T/2 orbit (not the start's noise)."""
        a = (z_prev.reshape(3, self.m) @ odd_projector.T).reshape(-1)
        b = (z_new.reshape(3, self.m) @ odd_projector.T).reshape(-1)
        na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
        return na > 1e-6 * math.sqrt(self.n) and float(a @ b) < -0.5 * na * nb

    def trace(self, z, p, tz, tp, p_lo, p_hi, max_steps: int, odd_projector=None, h0=None) -> dict:
        """Follow the branch from (z, p) along (tz, tp) until it leaves [p_lo, p_hi] moving outwards,
        its odd-harmonic part turns back (when ``odd_projector`` is given: :meth:`odd_flipped`), or
        ``max_steps``. Grid frequencies crossed are solved."""
        h = 0.5 * self.h_max if h0 is None else h0
        if hbm_kernels.enabled():
            return self._compiled_trace(z, p, tz, tp, p_lo, p_hi, max_steps, odd_projector, h)
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
                    hbm_kernels.hermite_seed(z, tz, p, tp, z_new, tz_new, p_new, tp_new, ds, float(self.p_grid[g]),
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

    def _compiled_trace(self, z, p, tz, tp, p_lo, p_hi, max_steps, odd_projector, h) -> dict:
        """:meth:`trace` by the compiled loop (:func:`hbm_kernels.trace_branch`: the same steps)."""
        sy = self.system
        kern = hbm_kernels
        status, p_end, steps, stopped, zs, tzs, table, fold_steps, g_z, g_table = kern.trace_branch(
            np.array(z, dtype=float), float(p), np.array(tz, dtype=float), float(tp), float(p_lo), float(p_hi),
            int(max_steps), float(h), float(self.h_max), np.asarray(self.p_grid, dtype=float), self.u2,
            sy.constants, sy.scale, sy.rate_ref, sy.d_theta, self.wz, float(self.tol),
            np.zeros((1, 1)) if odd_projector is None else np.ascontiguousarray(odd_projector, dtype=float),
            odd_projector is not None)
        if status == kern.TRACE_STEP_UNDERFLOW:
            raise ContinuationError(f"continuation step underflow near f = {self.excitation_Hz(p_end):.6g} Hz")
        if status == kern.TRACE_MAX_STEPS:
            raise ContinuationError(f"more than {max_steps} branch steps; the branch may be closed")
        grid = [(int(r[kern.GRID_INDEX]), g_z[j], r[kern.GRID_P], int(r[kern.GRID_ITERATIONS]),
                 int(r[kern.GRID_SEGMENT]), int(r[kern.GRID_STEP]), r[kern.GRID_FRACTION])
                for j, r in enumerate(g_table.tolist())]
        return {"z": zs, "p": table[:, kern.STEP_P], "tz": tzs, "tp": table[:, kern.STEP_TP],
                "h": table[:-1, kern.STEP_H], "segment": table[:, kern.STEP_SEGMENT].astype(int), "grid": grid,
                "fold_steps": fold_steps.tolist(), "steps": int(steps), "stopped": bool(stopped)}

    def at(self, tr: dict, k: int, tau: float):
        """The branch point a fraction tau of the way from step k to k+1 (corrector from step k)."""
        if tau <= 0.0:
            return tr["z"][k], float(tr["p"][k])
        if tau >= 1.0:
            return tr["z"][k + 1], float(tr["p"][k + 1])
        h = tau * tr["h"][k]
        z0, p0, tz, tp = tr["z"][k], tr["p"][k], tr["tz"][k], tr["tp"][k]
        res = self.correct(z0 + h * tz, p0 + h * tp, tz, tp)
        if res is None:  # straight interpolation, then Newton at its frequency
            zi = (1.0 - tau) * tr["z"][k] + tau * tr["z"][k + 1]
            pi = (1.0 - tau) * tr["p"][k] + tau * tr["p"][k + 1]
            zi, _it, _r = self.solve_at(pi, zi)
            return zi, float(pi)
        return res[0], float(res[1])


# ----------------------------------------------------------------------------- analysis
def _n_outside(mu) -> int:
    return int(np.count_nonzero(np.abs(mu) > 1.0))


def _critical(mu) -> complex:
    """The multiplier closest to the unit circle."""
    mu = np.asarray(mu)
    return complex(mu[int(np.argmin(np.abs(np.abs(mu) - 1.0)))])


def _event_kind(mu) -> str:
    c = _critical(mu)
    if abs(c.imag) > 1e-6 * abs(c):
        return "torus"
    return "period-doubling" if c.real < 0 else "branch point"


def _crossing_distance(mu, index: int) -> float:
    """The modulus at ``index`` of the multipliers sorted by decreasing modulus, minus 1: it changes
    sign where the number of multipliers outside the unit circle passes index <-> index + 1."""
    return float(np.sort(np.abs(mu))[::-1][index]) - 1.0


def _illinois(fn, a: float, b: float, fa: float, fb: float, f_tol: float, width: float, max_evals: int):
    """Root of a continuous fn on [a, b] (fa, fb of opposite signs) by the Illinois (bracketed secant)
    method. ``fn(t)`` returns (value, payload). Stops after ``max_evals`` evaluations, at |value| <=
    ``f_tol`` or once the bracket is narrower than ``width``. Returns (t, value, payload) of the
    evaluated point with the smallest |value| (None when nothing was evaluated)."""
    best = None
    side = 0
    for _ in range(max_evals):
        c = b - fb * (b - a) / (fb - fa) if fb != fa else 0.5 * (a + b)
        c = min(max(c, a + 1e-12), b - 1e-12)
        fc, payload = fn(c)
        if best is None or abs(fc) < abs(best[1]):
            best = (c, fc, payload)
        if abs(fc) <= f_tol:
            break
        if (fc > 0) == (fa > 0):   # the root is in [c, b]
            a, fa = c, fc
            if side == -1:
                fb *= 0.5
            side = -1
        else:
            b, fb = c, fc
            if side == 1:
                fa *= 0.5
            side = 1
        if b - a < width:
            break
    return best


def _rms_and_slopes(tracer: _Tracer, zs, tzs, d0) -> tuple:
    """d_rms (eq. 21) of the scaled unknowns zs (rows) and, when the unit tangents tzs (rows) are
    given, d(d_rms)/ds along them (the gradient of d_rms w.r.t. z dotted with tz; else None)."""
    m = tracer.m
    scale_d = tracer.setup.scale[0]
    rms, dev, _mean = _d_rms_rows(np.asarray(zs)[:, :m] * scale_d, d0)
    if tzs is None:
        return rms, None
    along = scale_d * np.einsum("ij,ij->i", dev, np.asarray(tzs)[:, :m])
    return rms, np.divide(along, m * rms, out=np.zeros_like(rms), where=rms > 0)


def _rms_of(tracer: _Tracer, z, d0) -> float:
    """d_rms (eq. 21) of one solution (scaled unknowns z)."""
    return float(_rms_and_slopes(tracer, z[None], None, d0)[0][0])


def _analyse(tracer: _Tracer, tr: dict, d0, name: str, stability: bool, ignore_ends: bool = False) -> dict:
    """Multipliers at every station, bifurcations (located), local maxima of d_rms, stable intervals."""
    setup = tracer.setup
    inp = tracer.periodic_input
    zs, ps = tr["z"], tr["p"]
    nsteps = zs.shape[0]
    # stations: branch steps and grid points, in arclength order
    stations = [(k, 0.0, zs[k], float(ps[k]), None) for k in range(nsteps)]
    stations += [(k, fr, zg, pg, j) for j, (_g, zg, pg, _it, _seg, k, fr) in enumerate(tr["grid"])]
    stations.sort(key=lambda s: (s[0], s[1]))
    mu_grid = [None] * len(tr["grid"])
    if stability:
        model = setup.model
        states = np.stack([s[2] for s in stations]).reshape(len(stations), 3, tracer.m) * \
            tracer.system.scale[None, :, None]
        periods = np.array([2.0 * np.pi / math.exp(s[3]) for s in stations])
        # h rho <= 0.5, >= 32 Magnus steps: |mu| to ~1e-5 next to the resonance (harmonic_balance.MAGNUS_H_RHO),
        # for the reported points and to detect where the stability changes
        mus = floquet_multipliers_batch(model, states, periods, inp, tracer.divisor, scale=setup.scale,
                                        h_rho=0.5, min_steps=32)
        for i, st in enumerate(stations):
            if st[4] is not None:
                mu_grid[st[4]] = mus[i]
    else:
        mus = np.zeros((len(stations), 3))
    counts = np.count_nonzero(np.abs(mus) > 1.0, axis=1).tolist()   # multipliers outside, per station
    # ---- folds (turning points), located on tp = 0 (tp of the unit tangent, continuous along the branch)
    folds = []
    for k in tr["fold_steps"]:
        s_lo = np.sign(tr["tp"][k])

        def tangent_p(tau, k=k):
            zm, pm = tracer.at(tr, k, tau)
            return tracer.tangent(zm, pm, tr["tz"][k], tr["tp"][k])[1], (zm, pm)
        try:
            tau, _tp, (zf, pf) = _illinois(tangent_p, 0.0, 1.0, float(tr["tp"][k]), float(tr["tp"][k + 1]),
                                           f_tol=1e-10, width=2.0 ** -11, max_evals=11)
        except (HarmonicBalanceError, np.linalg.LinAlgError):
            tau, zf, pf = 0.5, zs[k], float(ps[k])
        folds.append({"k": k, "tau": tau, "z": zf, "p": pf,
                      "direction": "forward->backward" if s_lo > 0 else "backward->forward"})
    if ignore_ends:  # the pitchfork turning points where a period-doubled branch starts / ends
        ends = [float(ps[0])] + ([float(ps[-1])] if tr["stopped"] else [])
        folds = [f for f in folds if min(abs(f["p"] - e) for e in ends) > END_TOL]
    # ---- stability changes, located along the branch where the multiplier that crosses the unit
    # circle has modulus 1 (Illinois on its modulus - 1; the stations' counts bracket it). One step
    # count for all evaluations of a location (|mu| continuous along it: the default rule jumps by
    # one step here and there), LOCATE_STEP_FACTOR times the default (|mu| ~256x more accurate).
    events = []
    if stability:
        for i in range(len(stations) - 1):
            if counts[i] == counts[i + 1]:
                continue
            (ka, ta, *_), (kb, tb, *_) = stations[i], stations[i + 1]
            k = ka
            lo, hi = ta, (tb if kb == ka else 1.0)
            c_lo = counts[i]
            index = min(c_lo, counts[i + 1])

            fixed_steps = []

            def crossing(tau, k=k, index=index, fixed_steps=fixed_steps):
                zm, pm = tracer.at(tr, k, tau)
                if not fixed_steps:
                    fixed_steps.append(LOCATE_STEP_FACTOR * tracer.magnus_steps(zm, pm))
                mu = tracer.multipliers(zm, pm, fixed_steps[0])
                return _crossing_distance(mu, index), (zm, pm, mu)
            try:
                tau, _f, (zc, pc, mu_c) = _illinois(
                    crossing, lo, hi, _crossing_distance(mus[i], index), _crossing_distance(mus[i + 1], index),
                    f_tol=1e-10, width=(hi - lo) * 1e-12, max_evals=12)
            except (HarmonicBalanceError, np.linalg.LinAlgError):
                continue
            kind = _event_kind(mu_c)
            fold = None
            if kind == "branch point":
                near = [f for f in folds if abs(f["p"] - pc) < 1e-4 and abs(f["k"] - k) <= 1]
                if near:
                    kind, fold = "fold", near[0]
                    fold["event"] = True
            if ignore_ends and min(abs(pc - e) for e in ends) <= END_TOL:
                continue
            events.append({"k": k, "tau": tau, "kind": kind, "z": zc, "p": pc,
                           "mu": _critical(mu_c), "stable_before": c_lo == 0, "fold": fold,
                           "count_before": c_lo, "count_after": counts[i + 1]})
    # ---- local maxima of d_rms along the arclength: d(d_rms)/ds = grad . t changes sign

    def slope(z, tz):
        return float(_rms_and_slopes(tracer, z[None], tz[None], d0)[1][0])

    maxima = []
    curve_d, slopes = _rms_and_slopes(tracer, zs, tr["tz"], d0)
    slopes = slopes.tolist()
    for k in range(nsteps - 1):
        if not (slopes[k] > 0.0 >= slopes[k + 1]):
            continue

        def slope_at(tau, k=k):
            zc, pc = tracer.at(tr, k, tau)
            tzc, _tpc = tracer.tangent(zc, pc, tr["tz"][k], tr["tp"][k])
            return slope(zc, tzc), (zc, pc)
        try:
            _tau, _f, (zc, pc) = _illinois(slope_at, 0.0, 1.0, slopes[k], slopes[k + 1],
                                           f_tol=1e-12 * max(abs(slopes[k]), 1e-30), width=1e-9, max_evals=30)
        except (HarmonicBalanceError, np.linalg.LinAlgError):
            zc, pc = zs[k], float(ps[k])
        stable_here = True
        if stability:
            stable_here = _n_outside(tracer.multipliers(zc, pc)) == 0
        maxima.append({"frequency_Hz": tracer.excitation_Hz(pc), "d_rms_m": _rms_of(tracer, zc, d0),
                       "stable": stable_here, "branch": name, "k": k})
    # ---- stable intervals along the branch (arclength order), bounded by events and folds
    marks = sorted([(e["k"], e["tau"], "event", e) for e in events] +
                   [(f["k"], f["tau"], "fold", f) for f in folds if not f.get("event")],
                   key=lambda x: (x[0], x[1]))
    intervals = []
    i0 = 0
    if ignore_ends:  # judge the start beyond the pitchfork (a multiplier is 1 there)
        far = [i for i, st in enumerate(stations) if abs(st[3] - float(ps[0])) > END_TOL]
        i0 = far[0] if far else 0
    stable_now = (counts[i0] == 0) if stability else True
    f_start = tracer.excitation_Hz(ps[0])
    edge_start = "range" if name == PRIMARY else "period-doubling"
    seg = 0
    start_obj = {"z": zs[0]}
    for k, tau, what, obj in marks:
        f_here = tracer.excitation_Hz(obj["p"])
        edge = obj["kind"] if what == "event" else "fold"
        if stable_now:
            intervals.append((min(f_start, f_here), max(f_start, f_here), seg, edge_start, edge))
            # the ends of a stable piece (fold tip, loss of stability) are candidate maxima
            for e_name, e_obj in ((edge_start, start_obj), (edge, obj)):
                if e_name != "range":
                    maxima.append({"frequency_Hz": tracer.excitation_Hz(e_obj.get("p", ps[0])),
                                   "d_rms_m": _rms_of(tracer, e_obj["z"], d0), "stable": True, "branch": name, "k": k,
                                   "edge": e_name})
        if what == "event":
            stable_now = obj["count_after"] == 0
        if what == "fold" or (what == "event" and obj.get("fold") is not None):
            seg += 1
        f_start, edge_start, start_obj = f_here, edge, obj
    if stable_now:
        f_end = tracer.excitation_Hz(ps[-1])
        end_edge = "period-doubling" if (name != PRIMARY and tr["stopped"]) else "range"
        intervals.append((min(f_start, f_end), max(f_start, f_end), seg, edge_start, end_edge))
        if edge_start != "range":
            maxima.append({"frequency_Hz": tracer.excitation_Hz(start_obj.get("p", ps[0])),
                           "d_rms_m": _rms_of(tracer, start_obj["z"], d0), "stable": True, "branch": name, "k": -1,
                           "edge": edge_start})
    return {"stations": stations, "mus": mus, "counts": counts, "mu_grid": mu_grid, "events": events,
            "folds": folds, "maxima": maxima, "intervals": intervals, "curve_d": curve_d}


def _make_branch(tracer: _Tracer, tr: dict, an: dict, name: str, kind: str, d0, stability: bool,
                 t_points: float) -> Branch:
    sols = []
    grid = tr["grid"]
    states = (np.stack([g[1] for g in grid]).reshape(len(grid), 3, tracer.m) * tracer.system.scale[None, :, None]
              if grid else [])
    for j, (_g, zg, pg, it, _seg, _k, _fr) in enumerate(grid):
        sol = tracer.solution(zg, pg, it, states[j])
        if stability:
            sol.multipliers = an["mu_grid"][j]
        sols.append(sol)
    points = _sweep_points(sols, d0, [g[3] for g in tr["grid"]], t_points, [g[4] for g in tr["grid"]], stability,
                           name)
    folds = [Fold(tracer.excitation_Hz(f["p"]), _rms_of(tracer, f["z"], d0), f["direction"], name)
             for f in an["folds"]]
    bifs = [Bifurcation(e["kind"], tracer.excitation_Hz(e["p"]), _rms_of(tracer, e["z"], d0),
                        name, e["mu"], e["stable_before"]) for e in an["events"] if e["fold"] is None]
    for f_raw, f in zip(an["folds"], folds):
        ev = [e for e in an["events"] if e["fold"] is f_raw]
        bifs.append(Bifurcation("fold", f.frequency_Hz, f.d_rms_m, name, complex(1.0, 0.0),
                                bool(ev[0]["stable_before"]) if ev else False))
    bifs.sort(key=lambda b: b.frequency_Hz)
    curve_f = np.array([tracer.excitation_Hz(p) for p in tr["p"]])
    counts = np.array([c for s, c in zip(an["stations"], an["counts"]) if s[4] is None])
    curve_stable = counts == 0 if stability else np.ones(counts.size, bool)
    return Branch(name=name, kind=kind, period_divisor=tracer.divisor, points=points, folds=folds,
                  bifurcations=bifs, curve_frequency_Hz=curve_f, curve_d_rms_m=an["curve_d"],
                  curve_stable=curve_stable, maxima=an["maxima"], stable_intervals=an["intervals"],
                  steps=tr["steps"])


# --------------------------------------------------------------------------- switching
def _odd_projector(m: int) -> np.ndarray:
    """Real M x M matrix keeping the odd harmonics of m equispaced samples over the period."""
    k = np.fft.fftfreq(m, 1.0 / m)
    mask = (np.abs(np.round(k)) % 2 == 1).astype(float)
    f = np.fft.fft(np.eye(m), axis=0)
    return np.real(np.fft.ifft(mask[:, None] * f, axis=0))


@functools.lru_cache(maxsize=16)
def _odd_basis(m: int) -> np.ndarray:
    """Orthonormal basis (3M, K) of the odd-harmonic subspace of the 3 states on m points (read-only)."""
    w, v = np.linalg.eigh(np.kron(np.eye(3), _odd_projector(m)))
    basis = np.ascontiguousarray(v[:, w > 0.5])
    basis.flags.writeable = False
    return basis


def _period_doubled_start(setup, half: _Tracer, full: _Tracer, z_half, p_half):
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


# ----------------------------------------------------------------------------- sweep
def stability_segments(branch: "Branch", bifurcations) -> tuple:
    """((f, d_rms) stable, (f, d_rms) unstable) polylines of a branch's curve, NaN between pieces, split
    where the stability changes at the branch's located bifurcation (fold, torus, period doubling)
    rather than half-way: a branch followed in long steps (a flat response) may have a single stable
    point between unstable ones, which masking the curve would not draw at all."""
    f = np.asarray(branch.curve_frequency_Hz, float)
    d = np.asarray(branch.curve_d_rms_m, float)
    st = np.asarray(branch.curve_stable, bool)
    own = [b for b in bifurcations if b.branch == branch.name]
    lines = {True: ([], []), False: ([], [])}

    def add(stable, f0, d0, f1, d1):
        xs, ys = lines[stable]
        if not xs or xs[-1] != f0 or ys[-1] != d0:
            if xs:
                xs.append(np.nan)
                ys.append(np.nan)
            xs.append(f0)
            ys.append(d0)
        xs.append(f1)
        ys.append(d1)

    for i in range(f.size - 1):
        if st[i] == st[i + 1]:
            add(bool(st[i]), f[i], d[i], f[i + 1], d[i + 1])
            continue
        lo, hi = min(f[i], f[i + 1]), max(f[i], f[i + 1])
        inside = [b for b in own if lo <= b.frequency_Hz <= hi]
        if inside:
            mid = 0.5 * (lo + hi)
            b = min(inside, key=lambda x: abs(x.frequency_Hz - mid))
            fb, db = b.frequency_Hz, b.d_rms_m
        else:
            fb, db = 0.5 * (f[i] + f[i + 1]), 0.5 * (d[i] + d[i + 1])
        add(bool(st[i]), f[i], d[i], fb, db)
        add(bool(st[i + 1]), fb, db, f[i + 1], d[i + 1])
    if f.size == 1:
        lines[bool(st[0])][0].append(f[0])
        lines[bool(st[0])][1].append(d[0])
    return tuple((np.array(lines[k][0], float), np.array(lines[k][1], float)) for k in (True, False))


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
    branch_switching: bool = True,
    realised: bool = True,
    settle_periods: int = SETTLE_PERIODS,
    window_periods: int = WINDOW_PERIODS,
) -> SweepResult:
    """Sweep the excitation frequency over ``frequencies_Hz`` (module docstring).

    ``periodic_input`` fixes the waveform (e.g. ``SinePeriodic(2500, f)``); its frequency is
    replaced along the sweep. ``d0`` chooses the reference of eq. 21: ``"static"`` (static
    equilibrium at u = 0, the paper) or ``"mean"`` (the mean of each response: then d_rms is
    the standard deviation). ``branch_switching``: follow the period-doubled branches (needs
    ``stability``); ``realised``: integrate where no periodic response is stable
    (``settle_periods`` then ``window_periods`` excitation periods).
    """
    t_start = time.perf_counter()
    timings = {}
    freqs = np.unique(np.asarray(frequencies_Hz, dtype=float))
    if freqs.size < 1 or not np.all(np.isfinite(freqs)) or freqs[0] <= 0:
        raise ValueError("frequencies_Hz: need positive, finite frequencies")
    if d0 not in ("static", "mean"):
        raise ValueError(f"d0: 'static' (equilibrium at u = 0, the paper's eq. 21) or 'mean', got {d0!r}")
    setup = model_setup(params)
    first_input = periodic_input.with_frequency(freqs[0])
    divisor, m = response_layout(first_input, n_harmonics, use_symmetry)
    d0_static = float(static_equilibrium(params, 0.0).displacement_m)
    ref = d0_static if d0 == "static" else None

    # Starting point: a cold solve at the lowest frequency (quasi-static there).
    start = solve_native(params, first_input, n_harmonics, use_symmetry=use_symmetry, stability=False, tol=tol)
    p0 = math.log(first_input.omega * divisor)
    p_grid = np.log(2.0 * np.pi * freqs * divisor)
    dp_grid = float(np.min(np.diff(p_grid))) if freqs.size > 1 else 0.1
    h_max = max(min(0.5 * (p_grid[-1] - p0) / 4.0 + 1e-3, 0.25), 1e-3)
    h_max = min(h_max, max(dp_grid, H_MAX))
    prim = _Tracer(setup, periodic_input, divisor, m, tol, h_max, p_grid)
    z0 = prim.system.to_z(start.state)
    tz0, tp0 = prim.tangent(z0, p0, np.zeros(prim.n), 1.0)
    t0 = time.perf_counter()
    tr = prim.trace(z0, p0, tz0, tp0, p_lo=p0 - 1.0, p_hi=p_grid[-1], max_steps=max_branch_steps)
    # the starting point is the first requested frequency
    tr["grid"].insert(0, (0, z0, p0, start.iterations, 0, 0, 0.0))
    timings["primary_branch"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    an = _analyse(prim, tr, ref, PRIMARY, stability)
    timings["stability_and_bifurcations"] = time.perf_counter() - t0
    n_pts = max(len(tr["grid"]), 1)
    primary = _make_branch(prim, tr, an, PRIMARY, "periodic", ref, stability,
                           (time.perf_counter() - t_start) / n_pts)
    branches = [primary]
    steps_total = tr["steps"]
    # ---- period-doubled branches from the period-doubling points of the T/2 branch
    t0 = time.perf_counter()
    if branch_switching and stability and divisor == 2:
        pd_events = [e for e in an["events"] if e["kind"] == "period-doubling"]
        visited = [False] * len(pd_events)
        m_full = 2 * (2 * n_harmonics) + 1
        p_grid_full = p_grid - math.log(2.0)
        full = _Tracer(setup, periodic_input, 1, m_full, tol, h_max, p_grid_full)
        podd = _odd_projector(m_full)
        count = 0
        for i, ev in enumerate(pd_events):
            if visited[i]:
                continue
            visited[i] = True
            try:
                z1, p1, phi = _period_doubled_start(setup, prim, full, ev["z"], ev["p"])
                norm = math.sqrt(full.inner(phi, 0.0, phi, 0.0))
                tz1, tp1 = phi / norm, 0.0

                h_first = min(0.02, h_max)
                trf = full.trace(z1, p1, tz1, tp1, p_lo=p_grid_full[0], p_hi=p_grid_full[-1],
                                 max_steps=max_branch_steps, odd_projector=podd, h0=h_first)
            except (ContinuationError, HarmonicBalanceError, np.linalg.LinAlgError):
                continue
            steps_total += trf["steps"]
            if trf["stopped"]:  # came back to the T/2 branch: at which period-doubling point?
                p_end = float(trf["p"][-1]) + math.log(2.0)
                for j, ev2 in enumerate(pd_events):
                    if not visited[j] and abs(ev2["p"] - p_end) < 5e-3:
                        visited[j] = True
            count += 1
            name = "T" if count == 1 else f"T#{count}"
            anf = _analyse(full, trf, ref, name, stability, ignore_ends=True)
            branches.append(_make_branch(full, trf, anf, name, "period-doubled", ref, stability, 0.0))
    timings["period_doubled_branches"] = time.perf_counter() - t0
    # ---- the realised response at every requested frequency
    t0 = time.perf_counter()
    responses = _responses(params, periodic_input, freqs, branches, ref, d0_static, stability, realised,
                           settle_periods, window_periods)
    timings["realised_responses"] = time.perf_counter() - t0
    bands = _bands(branches, freqs, stability) if stability else []
    bifurcations = sorted([b for br in branches for b in br.bifurcations], key=lambda b: b.frequency_Hz)
    return SweepResult(
        points=primary.points,
        folds=primary.folds,
        d0_m=d0_static if d0 == "static" else float("nan"),
        d0_choice=d0,
        n_harmonics=int(n_harmonics),
        method="native",
        wall_time_s=time.perf_counter() - t_start,
        branch_steps=steps_total,
        branches=branches,
        responses=responses,
        bands=bands,
        bifurcations=bifurcations,
        timings_s=timings,
    )


def _responses(params, periodic_input, freqs, branches, ref, d0_static, stability, realised,
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


def _bands(branches, freqs, stability) -> list:
    """Bands of one kind over [f_min, f_max] from the stable intervals of all branches."""
    f_lo, f_hi = float(freqs[0]), float(freqs[-1])
    pieces = []   # (lo, hi, branch name, kind, segment, lo_edge, hi_edge)
    for br in branches:
        for lo, hi, seg, e1, e2 in br.stable_intervals:
            lo, hi = max(lo, f_lo), min(hi, f_hi)
            if hi > lo:
                pieces.append((lo, hi, br.name, br.kind, seg, e1, e2))
    edges = {f_lo: "range", f_hi: "range"}
    for lo, hi, _n, _k, _s, e1, e2 in pieces:
        edges.setdefault(lo, e1)
        edges.setdefault(hi, e2)
    cuts = sorted(edges)
    merged = [cuts[0]]
    for c in cuts[1:]:
        if c - merged[-1] > 1e-9 * max(c, 1.0):
            merged.append(c)
    cuts = merged
    bands = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        mid = 0.5 * (a + b)
        cover = [(p[2], p[3]) for p in pieces if p[0] <= mid <= p[1]]
        names = sorted(n for n, _k in cover)
        if not cover:
            kind = "quasi-periodic"
        elif len(cover) == 1:
            kind = cover[0][1]
        else:
            kind = "coexisting"
        e_a = edges.get(a, "range")
        e_b = edges.get(b, "range")
        if bands and bands[-1].kind == kind and bands[-1].branches == names:
            bands[-1].f_end_Hz = b
            bands[-1].end_edge = e_b
        else:
            bands.append(Band(a, b, kind, names, e_a, e_b))
    return bands


def period_doubled_solution(params: MembraneParameters, periodic_input: PeriodicInput, n_harmonics: int = 8,
                            f_start_Hz: float | None = None) -> PeriodicSolution | None:
    """The period-doubled periodic solution at the input's frequency (full period, 2N harmonics of f),
    found by branch switching in a sweep from ``f_start_Hz`` (default f/2); None when the
    frequency is not on a period-doubled branch. Stable or not: check ``.stable``."""
    f = periodic_input.frequency_Hz
    lo = 0.5 * f if f_start_Hz is None else float(f_start_Hz)
    grid = np.linspace(lo, f, max(3, int(math.ceil((f - lo) / (0.02 * f))) + 1))
    res = frequency_sweep(params, periodic_input, grid, n_harmonics=n_harmonics, realised=False)
    cands = [p for b in res.branches if b.name != PRIMARY for p in b.points
             if abs(p.frequency_Hz - f) <= 1e-9 * f]
    if not cands:
        return None
    stable = [p for p in cands if p.stable]
    return (stable or cands)[0].solution


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

    For the ``mousai`` and ``integration`` methods, which have no arclength continuation; a
    point that fails to converge is reported with ``stability = "failed"`` and NaN values
    rather than aborting the sweep. With ``integration``, a frequency without a periodic
    steady state (quasi-periodic response) is reported by :func:`realised_response` instead.
    """
    t_start = time.perf_counter()
    freqs = np.unique(np.asarray(frequencies_Hz, dtype=float))
    d0_static = float(static_equilibrium(params, 0.0).displacement_m)
    points: list[SweepPoint] = []
    responses: list[Response] = []
    guess = None
    for f in freqs:
        inp = periodic_input.with_frequency(f)
        t0 = time.perf_counter()
        try:
            if method == "integration":
                sol = solve_periodic(params, inp, method=method, n_harmonics=n_harmonics, stability=stability,
                                     max_time_s=60.0)
            else:
                sol = solve_periodic(params, inp, method=method, n_harmonics=n_harmonics, stability=stability,
                                     x_guess=guess)
        except SteadyStateError as exc:
            nan = float("nan")
            x0 = np.asarray(static_equilibrium(params, 0.0).state, float).reshape(3)
            rr = realised_response(params, inp, x0, d0_static)
            points.append(SweepPoint(f, nan, nan, nan, False, f"failed: {exc}"[:200], nan, 0,
                                     time.perf_counter() - t0, 0, None))
            responses.append(Response(float(f), rr.kind, rr.d_rms_m, rr.d_rms_min_m, rr.d_rms_max_m,
                                      "integration", [], rr.to_dict()))
            continue
        except Exception as exc:  # noqa: BLE001 - reported per point, sweep goes on
            nan = float("nan")
            points.append(SweepPoint(f, nan, nan, nan, False, f"failed: {exc}"[:200], nan, 0,
                                     time.perf_counter() - t0, 0, None))
            responses.append(Response(float(f), "failed", nan, nan, nan, "none", []))
            guess = None
            continue
        guess = sol.state if method != "integration" else None
        ref = d0_static if d0 == "static" else _d0(params, d0, sol)
        pt = _sweep_points([sol], ref, [sol.iterations], time.perf_counter() - t0, [0], stability)[0]
        points.append(pt)
        if method == "integration":
            kind = "period-doubled" if (sol.odd_harmonic_ratio() > 1e-3 and inp.u2_half_periodic()) else "periodic"
        else:
            kind = "periodic" if pt.stable else "unstable"
        responses.append(Response(float(f), kind, pt.d_rms_m, pt.d_rms_m, pt.d_rms_m, method, []))
    return SweepResult(points, [], d0_static if d0 == "static" else float("nan"), d0,
                       int(n_harmonics), method, time.perf_counter() - t_start, len(freqs),
                       responses=responses)


def classify_point(point: SweepPoint) -> str:
    """Human name of a point's stability (see :func:`classify_stability`)."""
    return classify_stability(point.solution.stability_multipliers if point.solution else None)
