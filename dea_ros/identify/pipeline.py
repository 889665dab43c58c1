"""The whole identification: experiments -> static fit -> dynamic fit -> evaluation (metrics, curves).

:func:`identify` runs the two-step procedure of the paper (section IV): the static
parameters from the rest displacements (eqs. 19-20), then k1, eta1, eta2 from the step and
frequency responses with the static parameters fixed (eqs. 22-24). :func:`evaluate` then
checks the fitted model against *all* the data with the accurate solvers (adaptive
integration for the steps, harmonic balance with Floquet stability for a dense frequency
sweep) and computes the metrics of Tables III-IV; quality checks turn a model that does not
reproduce the data within the noise into warnings, never a silent fit.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..model.equilibrium import NoEquilibriumError, static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers.harmonic_balance import HarmonicBalanceError, solve_native
from ..solvers.inputs import SampledVoltage, SinePeriodic
from ..solvers.integrate import simulate
from ..solvers.transient import TransientCollocation
from .dynamic_fit import DynamicFitResult, fit_dynamic
from .experiments import ExperimentError, ExperimentSet, data_warnings, estimate_noise_m
from .metrics import resonance_peak_Hz, static_errors_um, step_error_indices
from .static_fit import StaticFitResult, fit_static, stress_combinations

__all__ = ["IdentificationResult", "IdentificationError", "identify", "evaluate", "frequency_sweep"]


class IdentificationError(ExperimentError):
    """The experiment set cannot be identified as asked (the message says what is missing)."""


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


def frequency_sweep(params: MembraneParameters, amplitude_V: float, frequencies_Hz, n_harmonics: int = 8,
                    mass_kg: float | None = None):
    """d_rms (eq. 21, around the rest position at 0 V) and stability over frequencies, by harmonic
    balance with continuation in ascending frequency. Failed points are NaN."""
    p = params if mass_kg is None else params.replace(mass_kg=mass_kg)
    d0 = float(static_equilibrium(p, 0.0).displacement_m)
    freqs = np.asarray(frequencies_Hz, float)
    order = np.argsort(freqs)
    rms = np.full(freqs.size, np.nan)
    stable = np.zeros(freqs.size, dtype=bool)
    guess = None
    for k in order:
        try:
            sol = solve_native(p, SinePeriodic(amplitude_V, float(freqs[k])), n_harmonics, x_guess=guess,
                               stability=True)
        except HarmonicBalanceError:
            guess = None
            continue
        guess = sol.state
        rms[k] = sol.displacement_rms(d0)
        stable[k] = bool(sol.stable)
    return rms, stable


def _series_model(params, series, amplitude_V, n_harmonics):
    """Model displacement at the samples of a sine record (phase aligned on the voltage samples)."""
    w = 2.0 * np.pi * series.frequency_Hz
    t = series.time_s
    basis = np.column_stack([np.sin(w * t), np.cos(w * t)])
    (a, b), *_ = np.linalg.lstsq(basis, series.voltage_V, rcond=None)
    phase = math.atan2(b, a)  # u = A sin(w t + phase)
    sol = solve_native(params, SinePeriodic(amplitude_V, series.frequency_Hz), n_harmonics, stability=False)
    return sol.evaluate(t + phase / w)[0]


def evaluate(params: MembraneParameters, experiments: ExperimentSet, n_harmonics: int = 8,
             sweep_points: int = 400) -> tuple[dict, dict, list]:
    """Metrics and plot curves of ``params`` against every experiment (accurate solvers).

    Returns (metrics, curves, warnings).
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
    freq_metrics = []
    curves["sines"] = []
    for sine in experiments.sines:
        p = params.replace(mass_kg=sine.mass_kg)
        f = sine.frequency_Hz
        amps = np.unique(sine.amplitude_V)
        entry = {"source": sine.source}
        model_at_data = np.full(f.size, np.nan)
        stable_at_data = np.zeros(f.size, dtype=bool)
        dense_curves = []
        for a in amps:
            sel = sine.amplitude_V == a
            model_at_data[sel], stable_at_data[sel] = frequency_sweep(p, float(a), f[sel], n_harmonics)
            f_dense = np.unique(np.r_[np.linspace(f[sel].min(), f[sel].max(), sweep_points), f[sel]])
            rms_dense, stab_dense = frequency_sweep(p, float(a), f_dense, n_harmonics)
            dense_curves.append((float(a), f_dense, rms_dense, stab_dense))
            if np.count_nonzero(sel) >= 3:
                f_meas = resonance_peak_Hz(f[sel], sine.d_rms_m[sel])
                ok = np.isfinite(rms_dense) & stab_dense
                f_sim = resonance_peak_Hz(f_dense[ok], rms_dense[ok]) if np.any(ok) else float("nan")
                entry.setdefault("resonance", []).append({
                    "amplitude_V": float(a), "measured_peak_Hz": f_meas, "simulated_peak_Hz": f_sim,
                    "error_percent": 100.0 * abs(f_sim - f_meas) / f_meas,
                })
        if sine.inputs:  # the applied waveforms were measured: compare the model under them
            d0_model = float(static_equilibrium(p, 0.0).displacement_m)
            for k, inp in enumerate(sine.inputs):
                try:
                    sol = solve_native(p, inp, n_harmonics, stability=True)
                except HarmonicBalanceError:
                    continue
                model_at_data[k], stable_at_data[k] = sol.displacement_rms(d0_model), bool(sol.stable)
        err = (model_at_data - sine.d_rms_m) * 1e6
        ok = np.isfinite(err)
        entry["rms_error_um"] = float(np.sqrt(np.mean(err[ok] ** 2))) if np.any(ok) else None
        entry["max_error_um"] = float(np.max(np.abs(err[ok]))) if np.any(ok) else None
        entry["max_relative_error_percent"] = (float(np.max(np.abs(err[ok]) / (sine.d_rms_m[ok] * 1e6))) * 100.0
                                               if np.any(ok) else None)
        entry["frequencies"] = int(f.size)
        unstable = f[ok & ~stable_at_data]
        if unstable.size:
            warnings.append(
                f"{sine.source}: the fitted model has no stable periodic response at "
                + ", ".join(f"{x:g}" for x in unstable) + " Hz (fold or parametric resonance): the rig "
                "shows a different response there (period doubling or a jump)"
            )
        failed = f[~ok]
        if failed.size:
            warnings.append(f"{sine.source}: harmonic balance failed at " + ", ".join(f"{x:g}" for x in failed) + " Hz")
        series_out = []
        for ser in sine.series:
            try:
                amp = float(np.max(np.abs(ser.voltage_V)))
                model_d = _series_model(p, ser, amp, n_harmonics)
                e = (model_d - ser.displacement_m) * 1e6
                series_out.append({"series": ser, "model_m": model_d,
                                   "rms_error_um": float(np.sqrt(np.mean(e**2)))})
                entry.setdefault("series_rms_error_um", {})[f"{ser.frequency_Hz:g} Hz"] = float(np.sqrt(np.mean(e**2)))
            except HarmonicBalanceError as exc:
                warnings.append(f"{ser.source}: no model response ({exc})")
        freq_metrics.append(entry)
        curves["sines"].append({"sine": sine, "model_at_data_m": model_at_data, "stable_at_data": stable_at_data,
                                "dense": dense_curves, "series": series_out})
    if freq_metrics:
        metrics["frequency_response"] = freq_metrics
    return metrics, curves, warnings


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
) -> IdentificationResult:
    """Identify all parameters of ``experiments`` (see the module docstring).

    ``weights``: "paper" (default, eq. 22 with w_step = 6.6e6, w_hbm = 0.1e6), "noise"
    (1/sigma^2 statistical weights) or a dict (see :func:`~dea_ros.identify.dynamic_fit.resolve_weights`).
    ``fit_curvature``: also identify sigma_h''(1) in the dynamic fit; "auto": with the
    least-squares fits, sine data and ``weights="noise"`` (with the paper's weights the
    frequency data carry ~1e-4 of the cost and cannot determine it).
    """
    t_start = time.perf_counter()
    timings: dict = {}
    warnings = list(data_warnings(experiments))
    template = experiments.template_parameters()
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
    dynamic = None
    if experiments.steps or experiments.sines:
        t0 = time.perf_counter()
        if fit_curvature == "auto":
            # sigma_h''(1) is only determined when the frequency data carry their statistical weight
            fit_curvature = bool(static is not None and static.method == "lsq" and dynamic_method == "lsq"
                                 and experiments.sines and weights == "noise" and stress_terms == 2)
        direction = static.curvature_direction() if (fit_curvature and static is not None) else None
        if fit_curvature and (direction is None or stress_terms != 2):
            raise IdentificationError("fit_curvature needs the least-squares static fit (static_method='lsq') "
                                      "with sigma_h(1) and sigma_h'(1) fitted (stress_terms=2, enough static points)")
        dyn_kw = dict(method=dynamic_method, frequency_method=frequency_method,
                      fit_frequencies_Hz=fit_frequencies_Hz, weights=weights, n_harmonics=n_harmonics,
                      progress=progress, noise_m=experiments.sensor_noise_m)
        dynamic = fit_dynamic(params, experiments.steps, experiments.sines, start=experiments.base_parameters,
                              curvature_direction=direction, **dyn_kw)
        evaluations = dynamic.n_evaluations
        t_step, t_freq = dynamic.time_step_s, dynamic.time_frequency_s
        if direction is not None:
            # sigma_h''(1) moved: refit sigma_h(1), sigma_h'(1), eps_r with it fixed, then polish
            # the dynamic parameters from the previous optimum (the coupling is weak).
            curvature = float(stress_combinations(dynamic.parameters.beta_Pa, dynamic.parameters.gamma_Pa)[2])
            t1 = time.perf_counter()
            static = fit_static(experiments.all_static(), template, method=static_method,
                                stress_terms=stress_terms, curvature_Pa=curvature,
                                prior_from_template=experiments.base_parameters is not None)
            timings["static_fit"] += time.perf_counter() - t1
            first = dynamic
            dynamic = fit_dynamic(static.parameters, experiments.steps, experiments.sines,
                                  curvature_direction=static.curvature_direction(),
                                  initial=first.parameters, **dyn_kw)
            dynamic.initial = first.initial
            dynamic.n_evaluations += evaluations
            dynamic.time_step_s += t_step
            dynamic.time_frequency_s += t_freq
            dynamic.starts = first.starts + dynamic.starts
        timings["dynamic_fit"] = time.perf_counter() - t0
        timings["dynamic_fit_step_simulations"] = dynamic.time_step_s
        timings["dynamic_fit_frequency_response"] = dynamic.time_frequency_s
        params = dynamic.parameters
        warnings += dynamic.warnings
        if experiments.sines and not dynamic.curvature_fitted:
            warnings.append(
                "sigma_h''(1) (curvature of the hyperelastic stress, eq. 10) is not identified: the static "
                "deflections cannot see it and with the paper's weights the frequency data carry too little "
                "weight; the large-amplitude response near resonance depends on it (an extrapolation here). "
                "To identify it use weights='noise' with frequencies near the resonance "
                "(--weights noise --fit-frequencies all)"
            )
        elif dynamic.curvature_fitted and dynamic.statistics is not None:
            k = dynamic.statistics.names.index("sigma_h''(1)_Pa")
            if dynamic.statistics.relative_ci[k] > 0.5:
                warnings.append("sigma_h''(1) is poorly determined by the fit frequencies: include frequencies "
                                "near the resonance peak (--fit-frequencies all)")
    if static is not None:
        warnings = static.warnings + warnings
    metrics: dict = {}
    curves: dict = {}
    if evaluate_fit:
        t0 = time.perf_counter()
        metrics, curves, quality = evaluate(params, experiments, n_harmonics)
        if dynamic is not None and curves.get("steps"):
            fast = dynamic.step_simulated_m
            diffs = [float(np.max(np.abs(f - c["simulated_m"]))) * 1e6 for f, c in zip(fast, curves["steps"])]
            metrics["transient_solver_max_difference_um"] = max(diffs)
        warnings += quality
        timings["evaluation"] = time.perf_counter() - t0
    timings["identification_total"] = time.perf_counter() - t_start
    options = {"static_method": static_method, "dynamic_method": dynamic_method,
               "frequency_method": frequency_method, "n_harmonics": n_harmonics,
               "stress_terms": stress_terms, "fit_frequencies_Hz": fit_frequencies_Hz,
               "fit_curvature": bool(dynamic is not None and dynamic.curvature_fitted),
               "weights": weights if isinstance(weights, (str, type(None))) else dict(weights)}
    # Drop duplicates, keep order.
    seen = set()
    unique = [w for w in warnings if not (w in seen or seen.add(w))]
    return IdentificationResult(experiments, params, static, dynamic, metrics, curves, timings, unique, options)
