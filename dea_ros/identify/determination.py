"""What the data determine: per parameter identified / poorly determined / not identified, its 95 %
interval, and which records determine it (issue 21, item 4).

The status follows the half-width of the 95 % interval relative to the value (``relative_ci``):
up to ``IDENTIFIED_REL_CI`` (50 %) "identified", below ``SIGN_KNOWN_REL_CI`` (100 %, the sign is
known) "poorly determined", otherwise "not identified" (as :mod:`~dea_ros.identify.refinement`
decides for sigma_h''(1)).

Which records determine a parameter: from the weighted Jacobian J of the fit whose intervals are
reported (rows grouped by record: the static points, each step, each sine record), the Fisher
information F = J^T J and, for every record g, the information without it, F - J_g^T J_g. The
standard error of parameter i without record g against with all records,
sqrt([(F - J_g^T J_g)^-1]_ii / [F^-1]_ii) - 1, is how much wider its interval would be without
that record (correlations included: a record that breaks the eta1/eta2 trade-off counts even if
it hardly sees either alone). Records that widen it by more than ``DETERMINING_WIDENING`` (5 %) are
listed as determining it, the widest first; when none does alone the information is spread over
many records and the three that matter most are named.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ParameterDetermination", "parameter_status", "record_widening", "inverse_diagonal", "determine_parameters",
           "IDENTIFIED_REL_CI", "SIGN_KNOWN_REL_CI", "DETERMINING_WIDENING", "SINGULAR_EIGENVALUE_RATIO"]

IDENTIFIED_REL_CI = 0.5
SIGN_KNOWN_REL_CI = 1.0
DETERMINING_WIDENING = 0.05
#: An information matrix's eigenvalue below this fraction of its largest is zero: a symmetric matrix's
#: eigenvalues are accurate to about machine epsilon times its norm (Weyl), so 1e-14 (~45 epsilon) can
#: still be told from zero. (1e-13 until session 18 called sigma_h'''(1) unseen on a softening membrane
#: where it is only poorly determined -- eigenvalue ratio 8.9e-14 -- and k1 with it.)
SINGULAR_EIGENVALUE_RATIO = 1e-14


@dataclass
class ParameterDetermination:
    """One parameter: value, 95 % interval, status and the records that determine it."""

    name: str                       # as in the statistics (SI unit in the name)
    value: float
    ci_low: float
    ci_high: float
    relative_ci: float              # half-width of the 95 % interval / |value|
    status: str                     # "identified", "poorly determined", "not identified"
    #: (record, relative widening of the interval without it; inf: not determined without it), widest first
    determined_by: list = field(default_factory=list)
    spread: bool = False            # no record alone widens the interval by DETERMINING_WIDENING
    note: str = ""

    def to_dict(self) -> dict:
        return {"value": self.value, "ci95": [self.ci_low, self.ci_high], "relative_ci": self.relative_ci,
                "status": self.status, "spread_over_many_records": self.spread,
                "determined_by": [{"record": r, "widening_without_it": w} for r, w in self.determined_by],
                "note": self.note}


def parameter_status(relative_ci: float) -> str:
    """identified / poorly determined / not identified from the relative 95 % half-width."""
    if not math.isfinite(relative_ci) or relative_ci >= SIGN_KNOWN_REL_CI:
        return "not identified"
    return "identified" if relative_ci <= IDENTIFIED_REL_CI else "poorly determined"


def inverse_diagonal(info: np.ndarray) -> np.ndarray:
    """diag(info^-1), inf where info is singular (a direction no remaining record sees: an eigenvalue below
    :data:`SINGULAR_EIGENVALUE_RATIO` of the largest)."""
    w, v = np.linalg.eigh(info)
    if w[-1] <= 0 or w[0] <= SINGULAR_EIGENVALUE_RATIO * w[-1]:
        out = np.full(info.shape[0], np.inf)
        good = w > SINGULAR_EIGENVALUE_RATIO * max(w[-1], 0.0)
        seen = np.abs(v[:, ~good]).max(axis=1) < 1e-4 if np.any(~good) else np.ones(info.shape[0], bool)
        part = (v[:, good] ** 2 / w[good]).sum(axis=1)
        out[seen] = part[seen]
        return out
    return (v ** 2 / w).sum(axis=1)


def record_widening(jacobian, row_records, names) -> dict:
    """name -> {record: relative widening of its 95 % interval without that record} (module docstring)."""
    jac = np.asarray(jacobian, float)
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    jac = jac / scale
    info = jac.T @ jac
    base = inverse_diagonal(info)
    rows = np.asarray(row_records, dtype=object)
    out = {n: {} for n in names}
    for rec in dict.fromkeys(row_records):
        jg = jac[rows == rec]
        without = inverse_diagonal(info - jg.T @ jg)
        for i, n in enumerate(names):
            if not math.isfinite(base[i]):
                continue
            out[n][rec] = math.inf if not math.isfinite(without[i]) else \
                math.sqrt(max(without[i] / base[i], 1.0)) - 1.0
    return out


def _determining(widening: dict) -> tuple:
    """(records that determine the parameter, widest first; spread over many records)."""
    ranked = sorted(widening.items(), key=lambda kv: -kv[1])
    main = [(r, float(w)) for r, w in ranked if w > DETERMINING_WIDENING]
    if main:
        return main, False
    return [(r, float(w)) for r, w in ranked[:3]], True


def determine_parameters(statistics, jacobian=None, row_records=(), notes: dict | None = None) -> list:
    """One :class:`ParameterDetermination` per parameter of ``statistics`` (a ParameterStatistics);
    with the fit's weighted ``jacobian`` and ``row_records`` also the records that determine each."""
    if statistics is None:
        return []
    names = tuple(statistics.names)
    widening = record_widening(jacobian, row_records, names) if jacobian is not None and len(row_records) else {}
    out = []
    for i, n in enumerate(names):
        rel = float(statistics.relative_ci[i])
        det, spread = _determining(widening.get(n, {})) if widening.get(n) else ([], False)
        out.append(ParameterDetermination(n, float(statistics.values[i]), float(statistics.ci_low[i]),
                                          float(statistics.ci_high[i]), rel, parameter_status(rel), det, spread,
                                          (notes or {}).get(n, "")))
    return out
