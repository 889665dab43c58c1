"""The results of a frequency sweep: points, folds, bifurcations, realised responses, bands, branches.

:class:`SweepResult` holds what :func:`~dea_ros.solvers.sweep.frequency_sweep` found: the primary
(T/2) branch at the requested frequencies (:class:`SweepPoint`), every continued :class:`Branch`
with its folds (:class:`Fold`) and located :class:`Bifurcation`s, the response a measurement sees at
each requested frequency (:class:`Response`) and the frequency range in :class:`Band`s of one kind.
:func:`stability_segments` turns a branch into the stable / unstable polylines a plot draws.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .floquet import classify_stability
from .periodic_solution import PeriodicSolution, truncation_ratios

__all__ = [
    "KINDS", "PRIMARY", "SweepPoint", "Fold", "Bifurcation", "Response", "Band", "Branch", "SweepResult",
    "d_rms_rows", "sweep_points", "stability_segments", "classify_point",
]

#: Kinds of realised response, in the order of the band summary.
KINDS = ("periodic", "period-doubled", "quasi-periodic", "coexisting")

PRIMARY = "T/2"


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
    """What a frequency sweep found (module docstring)."""

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


def d_rms_rows(d: np.ndarray, d0_m) -> tuple:
    """(d_rms (eq. 21), d - d0, mean) of displacement rows d (K, M) around d0_m (None: each row's mean)."""
    mean = d.sum(axis=1) / d.shape[1]
    dev = d - (mean[:, None] if d0_m is None else d0_m)
    return np.sqrt(np.einsum("ij,ij->i", dev, dev) / d.shape[1]), dev, mean


def sweep_points(sols: list, d0_m, iterations, wall_time_s: float, segments, stability: bool,
                 branch: str = PRIMARY) -> list:
    """SweepPoints of periodic solutions with the same number of points: d_rms around d0_m (eq. 21;
    None: around each one's mean), stability from each one's stability multipliers."""
    if not sols:
        return []
    d = np.stack([sol.state[0] for sol in sols])
    d_rms, _dev, mean = d_rms_rows(d, d0_m)
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


# ----------------------------------------------------------------------------- sweep
def stability_segments(branch: Branch, bifurcations) -> tuple:
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


def classify_point(point: SweepPoint) -> str:
    """Human name of a point's stability (see :func:`classify_stability`)."""
    return classify_stability(point.solution.stability_multipliers if point.solution else None)
