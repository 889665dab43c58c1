"""Frequency sweeps: what a measurement sees at every frequency, by continuation and branch switching.

Branches. The periodic solutions are followed by pseudo-arclength continuation
(:class:`~dea_ros.solvers.branch_tracer.BranchTracer` on the compiled engine of
:mod:`.arclength_kernels`) in y = (z, p), z the scaled collocation values and p = ln(omega) of the
response, so turning points (folds, where the response jumps in an experiment) are passed, not
stopped at. The primary branch ``"T/2"`` has the period of u^2 (T/2 for a sine without offset,
eq. 6). Every requested frequency a branch crosses is solved exactly (Newton at fixed frequency
seeded from the two neighbouring branch points); inside a hysteresis band the same frequency
appears once per branch segment. Stability, bifurcations and the resonance peak along a branch:
:mod:`.branch_analysis`; period-doubled branches and the realised response at every requested
frequency: :mod:`.branches`. :attr:`SweepResult.bands` summarises the frequency range in bands of
one kind, with edges at the located bifurcations (:func:`bands`).

:func:`sweep_independent` is the sweep of the ``mousai`` and ``integration`` methods, which have no
continuation: each frequency is solved in turn, seeded by the previous solution.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..errors import ContinuationError, DeaRosError, HarmonicBalanceError, SteadyStateError
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from .branch_analysis import END_TOL, LOCATE_STEP_FACTOR, analyse_branch, make_branch
from .branch_tracer import BranchTracer, GridPoint
from .branches import period_doubled_branches, realised_responses
from .collocation import model_setup, response_layout
from .inputs import PeriodicInput
from .newton import solve_native
from .periodic_solution import PeriodicSolution
from .realised import SETTLE_PERIODS, WINDOW_PERIODS, realised_response
from .steady_state import solve_periodic
from .sweep_results import (
    KINDS,
    PRIMARY,
    Band,
    Bifurcation,
    Branch,
    Fold,
    Response,
    SweepPoint,
    SweepResult,
    classify_point,
    stability_segments,
    sweep_points,
)

__all__ = [
    "SweepPoint", "Fold", "Bifurcation", "Response", "Band", "Branch", "SweepResult", "frequency_sweep",
    "ContinuationError", "sweep_independent", "KINDS", "period_doubled_solution", "PRIMARY", "END_TOL",
    "stability_segments", "H_MAX", "LOCATE_STEP_FACTOR", "bands", "classify_point", "orbit_time_constants",
]

#: Largest arclength step (ln omega and scaled collocation values): steps also halve when the
#: tangent turns by more than 10 degrees, and every requested frequency is a station of the
#: stability analysis, so bands are not stepped over.
H_MAX = 0.05


def _d0(params: MembraneParameters, choice: str, sol: PeriodicSolution) -> float:
    if choice == "static":
        return float(static_equilibrium(params, 0.0).displacement_m)
    if choice == "mean":
        return sol.mean_displacement_m
    raise ValueError(f"d0: 'static' (equilibrium at u = 0, the paper's eq. 21) or 'mean', got {choice!r}")


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
    d0_static = float(static_equilibrium(params, 0.0).displacement_m)
    ref = d0_static if d0 == "static" else None
    prim, tr, divisor, p_grid = _trace_primary(params, setup, periodic_input, freqs, n_harmonics, use_symmetry, tol,
                                               max_branch_steps, timings)
    t0 = time.perf_counter()
    an = analyse_branch(prim, tr, ref, PRIMARY, stability)
    timings["stability_and_bifurcations"] = time.perf_counter() - t0
    primary = make_branch(prim, tr, an, PRIMARY, "periodic", ref, stability,
                          (time.perf_counter() - t_start) / max(len(tr.grid), 1))
    branches = [primary]
    steps_total = tr.steps
    t0 = time.perf_counter()
    if branch_switching and stability and divisor == 2:
        more, steps = period_doubled_branches(setup, prim, an.events, periodic_input, n_harmonics, tol, prim.h_max,
                                              p_grid, ref, stability, max_branch_steps)
        branches += more
        steps_total += steps
    timings["period_doubled_branches"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    responses = realised_responses(params, periodic_input, freqs, branches, ref, d0_static, stability, realised,
                                   settle_periods, window_periods)
    timings["realised_responses"] = time.perf_counter() - t0
    return SweepResult(
        points=primary.points, folds=primary.folds, d0_m=d0_static if d0 == "static" else float("nan"),
        d0_choice=d0, n_harmonics=int(n_harmonics), method="native", wall_time_s=time.perf_counter() - t_start,
        branch_steps=steps_total, branches=branches, responses=responses,
        bands=bands(branches, freqs, stability) if stability else [],
        bifurcations=sorted([b for br in branches for b in br.bifurcations], key=lambda b: b.frequency_Hz),
        timings_s=timings,
    )


def _trace_primary(params, setup, periodic_input, freqs, n_harmonics, use_symmetry, tol, max_branch_steps,
                   timings) -> tuple:
    """The primary (T/2) branch from a cold solve at the lowest frequency (quasi-static there), the first
    requested frequency the first grid point: (tracer, trace, period divisor, ln omega of the grid)."""
    first_input = periodic_input.with_frequency(freqs[0])
    divisor, m = response_layout(first_input, n_harmonics, use_symmetry)
    try:
        start = solve_native(params, first_input, n_harmonics, use_symmetry=use_symmetry, stability=False, tol=tol)
    except HarmonicBalanceError:
        # the lowest frequency next to a fold (a second pass's sines near resonance): the Jacobian is
        # ill-conditioned there, the residual reaches the floating-point floor while the Newton step stays
        # above tol; a step below 1e-8 (scaled) is still far more accurate than any measured RMS value
        # (as identify.frequency_points.point_solution); the arclength tracer is not hampered by the fold
        start = solve_native(params, first_input, n_harmonics, use_symmetry=use_symmetry, stability=False,
                             tol=max(tol, 1e-8))
    p0 = math.log(first_input.omega * divisor)
    p_grid = np.log(2.0 * np.pi * freqs * divisor)
    dp_grid = float(np.min(np.diff(p_grid))) if freqs.size > 1 else 0.1
    h_max = max(min(0.5 * (p_grid[-1] - p0) / 4.0 + 1e-3, 0.25), 1e-3)
    h_max = min(h_max, max(dp_grid, H_MAX))
    prim = BranchTracer(setup, periodic_input, divisor, m, tol, h_max, p_grid)
    z0 = prim.system.to_z(start.state)
    tz0, tp0 = prim.tangent(z0, p0, np.zeros(prim.n), 1.0)
    t0 = time.perf_counter()
    tr = prim.trace(z0, p0, tz0, tp0, p_lo=p0 - 1.0, p_hi=p_grid[-1], max_steps=max_branch_steps)
    tr.grid.insert(0, GridPoint(0, z0, p0, start.iterations, 0, 0, 0.0))
    timings["primary_branch"] = time.perf_counter() - t0
    return prim, tr, divisor, p_grid


def bands(branches, freqs, stability) -> list:
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


def orbit_time_constants(params: MembraneParameters, periodic_input: PeriodicInput, freqs,
                         stable_only: bool = False) -> dict:
    """{frequency (Hz, rounded to mHz): the slowest time constant of the periodic orbits there (s; the
    slowest branch where there are several, inf where one is unstable)} from a harmonic-balance sweep of
    ``periodic_input`` (its frequency replaced) over ``freqs`` with Floquet multipliers
    (:attr:`PeriodicSolution.slowest_time_constant_s`): near a resonance or a fold the approach to the orbit
    is slower than any time constant at rest. ``stable_only``: the slowest of the stable branches (where a
    run lands), inf where only unstable orbits are found. The frequencies a sweep does not reach (it failed,
    the continuation turned back at a fold and never came past it, or, with ``stable_only``, it passed them
    on an unstable branch only) are swept on their own, halved where that reaches none of them, down to
    single frequencies (left out when nothing is found): one frequency the continuation cannot pass does not
    lose the others' time constants."""
    freqs = sorted(float(f) for f in freqs)
    out: dict = {}
    try:
        sweep = frequency_sweep(params, periodic_input, np.asarray(freqs, float), n_harmonics=8,
                                branch_switching=False, realised=False)
    except (DeaRosError, ArithmeticError, ValueError, np.linalg.LinAlgError):   # not a ValueError on numpy 1.21
        sweep = None
    unstable: set = set()
    for pt in sweep.points if sweep is not None else ():
        tau = pt.solution.slowest_time_constant_s if pt.solution is not None else float("nan")
        key = round(float(pt.frequency_Hz), 3)
        if stable_only and math.isinf(tau):
            unstable.add(key)
        elif tau == tau:
            out[key] = max(out.get(key, 0.0), tau)
    missing = [f for f in freqs if round(f, 3) not in out]
    if missing and len(freqs) > 1:
        parts = [missing] if len(missing) < len(freqs) else [freqs[:len(freqs) // 2], freqs[len(freqs) // 2:]]
        for part in parts:
            out.update(orbit_time_constants(params, periodic_input, part, stable_only))
    elif missing:
        out.update({key: math.inf for key in unstable})
    return out


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
        pt = sweep_points([sol], ref, [sol.iterations], time.perf_counter() - t0, [0], stability)[0]
        points.append(pt)
        if method == "integration":
            kind = "period-doubled" if (sol.odd_harmonic_ratio() > 1e-3 and inp.u2_half_periodic()) else "periodic"
        else:
            kind = "periodic" if pt.stable else "unstable"
        responses.append(Response(float(f), kind, pt.d_rms_m, pt.d_rms_m, pt.d_rms_m, method, []))
    return SweepResult(points, [], d0_static if d0 == "static" else float("nan"), d0,
                       int(n_harmonics), method, time.perf_counter() - t_start, len(freqs),
                       responses=responses)
