"""The fitted model against all the data: the evaluation of an identification (a result object).

:func:`evaluate` checks a parameter set against *every* experiment with the accurate solvers
(the static equilibria of eq. 20; adaptive integration for the steps, or the collocation solver
for a measured noisy voltage; the realised response of a continuation sweep for the frequency
response) and returns an :class:`Evaluation`: one comparison per data kind (static points, each
step, each frequency response with its sampled records), the metrics of Tables III-IV and the
curves of Figs. 6-8, and the warnings where the model does not reproduce the data within the
noise -- never a silent fit. The report and the figures read it; :meth:`Evaluation.to_dict` is
the ``metrics`` of result.json.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model.equilibrium import NoEquilibriumError, static_equilibrium
from ..model.parameters import MembraneParameters
from ..errors import HarmonicBalanceError
from ..solvers.inputs import SampledVoltage
from ..solvers.integrate import simulate
from .classification import classify_records, sweep_for
from .experiments import ExperimentSet, SineData, SineSeries, StaticData, StepData, estimate_noise_m
from .frequency_points import FrequencyPoint, point_solution, rms_reference_m
from .jsonable import jsonable
from .metrics import measured_resonance_peak, static_errors_um, step_error_indices
from .step_simulation import simulate_step

__all__ = ["Evaluation", "StaticComparison", "StepComparison", "SineComparison", "SeriesComparison", "evaluate",
           "series_model", "DISAGREEMENT_FRACTION"]

#: a fitted record whose model d_rms is further than this (relative) and 5 sigma from the data is reported
DISAGREEMENT_FRACTION = 0.02


@dataclass
class StaticComparison:
    """Fig. 6: the static points and the model's rest displacements (m)."""

    data: StaticData
    predicted_m: np.ndarray                 # the model at every point
    voltage_curves: dict                    # mass (kg) -> (voltage V, displacement m) curve of the model
    mass_curve: tuple                       # (masses kg, displacement m) of the model at 0 V
    errors_um: dict                         # rms_error_um, max_error_um (model - data)

    def to_dict(self) -> dict:
        """The static metrics (um)."""
        return dict(self.errors_um)


@dataclass
class StepComparison:
    """Fig. 8 (left), Table III: a step record and the model's response."""

    step: StepData
    simulated_m: np.ndarray
    indices: dict                           # IAE_mm_s, ISE_mm2_s, ITAE_mm_s2, rms_error_um, max_error_um
    noise_um: float | None                  # the laser noise the error is judged against

    def to_dict(self) -> dict:
        """Table III's error indices, the noise and the record's source."""
        return {**self.indices, "noise_um": self.noise_um, "source": self.step.source}


@dataclass
class SeriesComparison:
    """A sampled sine record and the model at its samples (None when there is no model response)."""

    series: SineSeries
    model_m: np.ndarray | None = None
    rms_error_um: float | None = None
    phase_rad: float | None = None
    kind: str | None = None                 # the solution shown: "periodic" or "period-doubled"
    how: str = "aligned on the phase of u^2"
    note: str = ""                          # why there is no model response


@dataclass
class SineComparison:
    """Figs. 7-8 (right), Table IV: a frequency response, the model's d_rms (eq. 21) and its sweeps."""

    sine: SineData
    model_at_data_m: np.ndarray             # the model's d_rms at every record (NaN where not compared)
    used: list                              # per record: "periodic", "period-doubled" or "left out"
    dense: list = field(default_factory=list)       # (amplitude V, frequency sweep of the model, offset V)
    resonance: list = field(default_factory=list)   # per amplitude: the model's and the data's peak
    bands: list = field(default_factory=list)       # the model's bands (what a measurement sees)
    rms_error_um: float | None = None
    max_error_um: float | None = None
    max_relative_error_percent: float | None = None
    normalised_rms_error: float | None = None       # RMS of (model - data) / d_rms_std_m
    compared: int = 0                       # records compared with a periodic model response
    not_reproduced: list = field(default_factory=list)
    series: list = field(default_factory=list)      # SeriesComparison per sampled record
    series_model: str | None = None         # how the model was put on the sampled records
    series_rms_error_um: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Table IV's metrics of this frequency response."""
        out = {"source": self.sine.source, "waveform": self.sine.waveform}
        if self.dense:
            out["resonance"] = list(self.resonance)
            out["bands"] = list(self.bands)
        out.update({"rms_error_um": self.rms_error_um, "max_error_um": self.max_error_um,
                    "max_relative_error_percent": self.max_relative_error_percent,
                    "frequencies": int(self.sine.frequency_Hz.size), "compared": self.compared,
                    "kinds": list(self.used)})
        if self.normalised_rms_error is not None:
            out["normalised_rms_error"] = self.normalised_rms_error
        if self.not_reproduced:
            out["not_reproduced"] = list(self.not_reproduced)
        if self.series_rms_error_um:
            out["series_model"] = self.series_model
            out["series_rms_error_um"] = dict(self.series_rms_error_um)
        return out


