"""Quality and trust of a fit: error indices (Tables III-IV), static errors, parameter statistics.

* :func:`step_error_indices` -- IAE [mm s], ISE [mm^2 s], ITAE [mm s^2] of a step fit (Table III),
  integrated with the trapezoidal rule over the record; ITAE weights |e| by the time since the step.
* :func:`resonance_peak_Hz` -- frequency of the RMS maximum of a frequency response, refined by a
  parabola through the largest sample and its neighbours (Table IV).
* :func:`measured_resonance_peak` -- the resonance peak of measured data, only when the data bracket
  it densely (neighbours within 1 % in frequency on both sides); otherwise "not measured".
* :func:`static_errors_um` -- RMS and maximum static error in micrometres (Fig. 6, section IV-B).
* :func:`parameter_statistics` -- standard errors, confidence intervals and the correlation matrix
  of fitted parameters from the residual Jacobian at the optimum, with the residual variance
  estimated as SSR / (n - p) (Gauss-Newton / linearised covariance ``s^2 (J^T J)^-1``), and
  warnings where the data cannot pin a parameter down (relative CI above a limit, |correlation|
  above a limit, or a rank-deficient Jacobian).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats as scipy_stats

__all__ = [
    "ParameterStatistics",
    "parameter_statistics",
    "step_error_indices",
    "resonance_peak_Hz",
    "measured_resonance_peak",
    "PEAK_SPACING_LIMIT",
    "static_errors_um",
    "linear_combination_ci",
    "RELATIVE_CI_LIMIT",
    "CORRELATION_LIMIT",
]

#: A parameter whose 95 % CI half-width exceeds this fraction of its value is "not pinned down".
RELATIVE_CI_LIMIT = 0.5
#: Pairs of parameters more correlated than this trade off against each other.
CORRELATION_LIMIT = 0.99


@dataclass
class ParameterStatistics:
    """Linearised statistics of fitted parameters at the optimum."""

    names: tuple
    values: np.ndarray
    std_error: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    relative_ci: np.ndarray     # CI half-width / |value| (inf when not identifiable)
    correlation: np.ndarray
    residual_std: float         # sqrt(SSR / (n - p)), in residual units
    dof: int
    rank: int
    singular_values: np.ndarray  # of the column-normalised Jacobian, descending
    confidence: float = 0.95
    warnings: list = field(default_factory=list)
    #: per parameter: True where it was fitted in ln (its interval is multiplicative); empty: none
    log_parameters: tuple = ()

    def is_log(self) -> np.ndarray:
        """(p,) bool: the parameters fitted in ln."""
        flags = np.zeros(len(self.names), dtype=bool)
        if len(self.log_parameters) == len(self.names):
            flags[:] = np.asarray(self.log_parameters, dtype=bool)
        return flags

    def covariance(self) -> np.ndarray | None:
        """Linearised covariance (p, p) in the fit's coordinates: ln(value) for the log parameters
        (:meth:`is_log`), the value itself for the others; from the standard errors and the
        correlation matrix. None when a parameter is not determined (infinite standard error)."""
        values = np.asarray(self.values, float)
        se = np.asarray(self.std_error, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(self.is_log(), se / np.abs(values), se)
        if not np.all(np.isfinite(s)):
            return None
        return np.asarray(self.correlation, float) * np.outer(s, s)

    def as_dict(self) -> dict:
        """JSON-friendly summary (CI, relative CI, correlation)."""
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        return {
            "confidence": self.confidence,
            "residual_std": num(self.residual_std),
            "dof": int(self.dof),
            "rank": int(self.rank),
            "parameters": {
                n: {"value": num(v), "std_error": num(s), "ci_low": num(lo), "ci_high": num(hi),
                    "relative_ci": num(r)}
                for n, v, s, lo, hi, r in zip(self.names, self.values, self.std_error, self.ci_low,
                                              self.ci_high, self.relative_ci)
            },
            "correlation": [[num(c) for c in row] for row in self.correlation],
            "warnings": list(self.warnings),
        }


def parameter_statistics(
    jacobian,
    residuals,
    names,
    values,
    log_parameters: bool = False,
    confidence: float = 0.95,
    relative_ci_limit: float = RELATIVE_CI_LIMIT,
    correlation_limit: float = CORRELATION_LIMIT,
    rcond: float = 1e-12,
    context: str = "",
) -> ParameterStatistics:
    """Standard errors, CIs and correlations from the Jacobian of the residuals at the optimum.

    ``jacobian`` (n, p) is d residual / d parameter, or d residual / d ln(parameter)
    where ``log_parameters`` is True (a bool for all, or one per parameter; the CI is
    then ``value * exp(+-t s_ln)``, asymmetric).
    Columns are normalised before the SVD, so ``rcond`` (relative singular-value
    threshold) detects directions the data do not see whatever the units; those
    parameters get infinite standard errors. Correlations use a minimally
    regularised inverse, so a rank-deficient pair still shows |r| -> 1.
    """
    jac = np.asarray(jacobian, dtype=float)
    res = np.asarray(residuals, dtype=float).reshape(-1)
    values = np.asarray(values, dtype=float).reshape(-1)
    n, p = jac.shape
    names = tuple(names)
    if len(names) != p or values.size != p:
        raise ValueError(f"names/values must have {p} entries (Jacobian columns)")
    no_dof = n <= p
    dof = max(n - p, 1)
    s2 = float(res @ res) / dof if not no_dof else float("inf")
    sv, rank, var, unseen, corr = _linearised_covariance(jac, s2, rcond)
    with np.errstate(invalid="ignore"):
        std_internal = np.sqrt(np.where(unseen | no_dof, np.inf, var))
    t = float(scipy_stats.t.ppf(0.5 + confidence / 2.0, dof))
    is_log = np.broadcast_to(np.asarray(log_parameters, dtype=bool), (p,))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        lo = np.where(is_log, values * np.exp(-t * std_internal), values - t * std_internal)
        hi = np.where(is_log, values * np.exp(t * std_internal), values + t * std_internal)
        std_error = np.where(is_log, np.abs(values) * std_internal, std_internal)
        rel = np.where(is_log, (hi - lo) / (2.0 * np.abs(values)), t * std_internal / np.abs(values))
    rel = np.where(np.isfinite(rel), rel, np.inf)
    warnings = _identifiability_warnings(names, rel, corr, rank, unseen, n, no_dof, confidence, relative_ci_limit,
                                         correlation_limit, f"{context}: " if context else "")
    return ParameterStatistics(
        names=names, values=values, std_error=std_error, ci_low=lo, ci_high=hi, relative_ci=rel,
        correlation=corr, residual_std=math.sqrt(s2), dof=0 if no_dof else dof, rank=rank,
        singular_values=sv, confidence=confidence, warnings=warnings,
        log_parameters=tuple(bool(x) for x in is_log),
    )


def _linearised_covariance(jac: np.ndarray, s2: float, rcond: float) -> tuple:
    """(singular values, rank, variances, unseen, correlation) of the Jacobian's linearised covariance
    s^2 (J^T J)^-1: columns normalised before the SVD; parameters along directions the data do not see
    (``unseen``) get no finite variance; correlations from a minimally regularised inverse."""
    norms = np.linalg.norm(jac, axis=0)
    norms_safe = np.where(norms > 0, norms, 1.0)
    jn = jac / norms_safe
    _u, sv, vt = np.linalg.svd(jn, full_matrices=False)
    smax = sv[0] if sv.size and sv[0] > 0 else 1.0
    keep = sv > rcond * smax
    rank = int(np.count_nonzero(keep))
    # Covariance of the normalised parameters (pseudo-inverse on the identifiable subspace).
    inv_s2 = np.where(keep, 1.0 / np.where(keep, sv, 1.0) ** 2, 0.0)
    cov_n = (vt.T * inv_s2) @ vt
    var = s2 * np.diag(cov_n) / norms_safe**2
    null = vt[~keep]
    unseen = (norms == 0)
    if null.size:
        unseen |= np.any(np.abs(null) > 1e-6, axis=0)
    # Correlations from a ridge-regularised inverse (finite even when rank-deficient).
    ridge = (1e-10 * smax) ** 2
    cov_r = (vt.T * (1.0 / (sv**2 + ridge))) @ vt
    d = np.sqrt(np.diag(cov_r))
    corr = cov_r / np.outer(d, d)
    np.fill_diagonal(corr, 1.0)
    return sv, rank, var, unseen, corr


def _identifiability_warnings(names, rel, corr, rank, unseen, n, no_dof, confidence, relative_ci_limit,
                              correlation_limit, prefix) -> list:
    """Where the data cannot pin a parameter down: no degrees of freedom, rank deficiency, a wide
    interval, a pair that trades off."""
    p = len(names)
    warnings = []
    if no_dof:
        warnings.append(f"{prefix}{n} residual(s) for {p} parameters: no degrees of freedom left, the "
                        "uncertainty of the parameters is unknown (add data)")
    if rank < p:
        lost = [nm for nm, u in zip(names, unseen) if u]
        warnings.append(
            f"{prefix}the data determine only {rank} combination(s) of the {p} parameters "
            f"({', '.join(lost)} cannot be pinned down individually)"
        )
    for nm, r in zip(names, rel):
        if r > relative_ci_limit and not ((rank < p or no_dof) and not math.isfinite(r)):
            warnings.append(
                f"{prefix}{nm} is poorly determined: {100 * confidence:.0f} % CI half-width is "
                f"{'infinite' if not math.isfinite(r) else f'{100 * r:.0f} %'} of its value "
                f"(limit {100 * relative_ci_limit:.0f} %)"
            )
    for i in range(p):
        for j in range(i + 1, p):
            if abs(corr[i, j]) > correlation_limit:
                warnings.append(
                    f"{prefix}{names[i]} and {names[j]} trade off (correlation {corr[i, j]:+.4f}): "
                    "the data constrain a combination of them, not each one"
                )
    return warnings


def linear_combination_ci(stats: ParameterStatistics, weights: dict):
    """(value, CI low, CI high, relative half-width) of sum_i w_i p_i over fitted parameters
    (``weights``: name -> w_i), from their linearised covariance, at the statistics' confidence.
    None when a name is not among the fitted parameters (or a parameter was fitted in log)."""
    if stats is None or any(n not in stats.names for n in weights):
        return None
    idx = [stats.names.index(n) for n in weights]
    w = np.array(list(weights.values()), float)
    se = np.asarray(stats.std_error, float)[idx]
    if not np.all(np.isfinite(se)):
        return (float(w @ np.asarray(stats.values, float)[idx]), -np.inf, np.inf, float("inf"))
    cov = np.asarray(stats.correlation, float)[np.ix_(idx, idx)] * np.outer(se, se)
    value = float(w @ np.asarray(stats.values, float)[idx])
    t = float(stats_t(stats))
    half = float(t * math.sqrt(max(float(w @ cov @ w), 0.0)))
    return value, value - half, value + half, (half / abs(value) if value != 0 else float("inf"))


def stats_t(stats: ParameterStatistics) -> float:
    """The t quantile of the statistics' confidence level and degrees of freedom."""
    return float(scipy_stats.t.ppf(0.5 + stats.confidence / 2.0, max(stats.dof, 1)))


