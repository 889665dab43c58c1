"""report.md: the text of the identification report, one function per section.

:func:`report_markdown` joins the sections in the order a reader needs them: what was done
(:func:`header`), the warnings first (they matter most), the parameters (Table II), the sine records
and how they were fitted, the quality of the fit (Tables III-IV), the uncertainty of the frequency
response, the three fits, the timings and the figures. Every section reads the result objects
(:class:`~dea_ros.identify.result.IdentificationResult` and its
:class:`~dea_ros.identify.evaluation.Evaluation`) and returns its lines.
"""
from __future__ import annotations

import math
import platform
import time
from pathlib import Path

import numpy as np

from ..evaluation import SineComparison
from ..metrics import linear_combination_ci
from ..result import IdentificationResult
from ..static_fit import stress_combinations

__all__ = ["report_markdown", "header", "warnings_section", "parameters_section", "classification_section",
           "quality_section", "uncertainty_section", "determination_section",
           "curvature_sensitivity_section", "fits_section", "timings_section", "figures_section",
           "applied_input_text", "WAVEFORM_TEXT"]

WAVEFORM_TEXT = {"sine": "u = U sin(2 pi f t)", "abs_sine": "u = |U sin(2 pi f t)| (unipolar amplifier)"}


# --------------------------------------------------------------------------- formatting
def _fmt(x, digits=4):
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    x = float(x)
    if not math.isfinite(x):
        return "inf"
    return f"{x:.{digits}g}"


def _ci_text(stats, name, scale=1.0):
    if stats is None or name not in stats.names:
        return "-", "-"
    i = stats.names.index(name)
    lo, hi, rel = stats.ci_low[i], stats.ci_high[i], stats.relative_ci[i]
    if not math.isfinite(rel):
        return "not identifiable", "inf"
    return f"[{_fmt(lo * scale)}, {_fmt(hi * scale)}]", f"{100 * rel:.2g} %"


def _ci_cells(ci, scale):
    if ci is None:
        return "-", "-"
    _v, lo, hi, rel = ci
    if not math.isfinite(rel):
        return "not identifiable", "inf"
    return f"[{_fmt(lo * scale)}, {_fmt(hi * scale)}]", f"{100 * rel:.2g} %"


def _stats_table(stats) -> str:
    if stats is None:
        return ""
    lines = ["| Parameter | Value | Std. error | 95 % CI | rel. CI |", "|---|---|---|---|---|"]
    for i, n in enumerate(stats.names):
        rel = stats.relative_ci[i]
        lines.append(f"| {n} | {_fmt(stats.values[i], 6)} | {_fmt(stats.std_error[i])} | "
                     f"[{_fmt(stats.ci_low[i])}, {_fmt(stats.ci_high[i])}] | "
                     f"{'inf' if not math.isfinite(rel) else f'{100 * rel:.2g} %'} |")
    lines.append("")
    lines.append("Correlation matrix:")
    lines.append("")
    lines.append("| | " + " | ".join(stats.names) + " |")
    lines.append("|---" * (len(stats.names) + 1) + "|")
    for i, n in enumerate(stats.names):
        lines.append(
            f"| {n} | " + " | ".join(f"{stats.correlation[i, j]:+.3f}" for j in range(len(stats.names))) + " |")
    lines.append("")
    lines.append(f"Residual std. {_fmt(stats.residual_std)} ({stats.dof} degrees of freedom), rank {stats.rank}.")
    lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------- sections
def applied_input_text(sine) -> str:
    """What the fit and the model curves were driven with when the records carry the applied voltage."""
    held = [x for x in sine.series if x.voltage_hold == "zoh"]
    steps = []
    for x in held:
        changes = np.nonzero(np.diff(x.voltage_V))[0]
        if changes.size > 2:
            steps.append(float(np.median(np.diff(x.time_s[changes + 1]))))
    hold = (f" as applied: a staircase, each value held {1e3 * np.median(steps):.3g} ms (zero-order hold at "
            f"{1.0 / np.median(steps):.4g} Hz; the 2f component of u^2 is sinc(2 f / f_hold) smaller and half a step "
            "later than the ideal sine's)") if steps else ""
    return ("Applied voltage: the fit, the model d_rms and the model curves use each record's recorded voltage"
            + hold + ", not the ideal sine.")