@dataclass
class Evaluation:
    """The fitted model against every experiment (module docstring); empty when not evaluated."""

    static: StaticComparison | None = None
    steps: list = field(default_factory=list)       # StepComparison per step record
    sines: list = field(default_factory=list)       # SineComparison per frequency response
    warnings: list = field(default_factory=list)    # where the model does not reproduce the data
    #: the fast transient solver of the fit against the evaluation's accurate one (um, steps only)
    transient_solver_max_difference_um: float | None = None

    def to_dict(self) -> dict:
        """The metrics, JSON-ready (result.json ``metrics``)."""
        out: dict = {}
        if self.static is not None:
            out["static"] = self.static.to_dict()
        if self.steps:
            out["steps"] = [s.to_dict() for s in self.steps]
        if self.sines:
            out["frequency_response"] = [s.to_dict() for s in self.sines]
        if self.transient_solver_max_difference_um is not None:
            out["transient_solver_max_difference_um"] = self.transient_solver_max_difference_um
        return jsonable(out)


# --------------------------------------------------------------------------- static and steps
def _compare_static(params: MembraneParameters, data: StaticData) -> StaticComparison:
    predicted = np.zeros(data.n_points)
    for m in np.unique(data.mass_kg):
        sel = data.mass_kg == m
        predicted[sel] = static_equilibrium(params, data.voltage_V[sel], mass_kg=float(m)).displacement_m
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
    return StaticComparison(data, predicted, curve, (masses, d_mass), static_errors_um(data.displacement_m, predicted))


def _compare_step(params: MembraneParameters, step: StepData, noise: float | None, warnings: list) -> StepComparison:
    p = params.replace(mass_kg=step.mass_kg)
    jumps = int(np.count_nonzero(np.diff(step.voltage_V)))
    if step.voltage_hold == "zoh" and jumps > 50:
        # A measured (noisy) voltage: every sample is a breakpoint of the adaptive integrator;
        # use the collocation solver (validated to ~1 nm against it) instead.
        sim_d = simulate_step(p, step)
    else:
        sim_d = simulate(p, SampledVoltage(step.time_s, step.voltage_V, hold=step.voltage_hold),
                         float(step.time_s[-1]), t_eval=step.time_s, t_start_s=float(step.time_s[0]),
                         rtol=1e-10, atol_scale=1e-10).displacement_m
    idx = step_error_indices(step.time_s, step.displacement_m, sim_d, step.step_time_s)
    est = estimate_noise_m(step)
    sigma = noise if noise is not None else est
    if sigma is not None and idx["rms_error_um"] > 2.0 * sigma * 1e6:
        warnings.append(
            f"{step.source}: the fitted model does not reproduce the step within the noise "
            f"(RMS error {idx['rms_error_um']:.3g} um vs noise {sigma * 1e6:.3g} um): the model or the "
            "data are inconsistent (unsettled rig, wrong mass, nonlinearity not in the model?)"
        )
    return StepComparison(step, sim_d, idx, None if sigma is None else sigma * 1e6)


# --------------------------------------------------------------------------- frequency response
def _record_point(sine: SineData, k: int, entry: dict, measured: bool = True) -> FrequencyPoint:
    """The frequency point of record ``k`` as classified (``measured``: with its measured RMS)."""
    return FrequencyPoint(float(sine.frequency_Hz[k]), float(sine.amplitude_V[k]),
                          float(sine.d_rms_m[k]) if measured else 0.0, sine.mass_kg, sine.source,
                          periodic_input=sine.inputs[k] if sine.inputs else None, kind=entry["used"],
                          guess=entry.get("guess"), rest_d0_m=sine.rest_d0(k))