def _trapezoid(y, x) -> float:
    """Trapezoidal rule (np.trapezoid is numpy >= 2 only; np.trapz is gone from numpy 2.4)."""
    y = np.asarray(y, dtype=float)
    x = np.asarray(x, dtype=float)
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)))


def step_error_indices(time_s, measured_m, simulated_m, step_time_s: float | None = None) -> dict:
    """IAE [mm s], ISE [mm^2 s] and ITAE [mm s^2] of the step-fit error (Table III).

    The error e = simulated - measured is converted to mm; integrals use the
    trapezoidal rule over the whole record; ITAE weights |e| by (t - t_step)
    (0 before the step; t_step defaults to the first sample).
    """
    t = np.asarray(time_s, dtype=float)
    e_mm = (np.asarray(simulated_m, float) - np.asarray(measured_m, float)) * 1e3
    t_step = float(t[0]) if step_time_s is None else float(step_time_s)
    weight = np.clip(t - t_step, 0.0, None)
    trap = _trapezoid
    return {
        "IAE_mm_s": float(trap(np.abs(e_mm), t)),
        "ISE_mm2_s": float(trap(e_mm**2, t)),
        "ITAE_mm_s2": float(trap(weight * np.abs(e_mm), t)),
        "rms_error_um": float(np.sqrt(np.mean(e_mm**2)) * 1e3),
        "max_error_um": float(np.max(np.abs(e_mm)) * 1e3),
    }