def header(result: IdentificationResult) -> list:
    """Title, data, excitation and methods."""
    exp = result.experiments
    out = [f"# Identification report: membrane {result.parameters.name}", ""]
    out.append(f"Data: `{exp.folder}` ({exp.summary()}). Generated {time.strftime('%Y-%m-%d %H:%M:%S')} by "
               "`dea_ros.identify` (paper sections IV-B/C, eqs. 19-24).")
    for sine in exp.sines:
        out.append(f"Sine excitation ({Path(sine.source).name}): {WAVEFORM_TEXT.get(sine.waveform, sine.waveform)}, "
                   "U = amplitude_V; the model sees u^2 only (eq. 6), the same for both waveforms. d_rms: eq. 21 "
                   "over whole periods around the rest position d0"
                   + (", the measured one, about which the fit takes the model's d_rms as well (d0's measurement "
                      "error cancels)." if sine.d0_m is not None else
                      "; the data state no d0: the model's d_rms is about its own rest position."))
        if sine.inputs:
            out.append(applied_input_text(sine))
    out.append("")
    out.append(f"Methods: static fit **{result.options.get('static_method')}**, dynamic fit "
               f"**{result.options.get('dynamic_method')}** (weights {result.options.get('weights')}), frequency "
               f"response by **{result.options.get('frequency_method')}** ({result.options.get('n_harmonics')} "
               f"harmonics), refinement **{result.options.get('refine', 'none')}**"
               + (" (all identifiable parameters jointly, statistical weights: the values and intervals below)"
                  if result.joint is not None else "") + ".")
    out.append("")
    return out


def warnings_section(result: IdentificationResult) -> list:
    """The warnings, first: they matter most."""
    out = ["## Warnings", ""]
    if result.warnings:
        out += [f"- {w}" for w in result.warnings]
    else:
        out.append("None: every parameter is determined by the data and the model reproduces the data "
                   "within the noise.")
    out.append("")
    return out


def _stress_rows(result: IdentificationResult) -> list:
    """Table II rows of the hyperelastic stress at lambda_r = 1 (derivatives w.r.t. lambda_r, eq. 10)."""
    p, st, stats = result.parameters, result.static, result.statistics
    combos = stress_combinations(p.beta_Pa, p.gamma_Pa)
    s_stats = stats if (stats is not None and "sigma_h(1)_Pa" in stats.names) else (st.statistics if st else None)
    c0 = linear_combination_ci(s_stats, {"sigma_h(1)_Pa": 1.0})
    c1 = linear_combination_ci(s_stats, {"sigma_h'(1)_Pa": 2.0})
    out = [f"| Hyperelastic stress (eq. 10) | sigma_h(lambda_r = 1) | {_fmt(combos[0] * 1e-3)} | kPa | "
           + " | ".join(_ci_cells(c0, 1e-3)) + " |",
           f"| Hyperelastic stress slope | d sigma_h / d lambda_r at 1 | {_fmt(2 * combos[1] * 1e-3)} | kPa | "
           + " | ".join(_ci_cells(c1, 1e-3)) + " |"]
    curvature = 2 * combos[1] + 4 * combos[2]
    if result.curvature_identified:
        c2 = linear_combination_ci(stats, {"sigma_h'(1)_Pa": 2.0, "sigma_h''(1)_Pa": 4.0})
        flag = "" if result.curvature_status == "identified" else f" ({result.curvature_status})"
        out.append("| Hyperelastic stress curvature | d2 sigma_h / d lambda_r2 at 1 | "
                   f"{_fmt(curvature * 1e-3)}{flag} | "
                   "kPa | " + " | ".join(_ci_cells(c2, 1e-3)) + " |")
    else:
        c2 = linear_combination_ci(stats, {"sigma_h'(1)_Pa": 2.0, "sigma_h''(1)_Pa": 4.0}) if (
            stats is not None and "sigma_h''(1)_Pa" in stats.names) else None
        what = "free fit's value" if c2 is not None else "static fit's representation"
        out.append(f"| Hyperelastic stress curvature | d2 sigma_h / d lambda_r2 at 1 | **not identified** ({what} "
                   f"{_fmt(curvature * 1e-3)} written as a representative) | kPa | "
                   + " | ".join(_ci_cells(c2, 1e-3)) + " |")
    return out


