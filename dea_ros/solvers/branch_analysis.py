"""What a traced branch shows: Floquet multipliers along it, located folds and bifurcations, maxima, stability.

Floquet multipliers are computed at every branch step and grid point (stacked,
:func:`~dea_ros.solvers.floquet.floquet_multipliers_batch`). Where the number of multipliers
outside the unit circle changes, the bifurcation is located along the branch where the crossing
multiplier has modulus 1 (Illinois method on |mu| - 1, to 1e-10; folds likewise on the p-component
of the tangent) and named by the critical multiplier: ``fold`` (+1, where the branch turns),
``period-doubling`` (-1) or ``torus`` (a complex pair, Neimark-Sacker). The resonance peak is the
extremum of d_rms along the branch (where d(d_rms)/ds = 0 between two branch steps, located by a
bracketed secant on the directional derivative), so it does not depend on the frequency grid.
:func:`analyse_branch` returns a :class:`BranchAnalysis`; :func:`make_branch` the
:class:`~dea_ros.solvers.sweep_results.Branch` of the sweep's result.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import HarmonicBalanceError
from .branch_tracer import BranchTrace, BranchTracer
from .floquet import floquet_multipliers_batch
from .sweep_results import PRIMARY, Bifurcation, Branch, Fold, d_rms_rows, sweep_points

__all__ = ["END_TOL", "LOCATE_STEP_FACTOR", "illinois", "BranchAnalysis", "analyse_branch", "make_branch", "rms_of"]

#: Folds and stability changes of a period-doubled branch closer than this (in ln f) to its ends
#: are the pitchforks it leaves and rejoins the T/2 branch at, not features of the branch.
END_TOL = 1e-4

#: Bifurcations are located with this many times the default Magnus steps (:func:`magnus_steps`).
LOCATE_STEP_FACTOR = 4


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


def illinois(fn, a: float, b: float, fa: float, fb: float, f_tol: float, width: float, max_evals: int):
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


def _rms_and_slopes(tracer: BranchTracer, zs, tzs, d0) -> tuple:
    """d_rms (eq. 21) of the scaled unknowns zs (rows) and, when the unit tangents tzs (rows) are
    given, d(d_rms)/ds along them (the gradient of d_rms w.r.t. z dotted with tz; else None)."""
    m = tracer.m
    scale_d = tracer.setup.scale[0]
    rms, dev, _mean = d_rms_rows(np.asarray(zs)[:, :m] * scale_d, d0)
    if tzs is None:
        return rms, None
    along = scale_d * np.einsum("ij,ij->i", dev, np.asarray(tzs)[:, :m])
    return rms, np.divide(along, m * rms, out=np.zeros_like(rms), where=rms > 0)


def rms_of(tracer: BranchTracer, z, d0) -> float:
    """d_rms (eq. 21) of one solution (scaled unknowns z)."""
    return float(_rms_and_slopes(tracer, z[None], None, d0)[0][0])


@dataclass
class BranchAnalysis:
    """Stations (branch steps and grid points in arclength order) with their multipliers, located folds and
    events (stability changes), local maxima of d_rms, stable intervals and the d_rms of every step."""

    stations: list          # (step k, fraction, z, p, grid index or None)
    mus: np.ndarray         # (S, 3) multipliers per station (zeros without stability)
    counts: list            # multipliers outside the unit circle per station
    mu_grid: list           # multipliers per grid point
    events: list            # located stability changes (dicts: k, tau, kind, z, p, mu, stable_before, fold, ...)
    folds: list             # located folds (dicts: k, tau, z, p, direction)
    maxima: list            # local maxima of d_rms and ends of stable pieces
    intervals: list         # stable intervals (f_lo, f_hi, segment, lo_edge, hi_edge)
    curve_d: np.ndarray     # d_rms at every branch step


def _stations_and_multipliers(tracer: BranchTracer, tr: BranchTrace, stability: bool) -> tuple:
    """Stations in arclength order and their multipliers: (stations, mus, mu_grid, counts)."""
    setup = tracer.setup
    zs, ps = tr.z, tr.p
    stations = [(k, 0.0, zs[k], float(ps[k]), None) for k in range(zs.shape[0])]
    stations += [(k, fr, zg, pg, j) for j, (_g, zg, pg, _it, _seg, k, fr) in enumerate(tr.grid)]
    stations.sort(key=lambda s: (s[0], s[1]))
    mu_grid = [None] * len(tr.grid)
    if stability:
        states = np.stack([s[2] for s in stations]).reshape(len(stations), 3, tracer.m) * \
            tracer.system.scale[None, :, None]
        periods = np.array([2.0 * np.pi / math.exp(s[3]) for s in stations])
        # h rho <= 0.5, >= 32 Magnus steps: |mu| to ~1e-5 next to the resonance (floquet.MAGNUS_H_RHO),
        # for the reported points and to detect where the stability changes
        mus = floquet_multipliers_batch(setup.model, states, periods, tracer.periodic_input, tracer.divisor,
                                        scale=setup.scale, h_rho=0.5, min_steps=32)
        for i, st in enumerate(stations):
            if st[4] is not None:
                mu_grid[st[4]] = mus[i]
    else:
        mus = np.zeros((len(stations), 3))
    counts = np.count_nonzero(np.abs(mus) > 1.0, axis=1).tolist()   # multipliers outside, per station
    return stations, mus, mu_grid, counts


def _branch_ends(tr: BranchTrace) -> list:
    """ln omega of the ends of a period-doubled branch (its pitchforks with the T/2 branch)."""
    return [float(tr.p[0])] + ([float(tr.p[-1])] if tr.stopped else [])


def _locate_folds(tracer: BranchTracer, tr: BranchTrace, ignore_ends: bool) -> list:
    """Folds (turning points), located on tp = 0 (tp of the unit tangent, continuous along the branch)."""
    folds = []
    for k in tr.fold_steps:
        s_lo = np.sign(tr.tp[k])

        def tangent_p(tau, k=k):
            zm, pm = tracer.at(tr, k, tau)
            return tracer.tangent(zm, pm, tr.tz[k], tr.tp[k])[1], (zm, pm)
        try:
            tau, _tp, (zf, pf) = illinois(tangent_p, 0.0, 1.0, float(tr.tp[k]), float(tr.tp[k + 1]),
                                          f_tol=1e-10, width=2.0 ** -11, max_evals=11)
        except (HarmonicBalanceError, np.linalg.LinAlgError):
            tau, zf, pf = 0.5, tr.z[k], float(tr.p[k])
        folds.append({"k": k, "tau": tau, "z": zf, "p": pf,
                      "direction": "forward->backward" if s_lo > 0 else "backward->forward"})
    if ignore_ends:  # the pitchfork turning points where a period-doubled branch starts / ends
        ends = _branch_ends(tr)
        folds = [f for f in folds if min(abs(f["p"] - e) for e in ends) > END_TOL]
    return folds


def _locate_event(tracer: BranchTracer, tr: BranchTrace, stations, mus, counts, i: int, folds: list):
    """The stability change between stations i and i + 1, located where the crossing multiplier has modulus
    1 (Illinois on its modulus - 1; one Magnus step count for all evaluations of a location, |mu|
    continuous along it, LOCATE_STEP_FACTOR times the default): an event dict, or None when it cannot be
    located."""
    (ka, ta, *_), (kb, tb, *_) = stations[i], stations[i + 1]
    k = ka
    lo, hi = ta, (tb if kb == ka else 1.0)
    c_lo = counts[i]
    index = min(c_lo, counts[i + 1])
    fixed_steps = []

    def crossing(tau):
        zm, pm = tracer.at(tr, k, tau)
        if not fixed_steps:
            fixed_steps.append(LOCATE_STEP_FACTOR * tracer.magnus_steps(zm, pm))
        mu = tracer.multipliers(zm, pm, fixed_steps[0])
        return _crossing_distance(mu, index), (zm, pm, mu)
    try:
        tau, _f, (zc, pc, mu_c) = illinois(
            crossing, lo, hi, _crossing_distance(mus[i], index), _crossing_distance(mus[i + 1], index),
            f_tol=1e-10, width=(hi - lo) * 1e-12, max_evals=12)
    except (HarmonicBalanceError, np.linalg.LinAlgError):
        return None
    kind = _event_kind(mu_c)
    fold = None
    if kind == "branch point":
        near = [f for f in folds if abs(f["p"] - pc) < 1e-4 and abs(f["k"] - k) <= 1]
        if near:
            kind, fold = "fold", near[0]
            fold["event"] = True
    return {"k": k, "tau": tau, "kind": kind, "z": zc, "p": pc, "mu": _critical(mu_c), "stable_before": c_lo == 0,
            "fold": fold, "count_before": c_lo, "count_after": counts[i + 1]}


def _locate_events(tracer, tr, stations, mus, counts, folds, ignore_ends: bool) -> list:
    """Every stability change along the branch (:func:`_locate_event`), ends of a period-doubled branch
    left out with ``ignore_ends``."""
    events = []
    for i in range(len(stations) - 1):
        if counts[i] == counts[i + 1]:
            continue
        event = _locate_event(tracer, tr, stations, mus, counts, i, folds)
        if event is None:
            continue
        if ignore_ends and min(abs(event["p"] - e) for e in _branch_ends(tr)) <= END_TOL:
            continue
        events.append(event)
    return events


def _locate_maxima(tracer: BranchTracer, tr: BranchTrace, d0, name: str, stability: bool) -> tuple:
    """Local maxima of d_rms along the arclength, where d(d_rms)/ds = grad . t changes sign: (maxima, d_rms
    of every step)."""
    def slope(z, tz):
        return float(_rms_and_slopes(tracer, z[None], tz[None], d0)[1][0])

    maxima = []
    curve_d, slopes = _rms_and_slopes(tracer, tr.z, tr.tz, d0)
    slopes = slopes.tolist()
    for k in range(tr.z.shape[0] - 1):
        if not (slopes[k] > 0.0 >= slopes[k + 1]):
            continue

        def slope_at(tau, k=k):
            zc, pc = tracer.at(tr, k, tau)
            tzc, _tpc = tracer.tangent(zc, pc, tr.tz[k], tr.tp[k])
            return slope(zc, tzc), (zc, pc)
        try:
            _tau, _f, (zc, pc) = illinois(slope_at, 0.0, 1.0, slopes[k], slopes[k + 1],
                                          f_tol=1e-12 * max(abs(slopes[k]), 1e-30), width=1e-9, max_evals=30)
        except (HarmonicBalanceError, np.linalg.LinAlgError):
            zc, pc = tr.z[k], float(tr.p[k])
        stable_here = True
        if stability:
            stable_here = _n_outside(tracer.multipliers(zc, pc)) == 0
        maxima.append({"frequency_Hz": tracer.excitation_Hz(pc), "d_rms_m": rms_of(tracer, zc, d0),
                       "stable": stable_here, "branch": name, "k": k})
    return maxima, curve_d


def _edge_maximum(tracer, tr, obj, d0, name, k, edge) -> dict:
    """The end of a stable piece at a fold or bifurcation ``obj`` as a candidate maximum."""
    return {"frequency_Hz": tracer.excitation_Hz(obj.get("p", tr.p[0])), "d_rms_m": rms_of(tracer, obj["z"], d0),
            "stable": True, "branch": name, "k": k, "edge": edge}


def _stable_intervals(tracer, tr, stations, counts, events, folds, d0, name, stability, ignore_ends) -> tuple:
    """Stable intervals along the branch (arclength order), bounded by events and folds, and the ends of
    the stable pieces as candidate maxima: (intervals, maxima)."""
    marks = sorted([(e["k"], e["tau"], "event", e) for e in events] +
                   [(f["k"], f["tau"], "fold", f) for f in folds if not f.get("event")], key=lambda x: (x[0], x[1]))
    intervals, maxima = [], []
    i0 = 0
    if ignore_ends:  # judge the start beyond the pitchfork (a multiplier is 1 there)
        far = [i for i, st in enumerate(stations) if abs(st[3] - float(tr.p[0])) > END_TOL]
        i0 = far[0] if far else 0
    stable_now = (counts[i0] == 0) if stability else True
    f_start = tracer.excitation_Hz(tr.p[0])
    edge_start = "range" if name == PRIMARY else "period-doubling"
    seg = 0
    start_obj = {"z": tr.z[0]}
    for k, _tau, what, obj in marks:
        f_here = tracer.excitation_Hz(obj["p"])
        edge = obj["kind"] if what == "event" else "fold"
        if stable_now:
            intervals.append((min(f_start, f_here), max(f_start, f_here), seg, edge_start, edge))
            for e_name, e_obj in ((edge_start, start_obj), (edge, obj)):   # ends of a stable piece: maxima?
                if e_name != "range":
                    maxima.append(_edge_maximum(tracer, tr, e_obj, d0, name, k, e_name))
        if what == "event":
            stable_now = obj["count_after"] == 0
        if what == "fold" or (what == "event" and obj.get("fold") is not None):
            seg += 1
        f_start, edge_start, start_obj = f_here, edge, obj
    if stable_now:
        f_end = tracer.excitation_Hz(tr.p[-1])
        end_edge = "period-doubling" if (name != PRIMARY and tr.stopped) else "range"
        intervals.append((min(f_start, f_end), max(f_start, f_end), seg, edge_start, end_edge))
        if edge_start != "range":
            maxima.append(_edge_maximum(tracer, tr, start_obj, d0, name, -1, edge_start))
    return intervals, maxima


def analyse_branch(tracer: BranchTracer, tr: BranchTrace, d0, name: str, stability: bool,
                   ignore_ends: bool = False) -> BranchAnalysis:
    """Multipliers at every station, bifurcations (located), local maxima of d_rms, stable intervals
    (module docstring); ``ignore_ends``: a period-doubled branch, whose ends are its pitchforks."""
    stations, mus, mu_grid, counts = _stations_and_multipliers(tracer, tr, stability)
    folds = _locate_folds(tracer, tr, ignore_ends)
    events = _locate_events(tracer, tr, stations, mus, counts, folds, ignore_ends) if stability else []
    maxima, curve_d = _locate_maxima(tracer, tr, d0, name, stability)
    intervals, edge_maxima = _stable_intervals(tracer, tr, stations, counts, events, folds, d0, name, stability,
                                               ignore_ends)
    return BranchAnalysis(stations, mus, counts, mu_grid, events, folds, maxima + edge_maxima, intervals, curve_d)


def make_branch(tracer: BranchTracer, tr: BranchTrace, an: BranchAnalysis, name: str, kind: str, d0, stability: bool,
                t_points: float) -> Branch:
    """The :class:`Branch` of a traced and analysed branch (points at the requested frequencies)."""
    sols = []
    grid = tr.grid
    states = (np.stack([g[1] for g in grid]).reshape(len(grid), 3, tracer.m) * tracer.system.scale[None, :, None]
              if grid else [])
    for j, (_g, zg, pg, it, _seg, _k, _fr) in enumerate(grid):
        sol = tracer.solution(zg, pg, it, states[j])
        if stability:
            sol.multipliers = an.mu_grid[j]
        sols.append(sol)
    points = sweep_points(sols, d0, [g[3] for g in tr.grid], t_points, [g[4] for g in tr.grid], stability, name)
    folds = [Fold(tracer.excitation_Hz(f["p"]), rms_of(tracer, f["z"], d0), f["direction"], name)
             for f in an.folds]
    bifs = [Bifurcation(e["kind"], tracer.excitation_Hz(e["p"]), rms_of(tracer, e["z"], d0),
                        name, e["mu"], e["stable_before"]) for e in an.events if e["fold"] is None]
    for f_raw, f in zip(an.folds, folds):
        ev = [e for e in an.events if e["fold"] is f_raw]
        bifs.append(Bifurcation("fold", f.frequency_Hz, f.d_rms_m, name, complex(1.0, 0.0),
                                bool(ev[0]["stable_before"]) if ev else False))
    bifs.sort(key=lambda b: b.frequency_Hz)
    curve_f = np.array([tracer.excitation_Hz(p) for p in tr.p])
    counts = np.array([c for s, c in zip(an.stations, an.counts) if s[4] is None])
    curve_stable = counts == 0 if stability else np.ones(counts.size, bool)
    return Branch(name=name, kind=kind, period_divisor=tracer.divisor, points=points, folds=folds,
                  bifurcations=bifs, curve_frequency_Hz=curve_f, curve_d_rms_m=an.curve_d,
                  curve_stable=curve_stable, maxima=an.maxima, stable_intervals=an.intervals,
                  steps=tr.steps)