def _model_at_data(p: MembraneParameters, sine: SineData, by_rec: dict, n_harmonics: int, warnings: list):
    """(the model's d_rms at every record, NaN where left out; how each record was compared)."""
    f = sine.frequency_Hz
    model_at_data = np.full(f.size, np.nan)
    used = ["left out"] * f.size
    for k in range(f.size):
        c = by_rec.get((sine.source, k))
        if c is None or c["used"] == "left out":
            continue
        point = _record_point(sine, k, c)
        try:
            sol = point_solution(p, point, n_harmonics)
        except HarmonicBalanceError as exc:
            warnings.append(f"{sine.source}: no model response at {f[k]:g} Hz ({exc})")
            continue
        model_at_data[k] = sol.displacement_rms(rms_reference_m(p, point))   # as the fit compares it
        used[k] = c["used"]
    return model_at_data, used


def _add_sweeps(out: SineComparison, p: MembraneParameters, n_harmonics: int, sweep_points: int,
                warnings: list) -> None:
    """The model's sweep per amplitude (dense curve, resonance peak of Table IV, bands) into ``out``."""
    sine, f = out.sine, out.sine.frequency_Hz
    for a, offset, sel in sine.waveform_groups():
        f_dense = np.unique(np.r_[np.linspace(f[sel].min(), f[sel].max(), sweep_points), f[sel]])
        try:
            sweep = sweep_for(p, a, f_dense, n_harmonics, offset_V=offset)
        except (HarmonicBalanceError, RuntimeError) as exc:
            warnings.append(f"{sine.source}: the model sweep at {a:g} V" + (f" + {offset:g} V offset" if offset else "")
                            + f" failed ({exc})")
            continue
        out.dense.append((a, sweep, offset))
        peak = sweep.resonance_peak(True)
        meas = measured_resonance_peak(f[sel], sine.d_rms_m[sel], [out.used[k] == "periodic" for k in sel])
        res = {"amplitude_V": a, **({"offset_V": offset} if offset else {}), "simulated_peak_Hz": peak["frequency_Hz"],
               "simulated_peak_rms_m": peak["d_rms_m"], "measured_peak_Hz": meas["frequency_Hz"],
               "measured": meas["measured"], "measured_note": meas["note"]}
        if meas["measured"]:
            res["error_percent"] = 100.0 * abs(peak["frequency_Hz"] - meas["frequency_Hz"]) / meas["frequency_Hz"]
        else:
            res["error_percent"] = None
        out.resonance.append(res)
        out.bands.extend([{"amplitude_V": a, **({"offset_V": offset} if offset else {}), **b.to_dict()}
                          for b in sweep.bands])


def _add_errors(out: SineComparison, warnings: list) -> None:
    """The d_rms errors (um, relative, in standard uncertainties) and the records the model does not reproduce."""
    sine, f, model_at_data = out.sine, out.sine.frequency_Hz, out.model_at_data_m
    err = (model_at_data - sine.d_rms_m) * 1e6
    ok = np.isfinite(err)
    out.rms_error_um = float(np.sqrt(np.mean(err[ok] ** 2))) if np.any(ok) else None
    out.max_error_um = float(np.max(np.abs(err[ok]))) if np.any(ok) else None
    out.max_relative_error_percent = (float(np.max(np.abs(err[ok]) / (sine.d_rms_m[ok] * 1e6))) * 100.0
                                      if np.any(ok) else None)
    out.compared = int(np.count_nonzero(ok))
    if sine.d_rms_std_m is not None and np.any(ok):
        z = err[ok] / (sine.d_rms_std_m[ok] * 1e6)
        out.normalised_rms_error = float(np.sqrt(np.mean(z**2)))
    # records the model does not reproduce: beyond the noise and by more than 2 % (a fitted
    # record is not a reproduced one)
    for k in np.nonzero(ok)[0]:
        rel = err[k] / (sine.d_rms_m[k] * 1e6)
        zk = err[k] / (sine.d_rms_std_m[k] * 1e6) if sine.d_rms_std_m is not None else None
        if abs(rel) > DISAGREEMENT_FRACTION and (zk is None or abs(zk) > 5.0):
            out.not_reproduced.append(f"{f[k]:g} Hz (data {sine.d_rms_m[k] * 1e6:.4g} um, model "
                                      f"{model_at_data[k] * 1e6:.4g} um, {100 * rel:+.1f} %"
                                      + (f", {zk:+.0f} sigma" if zk is not None else "") + ")")
    if out.not_reproduced:
        warnings.append(f"{sine.source}: the fitted model does not reproduce the record at "
                        + "; ".join(out.not_reproduced)
                        + ": a model-data disagreement (an excitation the model does not see, a record not "
                        "settled, or a model error), not a fit within the noise")