def _stress_notes(result: IdentificationResult) -> list:
    """What the stress derivatives mean, and why beta/gamma are one representative."""
    p, st = result.parameters, result.static
    combos = stress_combinations(p.beta_Pa, p.gamma_Pa)
    out = ["Derivatives are taken w.r.t. lambda_r as eq. 10 is written (sigma_h = sum beta_i lambda_r^2i - "
           "gamma_i lambda_r^-2i). The fits work in s = lambda_r^2 (eq. 20's s(d)): d sigma_h/d lambda_r = "
           "2 d sigma_h/ds and d2 sigma_h/d lambda_r2 = 2 d sigma_h/ds + 4 d2 sigma_h/ds2 at lambda_r = 1; "
           f"here d sigma_h/ds = {_fmt(combos[1] * 1e-3)} kPa, d2 sigma_h/ds2 = {_fmt(combos[2] * 1e-3)} kPa"
           + ("" if result.curvature_identified else " (not identified: a representative value)") + ".", ""]
    if st is not None:
        og = st.ogden_statistics
        sv = og.singular_values / og.singular_values[0]
        out.append(
            "Note on beta/gamma: the deflections probe sigma_h only near stretch 1. The normalised singular values "
            "of the Jacobian of the static residuals w.r.t. (beta_1..3, gamma_1..3, eps_r) are "
            + ", ".join(f"{x:.2g}" for x in sv)
            + f": the static data determine {int(np.count_nonzero(sv > 1e-3))} combinations, in practice sigma_h(1), "
            f"its slope and eps_r (the curvature only from large oscillations near resonance). The values above are "
            f"one representative ({st.representation}); any beta/gamma with the same identified combinations fits "
            "the data equally well."
        )
        out.append("")
    return out


def parameters_section(result: IdentificationResult) -> list:
    """Table II: the given geometry and every fitted parameter with its 95 % interval."""
    p, st, stats = result.parameters, result.static, result.statistics
    out = ["## Parameters (Table II)", "", "| Parameter | Symbol | Value | Unit | 95 % CI | rel. CI |",
           "|---|---|---|---|---|---|"]
    out.append(f"| Membrane name | | {p.name} | | | |")
    out.append(f"| Prestretch (given) | lambda_p | {_fmt(p.prestretch)} | - | | |")
    out.append(f"| Thickness (given) | z0 | {_fmt(p.thickness_m * 1e6)} | um | | |")
    out.append(f"| Plate radius (given) | r | {_fmt(p.plate_radius_m * 1e3)} | mm | | |")
    out.append(f"| Electrode width (given) | l0 | {_fmt(p.electrode_width_m * 1e3)} | mm | | |")
    out.append(f"| Mass (given) | m | {_fmt(p.mass_kg * 1e3)} | g | | |")
    eps_stats = stats if (stats is not None and "eps_r" in stats.names) else (st.statistics if st else None)
    ci, rel = _ci_text(eps_stats, "eps_r")
    out.append(f"| Relative permittivity | eps_r | {_fmt(p.relative_permittivity)} | - | {ci} | {rel} |")
    for name, sym, unit, scale in (("k1_Pa", "k1", "MPa", 1e-6), ("eta1_Pa_s", "eta1", "MPa s", 1e-6),
                                   ("eta2_Pa_s", "eta2", "kPa s", 1e-3)):
        ci, rel = _ci_text(stats, name, scale)
        out.append(f"| Viscoelastic model | {sym} | {_fmt(getattr(p, name) * scale)} | {unit} | {ci} | {rel} |")
    out += _stress_rows(result)
    for i in range(3):
        out.append(f"| Ogden coefficient | beta_{i + 1} | {_fmt(p.beta_Pa[i] * 1e-3)} | kPa | see note | |")
    for i in range(3):
        out.append(f"| Ogden coefficient | gamma_{i + 1} | {_fmt(p.gamma_Pa[i] * 1e-3)} | kPa | see note | |")
    out.append("")
    return out + _stress_notes(result)