def resonance_peak_Hz(frequency_Hz, d_rms_m) -> float:
    """Frequency of the largest RMS response, refined by a parabola through its neighbours.

    With a single point or a maximum at the edge of the range the sample frequency is returned.
    """
    f = np.asarray(frequency_Hz, dtype=float)
    r = np.asarray(d_rms_m, dtype=float)
    order = np.argsort(f)
    f, r = f[order], r[order]
    ok = np.isfinite(r)
    f, r = f[ok], r[ok]
    if f.size == 0:
        return float("nan")
    k = int(np.argmax(r))
    if k == 0 or k == f.size - 1:
        return float(f[k])
    x, y = f[k - 1:k + 2], r[k - 1:k + 2]
    a = np.polyfit(x, y, 2)
    if a[0] >= 0:
        return float(f[k])
    vertex = -a[1] / (2 * a[0])
    return float(np.clip(vertex, x[0], x[2]))


#: Largest relative frequency spacing of the neighbours of the largest measured RMS for a measured peak.
PEAK_SPACING_LIMIT = 0.01


def measured_resonance_peak(frequency_Hz, d_rms_m, usable=None, spacing_limit: float = PEAK_SPACING_LIMIT) -> dict:
    """The resonance peak of measured RMS values, only where the data bracket it densely.

    ``usable`` (optional, per point): records the peak may be taken from (e.g. the periodic ones;
    a period-doubled record is not the resonance). The largest usable value must have a usable
    neighbour on each side within ``spacing_limit`` of its frequency, both lower; then the peak
    is the vertex of the parabola through the three. Otherwise ``measured`` is False and ``note``
    says why (e.g. the paper's four frequencies do not bracket the peak): no number is invented.
    Returns {frequency_Hz, d_rms_m, measured, note}.
    """
    f = np.asarray(frequency_Hz, dtype=float)
    r = np.asarray(d_rms_m, dtype=float)
    ok = np.isfinite(r) if usable is None else (np.isfinite(r) & np.asarray(usable, dtype=bool))
    nan = float("nan")
    if np.count_nonzero(ok) < 3:
        return {"frequency_Hz": nan, "d_rms_m": nan, "measured": False,
                "note": "not measured: fewer than three usable frequencies"}
    order = np.argsort(f[ok])
    f, r = f[ok][order], r[ok][order]
    k = int(np.argmax(r))
    if k == 0 or k == f.size - 1:
        return {"frequency_Hz": nan, "d_rms_m": nan, "measured": False,
                "note": f"not measured: the largest RMS is at the edge of the data ({f[k]:g} Hz)"}
    gap = max(f[k] - f[k - 1], f[k + 1] - f[k]) / f[k]
    if gap > spacing_limit:
        return {"frequency_Hz": nan, "d_rms_m": nan, "measured": False,
                "note": (f"not measured: the largest RMS ({f[k]:g} Hz) has neighbours {100 * gap:.1f} % away "
                         f"in frequency; bracketing the peak needs <= {100 * spacing_limit:g} %")}
    x, y = f[k - 1:k + 2], r[k - 1:k + 2]
    a = np.polyfit(x - f[k], y, 2)
    if a[0] >= 0:
        return {"frequency_Hz": float(f[k]), "d_rms_m": float(r[k]), "measured": True,
                "note": "largest sample (no curvature)"}
    shift = float(np.clip(-a[1] / (2 * a[0]), x[0] - f[k], x[2] - f[k]))
    return {"frequency_Hz": float(f[k] + shift), "d_rms_m": float(np.polyval(a, shift)), "measured": True,
            "note": f"parabola through {x[0]:g}, {x[1]:g}, {x[2]:g} Hz"}


def static_errors_um(measured_m, predicted_m) -> dict:
    """RMS and maximum absolute static error (model - measurement) in micrometres."""
    e = (np.asarray(predicted_m, float) - np.asarray(measured_m, float)) * 1e6
    return {"rms_error_um": float(np.sqrt(np.mean(e**2))), "max_error_um": float(np.max(np.abs(e)))}