def _add_series(out: SineComparison, p: MembraneParameters, by_rec: dict, n_harmonics: int, noise: float | None,
                warnings: list) -> None:
    """The model on every sampled record of the frequency response (Fig. 'sampled sine records')."""
    sine, f = out.sine, out.sine.frequency_Hz
    for ser in sine.series:
        k = int(np.argmin(np.abs(f - ser.frequency_Hz)))
        c = by_rec.get((sine.source, k))
        if c is None or c["used"] == "left out" or abs(f[k] - ser.frequency_Hz) > 1e-9 * f[k]:
            out.series.append(SeriesComparison(ser, note=(c or {}).get("reason", "no model response")))
            continue
        try:
            sol = point_solution(p, _record_point(sine, k, c, measured=False), n_harmonics)
            model_d, phase = series_model(p, ser, float(sine.amplitude_V[k]), n_harmonics, solution=sol,
                                          periodic_input=sine.inputs[k] if sine.inputs else None)
        except HarmonicBalanceError as exc:
            warnings.append(f"{ser.source}: no model response ({exc})")
            continue
        e = (model_d - ser.displacement_m) * 1e6
        rms_e = float(np.sqrt(np.mean(e**2)))
        how = "driven by the recorded voltage" if sine.inputs else "aligned on the phase of u^2"
        out.series.append(SeriesComparison(ser, model_d, rms_e, phase, c["used"], how))
        out.series_model = how
        out.series_rms_error_um[f"{ser.frequency_Hz:g} Hz"] = rms_e
        sigma = noise if noise is not None else ser.noise_m()
        if sigma is not None and rms_e > 3.0 * sigma * 1e6:
            warnings.append(f"{ser.source}: the model does not reproduce the sampled record: RMS error "
                            f"{rms_e:.3g} um against {sigma * 1e6:.2g} um laser noise (a transient that has not "
                            "died out, an excitation the model does not see, or a model error)")


def _compare_sine(params: MembraneParameters, sine: SineData, by_rec: dict, classification: list | None,
                  own_classification: bool, n_harmonics: int, sweep_points: int, noise: float | None,
                  warnings: list) -> SineComparison:
    p = params.replace(mass_kg=sine.mass_kg)
    model_at_data, used = _model_at_data(p, sine, by_rec, n_harmonics, warnings)
    out = SineComparison(sine, model_at_data, used)
    _add_sweeps(out, p, n_harmonics, sweep_points, warnings)
    _add_errors(out, warnings)
    left = sine.frequency_Hz[[u == "left out" for u in used]]
    if left.size and own_classification:
        reasons = {c["frequency_Hz"]: c.get("reason", "") for c in (classification or [])
                   if c["source"] == sine.source and c["used"] == "left out"}
        warnings.append(f"{sine.source}: not compared with a periodic model response at "
                        + "; ".join(f"{x:g} Hz ({reasons.get(float(x), 'no solution')})" for x in left))
    _add_series(out, p, by_rec, n_harmonics, noise, warnings)
    return out


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


# --------------------------------------------------------------------------- evaluation
def evaluate(params: MembraneParameters, experiments: ExperimentSet, n_harmonics: int = 8,
             sweep_points: int = 120, classification: list | None = None) -> Evaluation:
    """The :class:`Evaluation` of ``params`` against every experiment (accurate solvers).

    ``classification`` (from :func:`~dea_ros.identify.classification.classify_records` with these
    parameters; computed when None) says which solution each sine record is compared with.
    """
    noise = experiments.sensor_noise_m
    out = Evaluation()
    data = experiments.all_static()
    if data is not None:
        out.static = _compare_static(params, data)
    out.steps = [_compare_step(params, step, noise, out.warnings) for step in experiments.steps]
    own_classification = bool(experiments.sines and classification is None)
    if own_classification:
        classification = classify_records(params, experiments, n_harmonics, noise)
    by_rec = {(c["source"], c["index"]): c for c in (classification or [])}
    out.sines = [_compare_sine(params, sine, by_rec, classification, own_classification, n_harmonics, sweep_points,
                               noise, out.warnings) for sine in experiments.sines]
    return out