_LABELS = {"sigma_h(1)_Pa": ("sigma_h(1)", "kPa", 1e-3), "sigma_h'(1)_Pa": ("d sigma_h/ds (1)", "kPa", 1e-3),
           "sigma_h''(1)_Pa": ("d2 sigma_h/ds2 (1)", "kPa", 1e-3),
           "sigma_h'''(1)_Pa": ("d3 sigma_h/ds3 (1) (nuisance)", "kPa", 1e-3),
           "sigma_h''''(1)_Pa": ("d4 sigma_h/ds4 (1) (nuisance)", "kPa", 1e-3),
           "sigma_h'''''(1)_Pa": ("d5 sigma_h/ds5 (1) (nuisance)", "kPa", 1e-3), "eps_r": ("eps_r", "-", 1.0),
           "k1_Pa": ("k1", "MPa", 1e-6), "eta1_Pa_s": ("eta1", "MPa s", 1e-6), "eta2_Pa_s": ("eta2", "kPa s", 1e-3)}


def _widening_text(records: list) -> str:
    return ", ".join(f"{r} ({'essential' if not math.isfinite(w) else f'+{100 * w:.0f} %'})" for r, w in records)


def determination_section(result: IdentificationResult) -> list:
    """Per parameter: identified / poorly determined / not identified, the interval, the records that
    determine it (how much wider its interval would be without each)."""
    if not result.determination:
        return []
    out = ["## What the data determine", "",
           "Status from the 95 % interval's half-width relative to the value: identified (<= 50 %), poorly "
           "determined (< 100 %, sign known), not identified. 'Determined by': the records without which the "
           "interval would be wider by more than 5 % (with how much wider; 'essential': not determined at all "
           "without it), from the Fisher information of the fit; when no record alone matters that much the "
           "three that matter most are named.", "",
           "| Parameter | Status | Value | 95 % CI | Unit | Determined by |", "|---|---|---|---|---|---|"]
    for d in result.determination:
        label, unit, scale = _LABELS.get(d.name, (d.name, "SI", 1.0))
        ci = (f"[{_fmt(d.ci_low * scale)}, {_fmt(d.ci_high * scale)}]" if math.isfinite(d.relative_ci)
              else "not identifiable")
        who = _widening_text(d.determined_by) if d.determined_by else "-"
        if d.spread:
            who = "spread over many records; most: " + who
        status = f"**{d.status}**" if d.status != "identified" else d.status
        out.append(f"| {label} | {status} | {_fmt(d.value * scale)} | {ci} | {unit} | {who} |")
    out.append("")
    return out


def curvature_sensitivity_section(result: IdentificationResult) -> list:
    """sigma_h''(1) not identified: the predictions with the value written and at both ends of its interval."""
    sens = result.curvature_sensitivity
    if sens is None:
        return []
    out = ["## sigma_h''(1) not identified: how the predictions depend on the value written", "",
           "The parameters and intervals above come from the fit in which sigma_h''(1) (and sigma_h'''(1)) are "
           "free, so the value written does not steer them. params.yaml must carry one value for the model to "
           "run: that fit's. With every other parameter as written, the model predicts:", "",
           "| sigma_h''(1) (d2 sigma_h/ds2) | value (kPa) | resonance peak (Hz) | peak d_rms (um) | "
           "step: max difference from the written model (um) |", "|---|---|---|---|---|"]
    for end, label in (("low", "low end of the 95 % interval"), ("written", "written (representative)"),
                       ("high", "high end of the 95 % interval")):
        f = sens.peak_frequency_Hz.get(end)
        a = sens.peak_d_rms_m.get(end)
        s = sens.step_max_difference_m.get(end)
        out.append(f"| {label} | {_fmt(sens.curvature_Pa[end] * 1e-3)} | {_fmt(f, 6)} | "
                   f"{_fmt(None if a is None else a * 1e6)} | {_fmt(None if s is None else s * 1e6, 3)} |")
    if sens.amplitude_V is not None:
        out.append("")
        out.append(f"Peaks at {_fmt(sens.amplitude_V)} V (the amplitude of the largest sine record), located on the "
                   "T/2 branch.")
    out += [f"Note: {n}" for n in sens.notes]
    out.append("")
    return out


