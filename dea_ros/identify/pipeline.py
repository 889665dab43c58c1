"""The whole identification: experiments -> static fit -> dynamic fit -> classification -> joint
refinement -> evaluation (metrics, curves).

:func:`identify` runs the two-step procedure of the paper (section IV): the static parameters
from the rest displacements (eqs. 19-20), then k1, eta1, eta2 from the step and frequency
responses with the static parameters fixed (eqs. 22-24). Then every sine record is classified
(:func:`classify_records`): what the record shows from its samples (periodic at T/2, period-
doubled, quasi-periodic; :meth:`SineSeries.classify`) and what the model at the current
parameters realises there (:func:`~dea_ros.solvers.continuation.frequency_sweep`: the branch a
slow upward sweep is on, the period-doubled branch in a period-doubling band, quasi-periodic in
a torus band; with coexisting responses the one nearest the measured RMS). Each record is fitted
with the matching solution or left out with a warning. The joint refinement
(:mod:`~dea_ros.identify.joint_fit`) then fits every identifiable parameter at once with
statistical weights, so that the reported intervals include the uncertainty of the static stage;
the classification is repeated with the refined model until it does not change. sigma_h''(1) is
written only when the data determine it; otherwise params.yaml carries the base value and says
"not identified".

:func:`evaluate` checks the fitted model against *all* the data with the accurate solvers
(adaptive integration for the steps, the realised response of a continuation sweep for the
frequency response) and computes the metrics of Tables III-IV; quality checks turn a model that
does not reproduce the data within the noise into warnings, never a silent fit.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import stats as scipy_stats

from ..model.equilibrium import NoEquilibriumError, static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers.continuation import PRIMARY, frequency_sweep
from ..solvers.harmonic_balance import HarmonicBalanceError
from ..solvers.inputs import SampledVoltage, SinePeriodic
from ..solvers.integrate import simulate
from ..solvers.transient import TransientCollocation
from .dynamic_fit import DynamicFitResult, FrequencyPoint, fit_dynamic, point_solution, select_fit_frequencies
from .experiments import ExperimentSet, data_warnings, estimate_noise_m
from .joint_fit import CURVATURE_REL_CI_LIMIT, JointFitError, JointFitResult, fit_joint
from .metrics import linear_combination_ci, measured_resonance_peak, static_errors_um, step_error_indices
from .static_fit import (
    EXTENDED_COMBINATION_MATRIX,
    OgdenRepresentation,
    StaticFitResult,
    fit_static,
    stress_combinations,
)
from ..errors import IdentificationError

__all__ = ["IdentificationResult", "IdentificationError", "identify", "evaluate", "classify_records",
           "series_model"]


@dataclass
class IdentificationResult:
    """Fitted parameters, the fits, the evaluation against the data, warnings and timings."""

    experiments: ExperimentSet
    parameters: MembraneParameters
    static: StaticFitResult | None
    dynamic: DynamicFitResult | None
    evaluation: dict
    curves: dict
    timings_s: dict
    warnings: list = field(default_factory=list)
    options: dict = field(default_factory=dict)
    joint: JointFitResult | None = None
    classification: list = field(default_factory=list)   # one entry per sine record (see classify_records)
    #: sigma_h''(1): True identified (written), False not identified (base value written), None not fitted
    curvature_identified: bool | None = None
    curvature_written_Pa: float | None = None
    curvature_status: str = "not fitted"   # "identified", "poorly determined", "not identified", "not fitted"
    #: confidence bands of the frequency response (:class:`~dea_ros.identify.uncertainty.ResponseBand`),
    #: one per sine data set and amplitude, when asked for (``uncertainty_samples``)
    uncertainty: list = field(default_factory=list)

    @property
    def statistics(self):
        """The statistics of the final parameters: the joint refinement's, else the dynamic fit's."""
        if self.joint is not None:
            return self.joint.statistics
        return self.dynamic.statistics if self.dynamic is not None else None

    def identification_metadata(self) -> dict:
        """What was identified and how (written next to the parameters in params.yaml).

        The hyperelastic stress is given at lambda_r = 1 with derivatives w.r.t. lambda_r as eq. 10 is
        written (the fits use s = lambda_r^2: d/dlambda = 2 d/ds, d2/dlambda2 = 2 d/ds + 4 d2/ds2).
        """
        c = stress_combinations(self.parameters.beta_Pa, self.parameters.gamma_Pa)
        stats = self.statistics
        s_stats = stats if (stats is not None and "sigma_h(1)_Pa" in stats.names) else (
            self.static.statistics if self.static is not None else None)

        def ci(st, weights):
            v = linear_combination_ci(st, weights)
            return None if v is None or not np.isfinite(v[3]) else [float(v[1]), float(v[2])]

        meta = {
            "method": "joint refinement (statistical weights)" if self.joint is not None else
                      f"two-stage (paper), weights {self.options.get('weights')}",
            "stress_derivatives": "w.r.t. lambda_r at lambda_r = 1 (eq. 10)",
            "sigma_h(1)_Pa": float(c[0]),
            "sigma_h(1)_Pa_ci95": ci(s_stats, {"sigma_h(1)_Pa": 1.0}),
            "dsigma_h_dlambda(1)_Pa": float(2.0 * c[1]),
            "dsigma_h_dlambda(1)_Pa_ci95": ci(s_stats, {"sigma_h'(1)_Pa": 2.0}),
        }
        if self.curvature_identified:
            meta["d2sigma_h_dlambda2(1)_Pa"] = float(2.0 * c[1] + 4.0 * c[2])
            meta["d2sigma_h_dlambda2(1)_Pa_ci95"] = ci(stats, {"sigma_h'(1)_Pa": 2.0, "sigma_h''(1)_Pa": 4.0})
            meta["d2sigma_h_dlambda2(1)_status"] = self.curvature_status
        else:
            meta["d2sigma_h_dlambda2(1)_Pa"] = "not identified"
            meta["d2sigma_h_dlambda2(1)_written_Pa"] = float(2.0 * c[1] + 4.0 * c[2])
            meta["d2sigma_h_dlambda2(1)_note"] = (
                "not determined by the data: beta/gamma carry the base value (base parameters file, or the "
                "representation of eqs. 8-9 without one), not a fitted one")
        for name in ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"):
            st = stats if (stats is not None and name in stats.names) else (
                self.static.statistics if (self.static is not None and name == "eps_r") else None)
            if st is not None and name in st.names:
                i = st.names.index(name)
                if np.isfinite(st.relative_ci[i]):
                    meta[f"{name}_ci95"] = [float(st.ci_low[i]), float(st.ci_high[i])]
        left_out = [c_["frequency_Hz"] for c_ in self.classification if c_.get("used") == "left out"]
        if left_out:
            meta["left_out_frequencies_Hz"] = [float(f) for f in left_out]
        pd = [c_["frequency_Hz"] for c_ in self.classification if c_.get("used") == "period-doubled"]
        if pd:
            meta["period_doubled_fits_Hz"] = [float(f) for f in pd]
        return meta

    def to_dict(self) -> dict:
        """JSON-friendly summary: parameters, fits, metrics, statistics, warnings, timings."""
        out = {
            "membrane": self.parameters.name,
            "parameters": self.parameters.to_dict(),
            "options": dict(self.options),
            "metrics": _jsonable(self.evaluation),
            "timings_s": {k: float(v) for k, v in self.timings_s.items()},
            "warnings": list(self.warnings),
        }
        if self.static is not None:
            st = self.static
            out["static_fit"] = {
                "method": st.method,
                "representation": st.representation,
                "combinations_Pa": {"sigma_h(1)": float(st.combinations_Pa[0]),
                                    "sigma_h'(1)": float(st.combinations_Pa[1]),
                                    "sigma_h''(1)": float(st.combinations_Pa[2])},
                "statistics": st.statistics.as_dict(),
                "evaluations": st.n_evaluations,
                "errors_um": st.errors_um,
            }
        out["identification"] = _jsonable(self.identification_metadata())
        out["classification"] = _jsonable([{k: v for k, v in c.items() if k != "guess"}
                                           for c in self.classification])
        if self.joint is not None:
            out["joint_fit"] = _jsonable(self.joint.as_dict())
        if self.uncertainty:
            out["uncertainty"] = _jsonable([b.to_dict() for b in self.uncertainty])
        if self.dynamic is not None:
            dy = self.dynamic
            out["dynamic_fit"] = {
                "method": dy.method,
                "frequency_method": dy.frequency_method,
                "fit_frequencies_Hz": [float(f) for f in dy.fit_frequencies_Hz],
                "weights": _jsonable(dy.weights[0] if dy.weights[0] != "custom" else dy.weights),
                "curvature_fitted": dy.curvature_fitted,
                "cost_eq22": dy.cost,
                "step_cost": dy.step_cost,
                "frequency_cost": dy.frequency_cost,
                "evaluations": dy.n_evaluations,
                "jacobians": dy.n_jacobians,
                "statistics": dy.statistics.as_dict() if dy.statistics else None,
                "initial_guess": _jsonable({k: v for k, v in dy.initial.items()}),
            }
        return out


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


# --------------------------------------------------------------------------- classification
def _sweep_for(params: MembraneParameters, amplitude_V: float, freqs, n_harmonics: int, realised: bool = True):
    return frequency_sweep(params, SinePeriodic(amplitude_V, 1.0), np.unique(np.asarray(freqs, float)),
                           n_harmonics=n_harmonics, realised=realised)


def _candidates(sweep, f: float) -> list:
    """(branch name, SweepPoint) of every periodic solution at f."""
    return [(b.name, p) for b in sweep.branches for p in b.points if abs(p.frequency_Hz - f) <= 1e-9 * max(f, 1.0)]


def classify_records(params: MembraneParameters, experiments: ExperimentSet, n_harmonics: int = 8,
                     noise_m: float | None = None) -> list:
    """What every sine record shows and what it is fitted with (module docstring).

    One dict per record: frequency_Hz, amplitude_V, source, measured_rms_m, ``data_kind`` (from the
    sampled record, None without one), ``model_kind`` (the realised response of the model),
    ``used`` ("periodic", "period-doubled" or "left out"), ``reason``, and ``guess`` (a state on
    the branch to fit; not serialised).
    """
    out = []
    for sine in experiments.sines:
        p = params.replace(mass_kg=sine.mass_kg)
        series_by_f = {round(s.frequency_Hz, 9): s for s in sine.series}
        for a in np.unique(sine.amplitude_V):
            sel = np.nonzero(sine.amplitude_V == a)[0]
            # the kinds only: no integration of quasi-periodic responses here
            sweep = _sweep_for(p, float(a), sine.frequency_Hz[sel], n_harmonics, realised=False)
            by_f = {round(r.frequency_Hz, 9): r for r in sweep.responses}
            for k in sel:
                f = float(sine.frequency_Hz[k])
                meas = float(sine.d_rms_m[k])
                ser = series_by_f.get(round(f, 9))
                data = ser.classify(noise_m) if ser is not None else None
                data_kind = data["kind"] if data else None
                resp = by_f.get(round(f, 9))
                model_kind = resp.kind if resp is not None else None
                cands = _candidates(sweep, f)
                stable = [(n, pt) for n, pt in cands if pt.stable]
                entry = {"frequency_Hz": f, "amplitude_V": float(a), "source": sine.source, "index": int(k),
                         "measured_rms_m": meas, "data_kind": data_kind, "model_kind": model_kind,
                         "model_rms_m": resp.d_rms_m if resp is not None else None}
                if data:
                    entry["data_test"] = {kk: v for kk, v in data.items() if kk != "kind"}

                def pick(names, pool):
                    cand = [(n, pt) for n, pt in pool if n in names or (names == "T" and n != PRIMARY)]
                    return min(cand, key=lambda c: abs(c[1].d_rms_m - meas)) if cand else None

                want = data_kind or model_kind
                chosen, reason = None, ""
                if want == "quasi-periodic":
                    reason = ("the record is quasi-periodic (no period in its samples)" if data_kind else
                              "the model has no stable periodic response there (quasi-periodic: a torus band)")
                elif want == "period-doubled":
                    chosen = pick("T", stable) or pick("T", cands)
                    if chosen is None:
                        reason = ("the record is period-doubled but the model has no period-doubled orbit at "
                                  f"{f:g} Hz with the current parameters")
                elif want in ("periodic", "coexisting"):
                    pool = stable or cands
                    if data_kind == "periodic":
                        chosen = pick(PRIMARY, pool) or pick(PRIMARY, cands)
                    else:
                        chosen = min(pool, key=lambda c: abs(c[1].d_rms_m - meas)) if pool else None
                    if chosen is None:
                        reason = "no periodic solution of the model there"
                else:
                    reason = "the model response could not be computed"
                if chosen is not None:
                    name, pt = chosen
                    entry["used"] = "periodic" if name == PRIMARY else "period-doubled"
                    entry["branch"] = name
                    entry["guess"] = pt.solution.state
                    if data_kind and model_kind and data_kind != model_kind and model_kind != "coexisting":
                        entry["note"] = (f"the data show a {data_kind} response, the model at these parameters "
                                         f"a {model_kind} one; fitted as {entry['used']}")
                    if len(stable) > 1:
                        # several stable responses: say which the data are on and what else the model has
                        entry["coexisting"] = [{"branch": n, "kind": branch_kind(n), "d_rms_m": float(q.d_rms_m),
                                                "fitted": n == name} for n, q in stable]
                        others = ", ".join(f"{branch_kind(n)} {q.d_rms_m * 1e6:.4g} um" for n, q in stable
                                           if n != name)
                        entry["note"] = (f"coexisting stable responses in the model: {branch_kind(name)} "
                                         f"{pt.d_rms_m * 1e6:.4g} um (fitted: the record, {meas * 1e6:.4g} um"
                                         + (f", {data_kind}" if data_kind else "") + f", is on it) and {others}"
                                         " (which one a measurement sees depends on the history)")
                else:
                    entry["used"] = "left out"
                    entry["reason"] = reason
                out.append(entry)
    return out


#: a fitted record whose model d_rms is further than this (relative) and 5 sigma from the data is reported
DISAGREEMENT_FRACTION = 0.02


def branch_kind(name: str) -> str:
    """The response kind of a continuation branch: the primary T/2 orbit or a period-doubled one."""
    return "T/2 orbit" if name == PRIMARY else "period-doubled (T)"


def _points_from(classification: list, experiments: ExperimentSet) -> list:
    """FrequencyPoints of the classified records that are fitted (with their kind and seed)."""
    pts = []
    for c in classification:
        if c["used"] == "left out":
            continue
        sine = [s for s in experiments.sines if s.source == c["source"]][0]
        k = c["index"]
        pts.append(FrequencyPoint(
            c["frequency_Hz"], c["amplitude_V"], c["measured_rms_m"], sine.mass_kg, sine.source,
            None if sine.d_rms_std_m is None else float(sine.d_rms_std_m[k]),
            sine.inputs[k] if sine.inputs else None, kind=c["used"], guess=c.get("guess")))
    return sorted(pts, key=lambda p: p.frequency_Hz)


def _kinds(classification: list) -> list:
    return [(round(c["frequency_Hz"], 9), c["used"], c.get("branch")) for c in classification]


def _static_sigma(static: StaticFitResult | None) -> float:
    """Weight of the static points in the joint chi-square: the static fit's residual standard
    deviation s, times t_0.975(dof) / z_0.975 -- s comes from few points (e.g. 9 degrees of freedom),
    and the joint intervals, which use the quantile of the joint fit's many degrees of freedom,
    would otherwise be too narrow for the parameters the static points determine (sigma_h(1))."""
    if static is None:
        return 1.0
    st = static.statistics
    s = float(st.residual_std) if st is not None and math.isfinite(st.residual_std) else float("nan")
    dof = int(st.dof) if st is not None else 0
    if not (math.isfinite(s) and s > 0):
        r = static.residuals_m
        s = float(np.sqrt(np.mean(r**2))) if r.size else 1e-7
    if dof >= 1:
        s *= float(scipy_stats.t.ppf(0.975, dof) / scipy_stats.norm.ppf(0.975))
    return max(s, 1e-9)


# --------------------------------------------------------------------------- evaluation
def series_model(params: MembraneParameters, series, amplitude_V: float, n_harmonics: int = 8,
                 solution=None, periodic_input=None):
    """Model displacement at the samples of a sine record, aligned on the phase of u^2.

    The model sees u^2 only (eq. 6), so the record's phase is that of the 2f component of its
    recorded voltage squared: u^2 = U^2/2 (1 - cos(2 w t + 2 phi)) for u = U sin(w t + phi) and
    for |U sin(w t + phi)| alike. ``solution``: the periodic solution to show (default: the T/2
    orbit); a period-doubled one is also compared shifted by T/2 (the other member of its pair)
    and the closer is kept. With ``periodic_input`` (the applied waveform, phase 0 at the record
    start) no alignment is needed. Returns (model displacement, phase phi in rad).
    """
    w = 2.0 * np.pi * series.frequency_Hz
    t = series.time_s - series.time_s[0]
    if periodic_input is not None:
        sol = solution or point_solution(params, FrequencyPoint(series.frequency_Hz, amplitude_V, 0.0,
                                                                params.mass_kg, "", periodic_input=periodic_input),
                                         n_harmonics)
        return sol.evaluate(t)[0], 0.0
    u2 = series.voltage_V ** 2
    basis = np.column_stack([np.ones_like(t), np.cos(2 * w * t), np.sin(2 * w * t)])
    (_c, a, b), *_ = np.linalg.lstsq(basis, u2, rcond=None)
    phase = 0.5 * math.atan2(b, -a)       # 2 phi from -U^2/2 cos(2 w t + 2 phi)
    if solution is None:
        solution = point_solution(params, FrequencyPoint(series.frequency_Hz, amplitude_V, 0.0, params.mass_kg, ""),
                                  n_harmonics)
    best = None
    shifts = (0.0, math.pi) if solution.period_divisor == 1 else (0.0,)
    for extra in shifts:
        d = solution.evaluate(t + (phase + extra) / w)[0]
        err = float(np.mean((d - series.displacement_m) ** 2))
        if best is None or err < best[0]:
            best = (err, d, phase + extra)
    return best[1], best[2]


def evaluate(params: MembraneParameters, experiments: ExperimentSet, n_harmonics: int = 8,
             sweep_points: int = 120, classification: list | None = None) -> tuple[dict, dict, list]:
    """Metrics and plot curves of ``params`` against every experiment (accurate solvers).

    ``classification`` (from :func:`classify_records` with these parameters; computed when
    None) says which solution each sine record is compared with. Returns (metrics, curves,
    warnings).
    """
    metrics: dict = {}
    curves: dict = {}
    warnings: list = []
    noise = experiments.sensor_noise_m
    # ---- static (Fig. 6)
    data = experiments.all_static()
    if data is not None:
        predicted = np.zeros(data.n_points)
        for m in np.unique(data.mass_kg):
            sel = data.mass_kg == m
            predicted[sel] = static_equilibrium(params, data.voltage_V[sel], mass_kg=float(m)).displacement_m
        metrics["static"] = static_errors_um(data.displacement_m, predicted)
        curve = {}
        for m in np.unique(data.mass_kg[np.abs(data.voltage_V) > 0]):
            u_max = float(np.max(np.abs(data.voltage_V[data.mass_kg == m])))
            u = np.linspace(0.0, 1.04 * u_max, 120)
            try:
                curve[float(m)] = (u, static_equilibrium(params, u, mass_kg=float(m)).displacement_m)
            except NoEquilibriumError:
                pass
        masses = np.linspace(0.0, 1.1 * float(np.max(data.mass_kg)), 60)
        d_mass = np.array([static_equilibrium(params, 0.0, mass_kg=float(m)).displacement_m for m in masses])
        curves["static"] = {"data": data, "predicted_m": predicted, "voltage_curves": curve,
                            "mass_curve": (masses, d_mass)}
    # ---- steps (Fig. 8 left, Table III)
    step_metrics = []
    curves["steps"] = []
    for step in experiments.steps:
        p = params.replace(mass_kg=step.mass_kg)
        jumps = int(np.count_nonzero(np.diff(step.voltage_V)))
        if step.voltage_hold == "zoh" and jumps > 50:
            # A measured (noisy) voltage: every sample is a breakpoint of the adaptive integrator;
            # use the collocation solver (validated to ~1 nm against it) instead.
            sim_d = TransientCollocation(step.time_s, step.voltage_V, hold="zoh").solve(p).displacement_m
        else:
            sim_d = simulate(p, SampledVoltage(step.time_s, step.voltage_V, hold=step.voltage_hold),
                             float(step.time_s[-1]), t_eval=step.time_s, t_start_s=float(step.time_s[0]),
                             rtol=1e-10, atol_scale=1e-10).displacement_m
        idx = step_error_indices(step.time_s, step.displacement_m, sim_d, step.step_time_s)
        est = estimate_noise_m(step)
        sigma = noise if noise is not None else est
        idx["noise_um"] = None if sigma is None else sigma * 1e6
        idx["source"] = step.source
        step_metrics.append(idx)
        curves["steps"].append({"step": step, "simulated_m": sim_d})
        if sigma is not None and idx["rms_error_um"] > 2.0 * sigma * 1e6:
            warnings.append(
                f"{step.source}: the fitted model does not reproduce the step within the noise "
                f"(RMS error {idx['rms_error_um']:.3g} um vs noise {sigma * 1e6:.3g} um): the model or the "
                "data are inconsistent (unsettled rig, wrong mass, nonlinearity not in the model?)"
            )
    if step_metrics:
        metrics["steps"] = step_metrics
    # ---- frequency response (Fig. 7-8 right, Table IV)
    own_classification = bool(experiments.sines and classification is None)
    if own_classification:
        classification = classify_records(params, experiments, n_harmonics, noise)
    by_rec = {(c["source"], c["index"]): c for c in (classification or [])}
    freq_metrics = []
    curves["sines"] = []
    for sine in experiments.sines:
        p = params.replace(mass_kg=sine.mass_kg)
        f = sine.frequency_Hz
        entry = {"source": sine.source, "waveform": sine.waveform}
        model_at_data = np.full(f.size, np.nan)
        used = ["left out"] * f.size
        dense_curves = []
        for k in range(f.size):
            c = by_rec.get((sine.source, k))
            if c is None or c["used"] == "left out":
                continue
            pt = FrequencyPoint(float(f[k]), float(sine.amplitude_V[k]), float(sine.d_rms_m[k]), sine.mass_kg,
                                sine.source, periodic_input=sine.inputs[k] if sine.inputs else None,
                                kind=c["used"], guess=c.get("guess"))
            try:
                sol = point_solution(p, pt, n_harmonics)
            except HarmonicBalanceError as exc:
                warnings.append(f"{sine.source}: no model response at {f[k]:g} Hz ({exc})")
                continue
            model_at_data[k] = sol.displacement_rms(float(static_equilibrium(p, 0.0).displacement_m))
            used[k] = c["used"]
        for a in np.unique(sine.amplitude_V):
            sel = sine.amplitude_V == a
            f_dense = np.unique(np.r_[np.linspace(f[sel].min(), f[sel].max(), sweep_points), f[sel]])
            try:
                sweep = _sweep_for(p, float(a), f_dense, n_harmonics)
            except (HarmonicBalanceError, RuntimeError) as exc:
                warnings.append(f"{sine.source}: the model sweep at {a:g} V failed ({exc})")
                continue
            dense_curves.append((float(a), sweep))
            peak = sweep.resonance_peak(True)
            meas = measured_resonance_peak(f[sel], sine.d_rms_m[sel],
                                           [used[k] == "periodic" for k in np.nonzero(sel)[0]])
            res = {"amplitude_V": float(a), "simulated_peak_Hz": peak["frequency_Hz"],
                   "simulated_peak_rms_m": peak["d_rms_m"], "measured_peak_Hz": meas["frequency_Hz"],
                   "measured": meas["measured"], "measured_note": meas["note"]}
            if meas["measured"]:
                res["error_percent"] = 100.0 * abs(peak["frequency_Hz"] - meas["frequency_Hz"]) / meas["frequency_Hz"]
            else:
                res["error_percent"] = None
            entry.setdefault("resonance", []).append(res)
            entry.setdefault("bands", []).extend([{"amplitude_V": float(a), **b.to_dict()} for b in sweep.bands])
        err = (model_at_data - sine.d_rms_m) * 1e6
        ok = np.isfinite(err)
        entry["rms_error_um"] = float(np.sqrt(np.mean(err[ok] ** 2))) if np.any(ok) else None
        entry["max_error_um"] = float(np.max(np.abs(err[ok]))) if np.any(ok) else None
        entry["max_relative_error_percent"] = (float(np.max(np.abs(err[ok]) / (sine.d_rms_m[ok] * 1e6))) * 100.0
                                               if np.any(ok) else None)
        entry["frequencies"] = int(f.size)
        entry["compared"] = int(np.count_nonzero(ok))
        entry["kinds"] = list(used)
        if sine.d_rms_std_m is not None and np.any(ok):
            z = err[ok] / (sine.d_rms_std_m[ok] * 1e6)
            entry["normalised_rms_error"] = float(np.sqrt(np.mean(z**2)))
        # records the model does not reproduce: beyond the noise and by more than 2 % (a fitted
        # record is not a reproduced one)
        apart = []
        for k in np.nonzero(ok)[0]:
            rel = err[k] / (sine.d_rms_m[k] * 1e6)
            zk = err[k] / (sine.d_rms_std_m[k] * 1e6) if sine.d_rms_std_m is not None else None
            if abs(rel) > DISAGREEMENT_FRACTION and (zk is None or abs(zk) > 5.0):
                apart.append(f"{f[k]:g} Hz (data {sine.d_rms_m[k] * 1e6:.4g} um, model "
                             f"{model_at_data[k] * 1e6:.4g} um, {100 * rel:+.1f} %"
                             + (f", {zk:+.0f} sigma" if zk is not None else "") + ")")
        if apart:
            entry["not_reproduced"] = apart
            warnings.append(f"{sine.source}: the fitted model does not reproduce the record at " + "; ".join(apart)
                            + ": a model-data disagreement (an excitation the model does not see, a record not "
                            "settled, or a model error), not a fit within the noise")
        left = f[[u == "left out" for u in used]]
        if left.size and own_classification:
            reasons = {c["frequency_Hz"]: c.get("reason", "") for c in (classification or [])
                       if c["source"] == sine.source and c["used"] == "left out"}
            warnings.append(f"{sine.source}: not compared with a periodic model response at "
                            + "; ".join(f"{x:g} Hz ({reasons.get(float(x), 'no solution')})" for x in left))
        series_out = []
        for ser in sine.series:
            k = int(np.argmin(np.abs(f - ser.frequency_Hz)))
            c = by_rec.get((sine.source, k))
            if c is None or c["used"] == "left out" or abs(f[k] - ser.frequency_Hz) > 1e-9 * f[k]:
                series_out.append({"series": ser, "model_m": None, "rms_error_um": None,
                                   "note": (c or {}).get("reason", "no model response")})
                continue
            try:
                pt = FrequencyPoint(float(f[k]), float(sine.amplitude_V[k]), 0.0, sine.mass_kg, sine.source,
                                    periodic_input=sine.inputs[k] if sine.inputs else None, kind=c["used"],
                                    guess=c.get("guess"))
                sol = point_solution(p, pt, n_harmonics)
                model_d, phase = series_model(p, ser, float(sine.amplitude_V[k]), n_harmonics, solution=sol,
                                              periodic_input=sine.inputs[k] if sine.inputs else None)
            except HarmonicBalanceError as exc:
                warnings.append(f"{ser.source}: no model response ({exc})")
                continue
            e = (model_d - ser.displacement_m) * 1e6
            rms_e = float(np.sqrt(np.mean(e**2)))
            how = "driven by the recorded voltage" if sine.inputs else "aligned on the phase of u^2"
            series_out.append({"series": ser, "model_m": model_d, "rms_error_um": rms_e, "phase_rad": phase,
                               "kind": c["used"], "how": how})
            entry["series_model"] = how
            entry.setdefault("series_rms_error_um", {})[f"{ser.frequency_Hz:g} Hz"] = rms_e
            sigma = noise if noise is not None else ser.noise_m()
            if sigma is not None and rms_e > 3.0 * sigma * 1e6:
                warnings.append(f"{ser.source}: the model does not reproduce the sampled record: RMS error "
                                f"{rms_e:.3g} um against {sigma * 1e6:.2g} um laser noise (a transient that has not "
                                "died out, an excitation the model does not see, or a model error)")
        freq_metrics.append(entry)
        curves["sines"].append({"sine": sine, "model_at_data_m": model_at_data, "used": used,
                                "dense": dense_curves, "series": series_out})
    if freq_metrics:
        metrics["frequency_response"] = freq_metrics
    return metrics, curves, warnings


# --------------------------------------------------------------------------- identification
#: Frequencies of a confidence band: over the range of a sine data set, and as many again within
#: +-15 % of the model's resonance peak (where the band is widest).
BAND_POINTS = 40


def _uncertainty_bands(params, statistics, experiments: ExperimentSet, n_samples: int, n_harmonics: int, engine,
                       metrics: dict):
    """Confidence bands (one per sine data set and amplitude) and warnings where none can be drawn."""
    from .uncertainty import response_band

    peaks = {(e.get("source"), r["amplitude_V"]): r.get("simulated_peak_Hz")
             for e in metrics.get("frequency_response", []) for r in e.get("resonance", [])}
    bands, warnings = [], []
    if statistics is None:
        return bands, ["no confidence band of the frequency response: no dynamic fit statistics"]
    for sine in experiments.sines:
        for a in np.unique(sine.amplitude_V):
            f = sine.frequency_Hz[sine.amplitude_V == a]
            grid = np.linspace(f.min(), f.max(), BAND_POINTS)
            fp = peaks.get((sine.source, float(a)))
            if fp is not None and np.isfinite(fp):
                near = np.linspace(0.85 * fp, 1.15 * fp, BAND_POINTS)
                grid = np.union1d(grid, near[(near >= f.min()) & (near <= f.max())])
            try:
                bands.append(response_band(params, statistics, float(a), grid, n_samples=n_samples,
                                           n_harmonics=n_harmonics, mass_kg=sine.mass_kg, engine=engine))
            except (ValueError, HarmonicBalanceError, RuntimeError) as exc:
                warnings.append(f"{sine.source}: no confidence band of the frequency response at {a:g} V ({exc})")
    return bands, warnings


def _curvature_fallback(static: StaticFitResult | None, params: MembraneParameters) -> np.ndarray:
    """(beta, gamma) whose curvature terms (sigma_h''(1), sigma_h'''(1)) are written when the data do
    not determine them: the base parameters' (or, without base parameters, the static fit's
    representation, eqs. 8-9)."""
    if static is not None and static.prior_beta_gamma is not None:
        return np.asarray(static.prior_beta_gamma, float)
    return np.r_[params.beta_Pa, params.gamma_Pa]


def _marginal_statistics(held, free):
    """Statistics of a fit with the curvature held, with every interval at least as wide as in the fit
    with it free (the marginal uncertainty, which allows for the unknown curvature), around the held
    fit's values."""
    from dataclasses import replace as dc_replace

    lo, hi = np.array(held.ci_low, float), np.array(held.ci_high, float)
    se, rel = np.array(held.std_error, float), np.array(held.relative_ci, float)
    vals = np.asarray(held.values, float)
    for i, name in enumerate(held.names):
        if name not in free.names:
            continue
        j = free.names.index(name)
        if not (free.relative_ci[j] > rel[i]):
            continue
        rel[i] = free.relative_ci[j]
        se[i] = max(se[i], free.std_error[j] * abs(vals[i] / free.values[j]) if free.values[j] else free.std_error[j])
        if free.ci_low[j] > 0 and abs(np.log(free.ci_high[j] / free.values[j])
                                      + np.log(free.ci_low[j] / free.values[j])) < 1e-9:
            f_hi = free.ci_high[j] / free.values[j]           # a log parameter: multiplicative interval
            lo[i], hi[i] = vals[i] / f_hi, vals[i] * f_hi
        else:
            half = 0.5 * (free.ci_high[j] - free.ci_low[j])
            lo[i], hi[i] = vals[i] - half, vals[i] + half
    return dc_replace(held, ci_low=lo, ci_high=hi, std_error=se, relative_ci=rel)


def _set_combinations(params: MembraneParameters, combos, prior_bg) -> MembraneParameters:
    """``params`` with (beta, gamma) matching the four combinations ``combos`` (eq. 10, in s)."""
    prior = np.r_[params.beta_Pa, params.gamma_Pa] if prior_bg is None else np.asarray(prior_bg, float)
    rep = OgdenRepresentation(params.prestretch, 4, prior, matrix=EXTENDED_COMBINATION_MATRIX)
    bg = rep.beta_gamma(np.asarray(combos, float))
    return params.replace(beta_Pa=tuple(float(v) for v in bg[:3]), gamma_Pa=tuple(float(v) for v in bg[3:]))


def _with_base_curvature(params: MembraneParameters, base_bg) -> MembraneParameters:
    """``params`` with sigma_h(1), sigma_h'(1) kept and the curvature terms of ``base_bg``."""
    c = EXTENDED_COMBINATION_MATRIX @ np.r_[params.beta_Pa, params.gamma_Pa]
    base = EXTENDED_COMBINATION_MATRIX @ np.asarray(base_bg, float)
    rep = OgdenRepresentation(params.prestretch, 4, np.asarray(base_bg, float), matrix=EXTENDED_COMBINATION_MATRIX)
    bg = rep.beta_gamma([c[0], c[1], base[2], base[3]])
    return params.replace(beta_Pa=tuple(float(v) for v in bg[:3]), gamma_Pa=tuple(float(v) for v in bg[3:]))


def identify(
    experiments: ExperimentSet,
    static_method: str = "lsq",
    frequency_method: str = "hbm",
    dynamic_method: str = "lsq",
    fit_frequencies_Hz=None,
    n_harmonics: int = 8,
    weights="paper",
    stress_terms: int = 2,
    progress: Callable[[dict], None] | None = None,
    evaluate_fit: bool = True,
    fit_curvature="auto",
    refine: str = "joint",
    uncertainty_samples: int = 0,
    engine=None,
) -> IdentificationResult:
    """Identify all parameters of ``experiments`` (see the module docstring).

    Stage 1 (the paper): ``weights`` "paper" (eq. 22 with w_step = 6.6e6, w_hbm = 0.1e6), "noise"
    (1/sigma^2) or a dict; ``fit_frequencies_Hz`` (default the paper's four in the data, "all", or
    a list); records classified as not periodic at T/2 are left out of it.
    ``refine``: "joint" (default) refines every identifiable parameter jointly with statistical
    weights on all classified records (the final parameters and intervals); "none" stops after
    the paper's two stages. ``fit_curvature``: identify sigma_h''(1) -- "auto" in the joint
    refinement when there are sine records; True also in stage 1 (with noise weights); False never.
    ``uncertainty_samples`` > 0: Monte Carlo confidence bands of the frequency response and the resonance
    peak over the final covariance (:func:`~dea_ros.identify.uncertainty.response_band`, one per sine data
    set and amplitude; ``engine``: an open :class:`~dea_ros.study.engine.Engine` for its batches).
    """
    if refine not in ("joint", "none"):
        raise ValueError(f"refine: 'joint' or 'none', got {refine!r}")
    t_start = time.perf_counter()
    timings: dict = {}
    warnings = list(data_warnings(experiments))
    template = experiments.template_parameters()
    noise = experiments.sensor_noise_m
    static = None
    if experiments.static:
        t0 = time.perf_counter()
        data = experiments.all_static()
        loaded = int(np.count_nonzero(data.mass_kg > 0))
        if static_method == "lsq" and loaded < stress_terms + 3 and stress_terms > 1:
            # too few points for sigma_h(1), sigma_h'(1) and eps_r with residual freedom left
            stress_terms = 1
            warnings.append(
                f"{data.source}: only {loaded} static point(s) with a mass; fitting sigma_h(1) and eps_r only, "
                "sigma_h'(1) is taken from the " + ("base parameters" if experiments.base_parameters is not None
                                                    else "representation (eqs. 8-9)")
                + " -- add zero-voltage points at several masses to identify it"
            )
        static = fit_static(data, template, method=static_method,
                            stress_terms=stress_terms,
                            prior_from_template=experiments.base_parameters is not None,
                            progress=progress)
        timings["static_fit"] = time.perf_counter() - t0
        params = static.parameters
    elif experiments.base_parameters is not None:
        params = template
    else:
        raise IdentificationError(
            "no static experiment and no base parameters file: beta, gamma and eps_r are unknown; add "
            "static points (mass, voltage, displacement) or reference a parameters file in the manifest"
        )
    # ---- data classification of the sampled records (before any fit)
    data_kinds = {}
    for sine in experiments.sines:
        for ser in sine.series:
            data_kinds[(sine.source, round(ser.frequency_Hz, 9))] = ser.classify(noise)["kind"]
    dynamic = None
    joint = None
    classification: list = []
    curvature_identified = None
    curvature_status = "not fitted"
    curvature_written = None
    if experiments.steps or experiments.sines:
        t0 = time.perf_counter()
        stage1_curvature = fit_curvature is True
        direction = static.curvature_direction() if (stage1_curvature and static is not None) else None
        if stage1_curvature and (direction is None or stress_terms != 2 or static.method != "lsq"):
            raise IdentificationError("fit_curvature needs the least-squares static fit (static_method='lsq') "
                                      "with sigma_h(1) and sigma_h'(1) fitted (stress_terms=2, enough static points)")
        # stage 1 (the paper): frequency points whose records are periodic at T/2 (as far as known)
        stage1_points = select_fit_frequencies(experiments.sines, fit_frequencies_Hz)
        dropped = [pt for pt in stage1_points
                   if data_kinds.get((pt.source, round(pt.frequency_Hz, 9)), "periodic") != "periodic"]
        stage1_freqs = [pt.frequency_Hz for pt in stage1_points if pt not in dropped]
        for pt in dropped:
            warnings.append(f"{pt.source}: the record at {pt.frequency_Hz:g} Hz is "
                            f"{data_kinds[(pt.source, round(pt.frequency_Hz, 9))]}, not periodic at T/2: left out "
                            "of the paper's fit (eq. 24 assumes the T/2 orbit)")
        dyn_kw = dict(method=dynamic_method, frequency_method=frequency_method, weights=weights,
                      n_harmonics=n_harmonics, progress=progress, noise_m=noise)
        sines_for_stage1 = experiments.sines if stage1_freqs else []
        dynamic = fit_dynamic(params, experiments.steps, sines_for_stage1,
                              fit_frequencies_Hz=stage1_freqs if stage1_freqs else None,
                              start=experiments.base_parameters, curvature_direction=direction, **dyn_kw)
        if direction is not None:
            # sigma_h''(1) moved: refit sigma_h(1), sigma_h'(1), eps_r with it fixed, then polish
            curvature = float(stress_combinations(dynamic.parameters.beta_Pa, dynamic.parameters.gamma_Pa)[2])
            static = fit_static(experiments.all_static(), template, method=static_method,
                                stress_terms=stress_terms, curvature_Pa=curvature,
                                prior_from_template=experiments.base_parameters is not None)
            first = dynamic
            dynamic = fit_dynamic(static.parameters, experiments.steps, sines_for_stage1,
                                  fit_frequencies_Hz=stage1_freqs if stage1_freqs else None,
                                  curvature_direction=static.curvature_direction(), initial=first.parameters,
                                  **dyn_kw)
            dynamic.initial = first.initial
            dynamic.n_evaluations += first.n_evaluations
            dynamic.starts = first.starts + dynamic.starts
        timings["dynamic_fit"] = time.perf_counter() - t0
        timings["dynamic_fit_step_simulations"] = dynamic.time_step_s
        timings["dynamic_fit_frequency_response"] = dynamic.time_frequency_s
        params = dynamic.parameters
        warnings += dynamic.warnings
        # ---- classification with the model, then the joint refinement (repeated while it changes)
        t0 = time.perf_counter()
        if experiments.sines:
            classification = classify_records(params, experiments, n_harmonics, noise)
            # a record of stage 1 that the model (or the data) says is not periodic at T/2 was fitted with
            # the wrong orbit: stage 1 again without it, then classify with that model
            wrong = {(c["source"], round(c["frequency_Hz"], 9)) for c in classification if c["used"] != "periodic"}
            kept = [f for f in stage1_freqs if not any((s.source, round(f, 9)) in wrong for s in experiments.sines)]
            if len(kept) < len(stage1_freqs) and direction is None and (kept or experiments.steps):
                for f in sorted(set(stage1_freqs) - set(kept)):
                    warnings.append(f"{f:g} Hz: not periodic at T/2 for the model after stage 1 (a period-doubled or "
                                    "quasi-periodic response): stage 1 repeated without it "
                                    "(eq. 24 assumes the T/2 orbit)")
                redo = fit_dynamic(params if static is None else static.parameters, experiments.steps,
                                   experiments.sines if kept else [], fit_frequencies_Hz=kept if kept else None,
                                   start=experiments.base_parameters, **dyn_kw)
                redo.n_evaluations += dynamic.n_evaluations
                dynamic = redo
                params = dynamic.parameters
                warnings += [w for w in dynamic.warnings if w not in warnings]
                classification = classify_records(params, experiments, n_harmonics, noise)
        timings["classification"] = time.perf_counter() - t0
        if refine == "joint" and static is not None and static.method == "lsq":
            t0 = time.perf_counter()
            fallback = _curvature_fallback(static, params)
            fit_c = (fit_curvature is not False) and bool(experiments.sines)
            for _round in range(3):
                pts = _points_from(classification, experiments)
                try:
                    joint = fit_joint(params, experiments.all_static(), experiments.steps, pts,
                                      _static_sigma(static), noise_m=noise,
                                      prior_beta_gamma=static.prior_beta_gamma, fit_curvature=fit_c,
                                      fit_slope=stress_terms >= 2,
                                      curvature_fallback_Pa=float(EXTENDED_COMBINATION_MATRIX[2] @ fallback),
                                      n_harmonics=n_harmonics, progress=progress)
                except JointFitError as exc:
                    warnings.append(f"joint refinement failed ({exc}); the two-stage result is reported")
                    joint = None
                    break
                params = joint.parameters
                if not experiments.sines:
                    break
                t1 = time.perf_counter()
                again = classify_records(params, experiments, n_harmonics, noise)
                timings["classification"] += time.perf_counter() - t1
                changed = _kinds(again) != _kinds(classification)
                classification = again
                if not changed:
                    break
            timings["joint_fit"] = time.perf_counter() - t0
            if joint is not None:
                warnings += joint.warnings
                if joint.curvature_fitted:
                    k = joint.names.index("sigma_h''(1)_Pa")
                    rel = float(joint.statistics.relative_ci[k])
                    if rel <= CURVATURE_REL_CI_LIMIT:
                        curvature_identified, curvature_status = True, "identified"
                    elif rel < 1.0:
                        curvature_identified, curvature_status = True, "poorly determined"
                        warnings.append(
                            f"sigma_h''(1) is poorly determined by these data "
                            f"(95 % interval +-{100 * rel:.0f} % of its "
                            "value, sign known): written as fitted, flagged in params.yaml; records near the "
                            "resonance peak (large amplitude) would pin it down")
                    else:
                        curvature_identified, curvature_status = False, "not identified"
                        # sigma_h''(1) held at the base value; sigma_h'''(1) (with which it trades off at
                        # these amplitudes) stays free, so the data keep their fit and the other parameters
                        # their values; the reported values and intervals are those of this fit
                        base_c2 = float(EXTENDED_COMBINATION_MATRIX[2] @ fallback)
                        c_free = EXTENDED_COMBINATION_MATRIX @ np.r_[params.beta_Pa, params.gamma_Pa]
                        start = _set_combinations(params, [c_free[0], c_free[1], base_c2, c_free[3]],
                                                  static.prior_beta_gamma)
                        chi_free = joint.cost
                        pts_now = _points_from(classification, experiments)
                        # first both curvature terms at the base values: when the data accept them (chi-square
                        # within 9 of the free fit) that is the written law
                        held = fit_joint(_with_base_curvature(params, fallback), experiments.all_static(),
                                         experiments.steps, pts_now, _static_sigma(static), noise_m=noise,
                                         prior_beta_gamma=static.prior_beta_gamma, fit_curvature=False,
                                         fit_slope=stress_terms >= 2,
                                         curvature_fallback_Pa=base_c2, n_harmonics=n_harmonics, progress=progress)
                        how = "both curvature terms at the base values"
                        if held.cost - chi_free > 9.0:
                            held = fit_joint(start, experiments.all_static(), experiments.steps, pts_now,
                                             _static_sigma(static), noise_m=noise,
                                             prior_beta_gamma=static.prior_beta_gamma, fit_curvature="third",
                                             fit_slope=stress_terms >= 2,
                                             curvature_fallback_Pa=base_c2, n_harmonics=n_harmonics,
                                             progress=progress)
                            how = ("sigma_h''(1) at the base value, sigma_h'''(1) refitted "
                                   "(the data reject both at base)")
                        written = held.parameters
                        held.statistics = _marginal_statistics(held.statistics, joint.statistics)
                        refit_note = (f" Written with {how}: chi-square {held.cost - chi_free:+.3g} against the free "
                                      "fit; the 95 % intervals keep the widths of the free fit (they allow for the "
                                      "unknown curvature).")
                        free_joint = joint
                        joint = held
                        joint.warnings = free_joint.warnings + \
                            [w for w in held.warnings if w not in free_joint.warnings]
                        params = written
                        near = [c for c in classification if c["used"] != "left out"
                                and c["measured_rms_m"] > 0.5 * max(x["measured_rms_m"] for x in classification)]
                        hint = ("" if len(near) >= 3 else
                                " Records near the resonance peak (large amplitude) would determine it.")
                        warnings.append(
                            "sigma_h''(1) (curvature of the hyperelastic stress, eq. 10) is not identified by these "
                            f"data (95 % interval +-{100 * rel:.0f} % of the fitted value: sign unknown): params.yaml "
                            f"carries the base value {EXTENDED_COMBINATION_MATRIX[2] @ fallback / 1e3:.6g} kPa "
                            "(derivative in s = lambda^2) and says 'not identified'; the other parameters' intervals "
                            "allow for its uncertainty." + refit_note + hint)
                else:
                    curvature_identified = None
        elif experiments.sines:
            if refine == "joint":
                warnings.append("joint refinement skipped: it needs the least-squares static fit "
                                "(static_method='lsq'); "
                                "the two-stage result is reported")
            if not dynamic.curvature_fitted:
                curvature_identified, curvature_status = False, "not identified"
                warnings.append(
                    "sigma_h''(1) (curvature of the hyperelastic stress, eq. 10) is not identified: the static "
                    "deflections cannot see it and this fit did not use it; params.yaml says 'not identified'")
        for c in classification:
            if c.get("note"):
                warnings.append(f"{c['source']}: {c['frequency_Hz']:g} Hz: {c['note']}")
            if c["used"] == "left out":
                warnings.append(f"{c['source']}: the record at {c['frequency_Hz']:g} Hz is left out of the fit: "
                                f"{c.get('reason', '')}")
        curvature_written = float(stress_combinations(params.beta_Pa, params.gamma_Pa)[2])
    if static is not None:
        warnings = static.warnings + warnings
    metrics: dict = {}
    curves: dict = {}
    if evaluate_fit:
        t0 = time.perf_counter()
        final_class = classification if (classification and joint is not None) else None
        metrics, curves, quality = evaluate(params, experiments, n_harmonics, classification=final_class)
        if dynamic is not None and curves.get("steps") and joint is None:
            fast = dynamic.step_simulated_m
            diffs = [float(np.max(np.abs(f - c["simulated_m"]))) * 1e6 for f, c in zip(fast, curves["steps"])]
            metrics["transient_solver_max_difference_um"] = max(diffs)
        elif curves.get("steps"):
            sims = [TransientCollocation(st.time_s, st.voltage_V, hold=st.voltage_hold)
                    .solve(params.replace(mass_kg=st.mass_kg)).displacement_m for st in experiments.steps]
            metrics["transient_solver_max_difference_um"] = max(
                float(np.max(np.abs(a - c["simulated_m"]))) * 1e6 for a, c in zip(sims, curves["steps"]))
        warnings += quality
        timings["evaluation"] = time.perf_counter() - t0
    bands = []
    if uncertainty_samples and experiments.sines:
        t0 = time.perf_counter()
        bands, band_warnings = _uncertainty_bands(params, joint.statistics if joint is not None else (
            dynamic.statistics if dynamic is not None else None), experiments, int(uncertainty_samples), n_harmonics,
            engine, metrics)
        warnings += band_warnings
        timings["uncertainty"] = time.perf_counter() - t0
    timings["identification_total"] = time.perf_counter() - t_start
    options = {"static_method": static_method, "dynamic_method": dynamic_method,
               "frequency_method": frequency_method, "n_harmonics": n_harmonics,
               "stress_terms": stress_terms, "fit_frequencies_Hz": fit_frequencies_Hz,
               "fit_curvature": bool(dynamic is not None and dynamic.curvature_fitted)
               or bool(joint is not None and joint.curvature_fitted),
               "weights": weights if isinstance(weights, (str, type(None))) else dict(weights),
               "refine": refine if joint is not None else "none", "uncertainty_samples": int(uncertainty_samples)}
    # Drop duplicates, keep order.
    seen = set()
    unique = [w for w in warnings if not (w in seen or seen.add(w))]
    return IdentificationResult(experiments, params, static, dynamic, metrics, curves, timings, unique, options,
                                joint=joint, classification=classification,
                                curvature_identified=curvature_identified, curvature_written_Pa=curvature_written,
                                curvature_status=curvature_status, uncertainty=bands)