def classification_section(result: IdentificationResult) -> list:
    """The sine records: what they show and what they were fitted with."""
    if not result.classification:
        return []
    out = ["## Sine records: what they show and how they were fitted", "",
           "Kinds: periodic = period of u^2 (T/2), period-doubled = period T, quasi-periodic = no period "
           "(the data kind from the sampled record where one exists; the model kind from the realised response "
           "of the fitted model in a slow upward sweep).", "",
           "| f [Hz] | measured d_rms [um] | data | model | fitted as | model d_rms [um] | (model - data) / sigma |",
           "|---|---|---|---|---|---|---|"]
    comparisons = {id(c.sine): c for c in result.evaluation.sines}
    for c in result.classification:
        sine = [x for x in result.experiments.sines if x.source == c["source"]][0]
        item = comparisons.get(id(sine))
        model = item.model_at_data_m[c["index"]] if item is not None else float("nan")
        z = "-"
        if sine.d_rms_std_m is not None and np.isfinite(model):
            z = f"{(model - c['measured_rms_m']) / sine.d_rms_std_m[c['index']]:+.2f}"
        used = c["used"] if c["used"] != "left out" else f"left out: {c.get('reason', '')}"
        model_kind = c.get("model_kind") or "-"
        if c.get("coexisting"):
            model_kind = "coexisting: " + "; ".join(
                f"{b['kind']} {b['d_rms_m'] * 1e6:.4g} um" + (" (fitted)" if b["fitted"] else "")
                for b in c["coexisting"])
        out.append(f"| {c['frequency_Hz']:g} | {c['measured_rms_m'] * 1e6:.4g} | {c.get('data_kind') or '-'} | "
                   f"{model_kind} | {used} | "
                   f"{_fmt(model * 1e6) if np.isfinite(model) else '-'} | {z} |")
    out.append("")
    return out


def _frequency_response_lines(entry: SineComparison) -> list:
    """Table IV of one frequency response: errors, resonance peaks, bands, sampled records."""
    norm = entry.normalised_rms_error
    out = [f"Frequency response ({Path(entry.sine.source).name}, {entry.sine.frequency_Hz.size} frequencies, "
           f"{entry.compared} compared with a periodic model response): RMS error "
           f"{_fmt(entry.rms_error_um)} um, max {_fmt(entry.max_error_um)} um "
           f"(max {_fmt(entry.max_relative_error_percent, 3)} % of the RMS)"
           + (f"; RMS of (model - data) / d_rms_std: {_fmt(norm, 3)}" if norm is not None else "") + ".", ""]
    if entry.resonance:
        out.append("| Amplitude | Resonance peak, model [Hz] | Resonance peak, data [Hz] | Error (Table IV) |")
        out.append("|---|---|---|---|")
        for r in entry.resonance:
            meas = (_fmt(r["measured_peak_Hz"]) if r.get("measured")
                    else f"not measured ({r.get('measured_note')})")
            errs = f"{_fmt(r['error_percent'], 3)} %" if r.get("error_percent") is not None else "-"
            out.append(f"| {r['amplitude_V'] / 1e3:g} kV | {_fmt(r['simulated_peak_Hz'], 6)} "
                       f"({_fmt(r['simulated_peak_rms_m'] * 1e6)} um) | {meas} | {errs} |")
        out.append("")
        out.append("The model peak is located on the continued branch (the extremum of d_rms along it), not on a "
                   "frequency grid.")
        out.append("")
    if entry.bands:
        out.append("Bands of the fitted model (what a measurement sees): "
                   + "; ".join(f"{b['f_start_Hz']:.3f}-{b['f_end_Hz']:.3f} Hz {b['kind']}" for b in entry.bands)
                   + ".")
        out.append("")
    for k, v in entry.series_rms_error_um.items():
        out.append(f"- sampled record at {k}: RMS error {_fmt(v)} um (model "
                   f"{entry.series_model or 'aligned on the phase of u^2'})")
    if entry.series_rms_error_um:
        out.append("")
    return out


def quality_section(result: IdentificationResult) -> list:
    """The quality of the fit: static errors, Table III, the transient solver, Table IV."""
    out = ["## Quality of the fit", ""]
    ev, st = result.evaluation, result.static
    if ev.static is not None:
        out.append(f"Static (Fig. 6): RMS error {_fmt(ev.static.errors_um['rms_error_um'])} um, max "
                   f"{_fmt(ev.static.errors_um['max_error_um'])} um over {st.mass_kg.size if st else '?'} points.")
        out.append("")
    if ev.steps:
        out.append("Step responses (Table III; error = model - data):")
        out.append("")
        out.append(
            "| Record | IAE [mm s] | ISE [mm^2 s] | ITAE [mm s^2] | RMS error [um] | max error [um] | noise [um] |")
        out.append("|---|---|---|---|---|---|---|")
        for c in ev.steps:
            s_ = c.indices
            out.append(f"| {Path(c.step.source).name} | {_fmt(s_['IAE_mm_s'])} | {_fmt(s_['ISE_mm2_s'])} | "
                       f"{_fmt(s_['ITAE_mm_s2'])} | {_fmt(s_['rms_error_um'])} | {_fmt(s_['max_error_um'])} | "
                       f"{_fmt(c.noise_um)} |")
        out.append("")
    if ev.transient_solver_max_difference_um is not None:
        out.append(f"Fast transient solver (used in the fit) vs adaptive integration at the optimum: max "
                   f"difference {_fmt(ev.transient_solver_max_difference_um)} um.")
        out.append("")
    for entry in ev.sines:
        out += _frequency_response_lines(entry)
    return out


def uncertainty_section(bands) -> list:
    """The confidence of the frequency response and the resonance peak (Monte Carlo)."""
    if not bands:
        return []
    b0 = bands[0]
    out = ["## Uncertainty of the frequency response", "",
           f"Monte Carlo over the final fit's linearised covariance ({b0.samples} samples of "
           f"{', '.join(b0.parameters)}; seed {b0.seed}): the shaded band in the frequency-response figure holds the "
           f"central {100 * b0.confidence:.0f} % of the samples' responses at every frequency "
           "(`dea_ros.identify.uncertainty`).", "",
           f"| Amplitude | Mass | Resonance peak [Hz] | {100 * b0.confidence:.0f} % interval [Hz] | Peak d_rms [um] | "
           f"{100 * b0.confidence:.0f} % interval [um] | widest band (half width / d_rms) | failed samples |",
           "|---|---|---|---|---|---|---|---|"]
    for b in bands:
        rel = b.to_dict()["max_relative_half_width"]
        out.append(f"| {b.amplitude_V / 1e3:g} kV | {b.mass_kg * 1e3:g} g | {_fmt(b.peak_frequency_Hz, 6)} | "
                   f"[{_fmt(b.peak_frequency_ci_Hz[0], 6)}, {_fmt(b.peak_frequency_ci_Hz[1], 6)}] | "
                   f"{_fmt(b.peak_d_rms_m * 1e6)} | [{_fmt(b.peak_d_rms_ci_m[0] * 1e6)}, "
                   f"{_fmt(b.peak_d_rms_ci_m[1] * 1e6)}] | {_fmt(100 * rel, 3) if rel is not None else '-'} % | "
                   f"{b.n_failed} |")
    out.append("")
    return out


def _static_fit_lines(st) -> list:
    out = ["## Static fit (eqs. 19-20)", "",
           f"Method `{st.method}`, {st.n_evaluations} model evaluations, {_fmt(st.wall_time_s * 1e3, 3)} ms."]
    if st.starts:
        out.append("")
        out.append("| Start | Result |")
        out.append("|---|---|")
        for s_ in st.starts:
            out.append(f"| {s_.get('start')} | " + ", ".join(f"{k} = {_fmt(v)}" for k, v in s_.items()
                                                             if k != "start") + " |")
    out.append("")
    out.append(_stats_table(st.statistics))
    return out


def _dynamic_fit_lines(dy, jt) -> list:
    out = ["## Dynamic fit, stage 1 (eqs. 22-24)" if jt is not None else "## Dynamic fit (eqs. 22-24)", ""]
    pts = ", ".join(f"{f:g}" for f in dy.fit_frequencies_Hz)
    out.append(f"Method `{dy.method}`, frequency response by `{dy.frequency_method}`; "
               f"fit frequencies {pts or 'none'} Hz; "
               f"cost J (eq. 22) = {_fmt(dy.cost)} (step {_fmt(dy.step_cost)}, "
               f"frequency {_fmt(dy.frequency_cost)}); "
               f"{dy.n_evaluations} evaluations ({dy.n_jacobians} with Jacobian"
               + (f"; {dy.rejected_trials} trial points rejected where harmonic balance failed, not integrated"
                  if dy.rejected_trials else "") + ").")
    init = dy.initial
    out.append("")
    out.append(f"Initial guess from the {init.get('source')}: oscillation {_fmt(init.get('oscillation_Hz'))} Hz, "
               f"decay {_fmt(init.get('decay_rate_per_s'))} 1/s, then a scan of eta1/k1.")
    out.append("")
    if jt is None:
        out.append(_stats_table(dy.statistics))
    return out


def _joint_fit_lines(jt) -> list:
    blocks = ", ".join(f"{k} {_fmt(v)}" for k, v in jt.block_chi2.items())
    return ["## Joint refinement (all identifiable parameters, statistical weights)", "",
            f"chi-square {_fmt(jt.cost)} for {jt.dof} degrees of freedom ({blocks}); fitted records: "
            + ", ".join(f"{pt.frequency_Hz:g} Hz ({pt.kind})" for pt in jt.frequency_points)
            + f"; {jt.n_evaluations} evaluations, {_fmt(jt.wall_time_s, 3)} s. Weights: static points "
            + _static_weights_text(jt.sigmas["static_m"]) + ", step samples "
            + ", ".join(_fmt(x * 1e6) for x in jt.sigmas["step_m"]) + " um (laser noise), RMS values their "
            "stated uncertainty. Stress combinations in s = lambda_r^2.", "",
            _stats_table(jt.statistics)]


def _static_weights_text(static_m) -> str:
    if np.ndim(static_m) == 0:
        return f"{_fmt(static_m * 1e6)} um (static fit residual)"
    sig = np.asarray(static_m, float) * 1e6
    return (f"{_fmt(sig.min())}-{_fmt(sig.max())} um (each point's laser noise over the square root of its "
            "samples, scaled up where the static fit's residuals scatter more)")


def _two_stage_linearisation_lines(lin) -> list:
    blocks = ", ".join(f"{k} {_fmt(v)}" for k, v in lin.block_chi2.items())
    return ["## Intervals of the two-stage result (no joint refinement)", "",
            "The joint refinement was rejected or failed (see the warnings), so the parameters are the two-stage "
            "result's. Its intervals: the joint objective (the refinement's chi-square, statistical weights) "
            "linearised at the two-stage result, every parameter free -- the static stage's uncertainty included, "
            "which the dynamic fit's table above leaves out (it holds eps_r and the stress at the static fit's "
            f"values). chi-square there {_fmt(lin.cost)} for {lin.dof} degrees of freedom ({blocks}).", "",
            _stats_table(lin.statistics)]


def fits_section(result: IdentificationResult) -> list:
    """The static fit, the dynamic fit (stage 1) and the joint refinement (or, without one, the two-stage
    result's linearised intervals), each with its statistics."""
    out = []
    if result.static is not None:
        out += _static_fit_lines(result.static)
    if result.dynamic is not None:
        out += _dynamic_fit_lines(result.dynamic, result.joint)
    if result.joint is not None:
        out += _joint_fit_lines(result.joint)
    elif result.two_stage_linearisation is not None:
        out += _two_stage_linearisation_lines(result.two_stage_linearisation)
    return out


def timings_section(result: IdentificationResult, timings_extra: dict | None = None) -> list:
    """Wall time per stage and the machine."""
    out = ["## Timings", "", "| Stage | Wall time [s] |", "|---|---|"]
    timings = dict(result.timings_s)
    timings.update(timings_extra or {})
    for k, v in timings.items():
        out.append(f"| {k} | {v:.3f} |")
    out.append("")
    out.append(f"Machine: {platform.machine()}, Python {platform.python_version()}.")
    out.append("")
    return out


def figures_section(figures: dict) -> list:
    """The figures (title -> file name), embedded."""
    if not figures:
        return []
    out = ["## Figures", ""]
    for title, name in figures.items():
        out.append(f"### {title}")
        out.append("")
        out.append(f"![{title}]({name})")
        out.append("")
    return out


def report_markdown(result: IdentificationResult, figures: dict, timings_extra: dict | None = None) -> str:
    """The text of ``report.md``."""
    out = (header(result) + warnings_section(result) + parameters_section(result) + determination_section(result)
           + curvature_sensitivity_section(result) + classification_section(result)
           + quality_section(result) + uncertainty_section(result.uncertainty) + fits_section(result)
           + timings_section(result, timings_extra) + figures_section(figures))
    return "\n".join(out)
