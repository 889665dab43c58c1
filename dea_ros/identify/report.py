"""Outputs of an identification: parameters YAML, PNG figures (Figs. 6-8 style) and ``report.md``.

:func:`write_report` writes into one folder::

    params.yaml        fitted MembraneParameters (loadable by MembraneParameters.from_yaml)
    report.md          parameter table (Table II style, with 95 % CIs), metrics (Tables III-IV),
                       correlations, warnings, timings
    result.json        the same content, machine readable
    static.png         Fig. 6: rest displacement vs voltage (and vs mass), data and model
    step.png           Fig. 8 left: step responses, data and model, and the error
    frequency.png      Fig. 8 right: RMS displacement vs frequency, data and model (with the model's
                       confidence band and the peak's interval when the identification computed them)
    sine_series.png    sampled sine records vs model (when the data include them)

Figures are drawn on :class:`matplotlib.figure.Figure` objects (Agg), without pyplot state.
"""
from __future__ import annotations

import json
import math
import platform
import time
from pathlib import Path

import numpy as np

from .metrics import linear_combination_ci
from ..solvers.continuation import stability_segments
from .pipeline import IdentificationResult
from .static_fit import stress_combinations

__all__ = ["write_report", "write_parameters", "plot_static", "plot_steps", "plot_frequency",
           "plot_sine_series", "report_markdown"]


def write_parameters(result: IdentificationResult, path: str | Path) -> Path:
    """Fitted parameters as YAML: the MembraneParameters fields under ``membrane:`` (loadable by
    :meth:`MembraneParameters.from_yaml` and every node and command), what was identified and how
    under ``identification:`` (sigma_h''(1) "not identified" when the data do not determine it:
    beta/gamma then carry the base value), and a header naming the data and the methods."""
    import yaml

    path = Path(path)
    exp = result.experiments
    lines = [
        "dea_ros membrane parameters, SI units (m, kg, Pa, Pa s, V/m); fields: see dea_ros.model.parameters,",
        "paper eqs. 1-12, Tables I-II.",
        f"fitted by dea_ros.identify from {exp.folder if exp.folder else 'in-memory data'} ({exp.summary()})",
        f"static fit: {result.options.get('static_method')}, dynamic fit: {result.options.get('dynamic_method')} "
        f"with frequency response by {result.options.get('frequency_method')}, refinement: "
        f"{result.options.get('refine', 'none')}",
    ]
    if result.static is not None and result.static.method == "lsq":
        lines.append("identified: sigma_h(1), its slope and eps_r (and the curvature where the 'identification' "
                     "section says so); beta/gamma are one representative, not individually identifiable")
    if result.curvature_identified is False:
        lines.append("sigma_h''(1): NOT IDENTIFIED by these data; beta/gamma carry the base value "
                     "(see 'identification')")
    text = "\n".join(f"# {line}" for line in lines) + "\n"
    data = {"membrane": result.parameters.to_dict(), "identification": _plain(result.identification_metadata())}
    text += yaml.safe_dump(data, sort_keys=False)
    path.write_text(text)
    return path


def _plain(obj):
    """YAML-safe copy (floats, lists, strings)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if isinstance(obj, (np.integer, int)) and not isinstance(obj, bool):
        return int(obj)
    return obj


def _fig(width=7.0, height=4.5, nrows=1, ncols=1, **kw):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    axes = fig.subplots(nrows, ncols, **kw)
    return fig, axes


def plot_static(result: IdentificationResult, path: str | Path) -> Path | None:
    """Fig. 6: rest displacement vs voltage at the loaded mass(es), and vs mass at 0 V."""
    curves = result.curves.get("static")
    if not curves:
        return None
    data = curves["data"]
    fig, (ax1, ax2, ax3) = _fig(13.0, 4.2, 1, 3)
    volt = np.abs(data.voltage_V) > 0
    for m, (u, d) in curves["voltage_curves"].items():
        sel = volt & (data.mass_kg == m)
        ax1.plot(u / 1e3, d * 1e3, "-", label=f"model, {m * 1e3:g} g")
        ax1.plot(data.voltage_V[sel] / 1e3, data.displacement_m[sel] * 1e3, "x", ms=8, label=f"data, {m * 1e3:g} g")
        zero = (~volt) & (data.mass_kg == m)
        if np.any(zero):
            ax1.plot(np.zeros(np.count_nonzero(zero)), data.displacement_m[zero] * 1e3, "x", ms=8, color="C1")
    ax1.set_xlabel("voltage (kV)")
    ax1.set_ylabel("displacement d (mm)")
    ax1.set_title(f"{result.parameters.name}: static displacement vs voltage")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    masses, d_mass = curves["mass_curve"]
    sel = ~volt
    ax2.plot(masses * 1e3, d_mass * 1e3, "-", label="model, 0 V")
    ax2.plot(data.mass_kg[sel] * 1e3, data.displacement_m[sel] * 1e3, "x", ms=8, label="data, 0 V")
    ax2.set_xlabel("mass (g)")
    ax2.set_ylabel("displacement d (mm)")
    ax2.set_title("static displacement vs mass")
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8, loc="upper left")
    err = (curves["predicted_m"] - data.displacement_m) * 1e6
    ax3.plot(np.arange(err.size) + 1, err, "o", ms=4)
    ax3.axhline(0.0, color="k", lw=0.6)
    ax3.set_xlabel("static point (file order)")
    ax3.set_ylabel("model - data (um)")
    ax3.set_title("static error")
    ax3.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    return Path(path)


def plot_steps(result: IdentificationResult, path: str | Path) -> Path | None:
    """Fig. 8 (left): each step response, data and model, with the error below."""
    steps = result.curves.get("steps")
    if not steps:
        return None
    n = len(steps)
    fig, axes = _fig(9.0, 3.2 * n + 1.5, 2 * n, 1, squeeze=False, sharex=False,
                     gridspec_kw={"height_ratios": [3, 1] * n})
    axes = axes[:, 0]
    for k, item in enumerate(steps):
        step, sim = item["step"], item["simulated_m"]
        ax, axe = axes[2 * k], axes[2 * k + 1]
        ax.plot(step.time_s, step.displacement_m * 1e3, ".", ms=1.5, color="0.55", label="data")
        ax.plot(step.time_s, sim * 1e3, "-", lw=0.9, color="C0", label="model")
        ax.set_ylabel("d (mm)")
        ax.set_title(f"{result.parameters.name}: step {step.initial_V:g} V -> {step.final_V:g} V "
                     f"({Path(step.source).name})")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
        axe.plot(step.time_s, (sim - step.displacement_m) * 1e6, lw=0.5, color="C3")
        axe.set_ylabel("model - data (um)")
        axe.set_xlabel("time (s)")
        axe.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    return Path(path)


KIND_MARKERS = {"periodic": ("o", "C0"), "period-doubled": ("s", "C1"), "left out": ("x", "C3")}


def plot_frequency(result: IdentificationResult, path: str | Path) -> Path | None:
    """Fig. 8 (right): RMS displacement (eq. 21) vs frequency: the model's realised response (what a
    measurement sees: periodic, period-doubled, quasi-periodic by integration), its T/2 branch
    (dotted where unstable), the data marked by what they were fitted with."""
    sines = result.curves.get("sines")
    if not sines:
        return None
    fig, ax = _fig(8.5, 5.0)
    for k, item in enumerate(sines):
        sine = item["sine"]
        for amp, sweep in item["dense"]:
            for br in sweep.branches:
                col = "C0" if br.kind == "periodic" else "C1"
                (fs, ds), (fu, du) = stability_segments(br, sweep.bifurcations)
                ax.plot(fs, ds * 1e3, "-", color=col, lw=1.0, label=f"model {br.name} branch ({br.kind}), "
                        f"{amp / 1e3:g} kV")
                ax.plot(fu, du * 1e3, ":", color=col, lw=0.8)
            qp = [r for r in sweep.responses if r.branch == "integration"]
            if qp:
                ax.errorbar([r.frequency_Hz for r in qp], [r.d_rms_m * 1e3 for r in qp],
                            yerr=[[(r.d_rms_m - r.d_rms_min_m) * 1e3 for r in qp],
                                  [(r.d_rms_max_m - r.d_rms_m) * 1e3 for r in qp]],
                            fmt=".", color="C3", ms=3, lw=0.6, label="model, quasi-periodic (mean, min/max)")
            for b in sweep.bands:
                if b.kind != "periodic":
                    ax.axvspan(b.f_start_Hz, b.f_end_Hz, color={"period-doubled": "C1", "coexisting": "C4"}
                               .get(b.kind, "C3"), alpha=0.10, lw=0)
            peak = sweep.resonance_peak(True)
            ax.axvline(peak["frequency_Hz"], color="C0", lw=0.6, ls="--")
        for band in result.uncertainty:
            if abs(band.mass_kg - sine.mass_kg) > 1e-12 or band.amplitude_V not in sine.amplitude_V:
                continue
            ax.fill_between(band.frequencies_Hz, band.lower_m * 1e3, band.upper_m * 1e3, color="C0", alpha=0.25,
                            lw=0, label=f"model {100 * band.confidence:.0f} % band ({band.samples} Monte Carlo "
                                        "samples)")
            lo, hi = band.peak_frequency_ci_Hz
            if np.isfinite(lo) and np.isfinite(hi):
                ax.errorbar([band.peak_frequency_Hz], [band.peak_d_rms_m * 1e3],
                            xerr=[[band.peak_frequency_Hz - lo], [hi - band.peak_frequency_Hz]],
                            yerr=[[(band.peak_d_rms_m - band.peak_d_rms_ci_m[0]) * 1e3],
                                  [(band.peak_d_rms_ci_m[1] - band.peak_d_rms_m) * 1e3]],
                            fmt="D", color="C0", ms=4, capsize=3, lw=0.8,
                            label=f"model peak, {100 * band.confidence:.0f} % interval")
        used = np.array(item["used"])
        for kind, (marker, col) in KIND_MARKERS.items():
            sel = used == kind
            if np.any(sel):
                ax.plot(sine.frequency_Hz[sel], sine.d_rms_m[sel] * 1e3, marker,
                        color="k" if kind != "left out" else col,
                        mfc="none" if kind != "periodic" else "k", ms=6,
                        label=(f"data, fitted as {kind}" if kind != "left out"
                               else "data, left out (no periodic response)"))
    for entry in result.evaluation.get("frequency_response", []):
        for res in entry.get("resonance", []):
            if res.get("measured"):
                ax.axvline(res["measured_peak_Hz"], color="k", lw=0.6, ls="--")
    ax.set_xlabel("excitation frequency (Hz)")
    ax.set_ylabel("d_rms (mm), eq. 21")
    ax.set_title(f"{result.parameters.name}: frequency response (dashed: peak, model blue / data black when measured)")
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    seen = {}
    for h, lab in zip(handles, labels):
        seen.setdefault(lab, h)
    ax.legend(seen.values(), seen.keys(), fontsize=7)
    fig.savefig(path, dpi=110)
    return Path(path)


def plot_sine_series(result: IdentificationResult, path: str | Path) -> Path | None:
    """Sampled sine records vs the model, driven by the recorded voltage when the records carry it
    (else aligned on the phase of u^2, the recorded voltage's 2f component: right for U sin and
    |U sin| alike), with the voltage as applied (a held staircase drawn as one)."""
    items = [s for item in result.curves.get("sines", []) for s in item["series"]]
    if not items:
        return None
    fig, axes = _fig(9.0, 2.8 * len(items) + 0.8, len(items), 1, squeeze=False)
    for ax, item in zip(axes[:, 0], items):
        ser = item["series"]
        show = ser.time_s <= ser.time_s[0] + max(3.0 / ser.frequency_Hz, 0.2)
        ax.plot(ser.time_s[show], ser.displacement_m[show] * 1e3, ".", ms=2, color="0.55", label="data")
        if item.get("model_m") is not None:
            ax.plot(ser.time_s[show], item["model_m"][show] * 1e3, "-", color="C0",
                    label=f"model ({item.get('kind')})")
            ax.set_title(f"{ser.frequency_Hz:g} Hz: RMS error {item['rms_error_um']:.3g} um (model "
                         f"{item.get('how', 'aligned on the phase of u^2')})")
        else:
            ax.set_title(f"{ser.frequency_Hz:g} Hz: no periodic model response ({item.get('note', '')})")
        ax.set_ylabel("d (mm)")
        ax.grid(alpha=0.3)
        ax2 = ax.twinx()
        ax2.plot(ser.time_s[show], ser.voltage_V[show] / 1e3, "-", color="C1", lw=0.5, alpha=0.5,
                 drawstyle="steps-post" if ser.voltage_hold == "zoh" else "default")
        ax2.set_ylabel("u (kV, as applied)" if ser.voltage_hold == "zoh" else "u (kV)", color="C1")
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    fig.savefig(path, dpi=110)
    return Path(path)


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


WAVEFORM_TEXT = {"sine": "u = U sin(2 pi f t)", "abs_sine": "u = |U sin(2 pi f t)| (unipolar amplifier)"}


def report_markdown(result: IdentificationResult, figures: dict, timings_extra: dict | None = None) -> str:
    """The text of ``report.md``."""
    p = result.parameters
    exp = result.experiments
    st, dy, jt = result.static, result.dynamic, result.joint
    stats = result.statistics
    out = [f"# Identification report: membrane {p.name}", ""]
    out.append(f"Data: `{exp.folder}` ({exp.summary()}). Generated {time.strftime('%Y-%m-%d %H:%M:%S')} by "
               "`dea_ros.identify` (paper sections IV-B/C, eqs. 19-24).")
    for sine in exp.sines:
        out.append(f"Sine excitation ({Path(sine.source).name}): {WAVEFORM_TEXT.get(sine.waveform, sine.waveform)}, "
                   "U = amplitude_V; the model sees u^2 only (eq. 6), the same for both waveforms. d_rms: eq. 21 "
                   "over whole periods around the rest position d0.")
        if sine.inputs:
            out.append(applied_input_text(sine))
    out.append("")
    out.append(f"Methods: static fit **{result.options.get('static_method')}**, dynamic fit "
               f"**{result.options.get('dynamic_method')}** (weights {result.options.get('weights')}), frequency "
               f"response by **{result.options.get('frequency_method')}** ({result.options.get('n_harmonics')} "
               f"harmonics), refinement **{result.options.get('refine', 'none')}**"
               + (" (all identifiable parameters jointly, statistical weights: the values and intervals below)"
                  if jt is not None else "") + ".")
    out.append("")
    # ---- warnings first: they matter most
    out.append("## Warnings")
    out.append("")
    if result.warnings:
        out += [f"- {w}" for w in result.warnings]
    else:
        out.append("None: every parameter is determined by the data and the model reproduces the data "
                   "within the noise.")
    out.append("")
    # ---- parameter table (Table II)
    out.append("## Parameters (Table II)")
    out.append("")
    out.append("| Parameter | Symbol | Value | Unit | 95 % CI | rel. CI |")
    out.append("|---|---|---|---|---|---|")
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
    # hyperelastic stress at lambda_r = 1, derivatives w.r.t. lambda_r as eq. 10 is written
    combos = stress_combinations(p.beta_Pa, p.gamma_Pa)
    s_stats = stats if (stats is not None and "sigma_h(1)_Pa" in stats.names) else (st.statistics if st else None)
    c0 = linear_combination_ci(s_stats, {"sigma_h(1)_Pa": 1.0})
    c1 = linear_combination_ci(s_stats, {"sigma_h'(1)_Pa": 2.0})
    out.append(f"| Hyperelastic stress (eq. 10) | sigma_h(lambda_r = 1) | {_fmt(combos[0] * 1e-3)} | kPa | "
               + " | ".join(_ci_cells(c0, 1e-3)) + " |")
    out.append(f"| Hyperelastic stress slope | d sigma_h / d lambda_r at 1 | {_fmt(2 * combos[1] * 1e-3)} | kPa | "
               + " | ".join(_ci_cells(c1, 1e-3)) + " |")
    curvature = 2 * combos[1] + 4 * combos[2]
    if result.curvature_identified:
        c2 = linear_combination_ci(stats, {"sigma_h'(1)_Pa": 2.0, "sigma_h''(1)_Pa": 4.0})
        flag = "" if result.curvature_status == "identified" else f" ({result.curvature_status})"
        out.append("| Hyperelastic stress curvature | d2 sigma_h / d lambda_r2 at 1 | "
                   f"{_fmt(curvature * 1e-3)}{flag} | "
                   "kPa | " + " | ".join(_ci_cells(c2, 1e-3)) + " |")
    else:
        out.append(f"| Hyperelastic stress curvature | d2 sigma_h / d lambda_r2 at 1 | **not identified** (base value "
                   f"{_fmt(curvature * 1e-3)} written) | kPa | - | - |")
    for i in range(3):
        out.append(f"| Ogden coefficient | beta_{i + 1} | {_fmt(p.beta_Pa[i] * 1e-3)} | kPa | see note | |")
    for i in range(3):
        out.append(f"| Ogden coefficient | gamma_{i + 1} | {_fmt(p.gamma_Pa[i] * 1e-3)} | kPa | see note | |")
    out.append("")
    out.append("Derivatives are taken w.r.t. lambda_r as eq. 10 is written (sigma_h = sum beta_i lambda_r^2i - "
               "gamma_i lambda_r^-2i). The fits work in s = lambda_r^2 (eq. 20's s(d)): d sigma_h/d lambda_r = "
               "2 d sigma_h/ds and d2 sigma_h/d lambda_r2 = 2 d sigma_h/ds + 4 d2 sigma_h/ds2 at lambda_r = 1; "
               f"here d sigma_h/ds = {_fmt(combos[1] * 1e-3)} kPa, d2 sigma_h/ds2 = {_fmt(combos[2] * 1e-3)} kPa"
               + ("" if result.curvature_identified else " (not identified: the base value)") + ".")
    out.append("")
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
    # ---- sine records: what they show and what they were fitted with
    if result.classification:
        out.append("## Sine records: what they show and how they were fitted")
        out.append("")
        out.append("Kinds: periodic = period of u^2 (T/2), period-doubled = period T, quasi-periodic = no period "
                   "(the data kind from the sampled record where one exists; the model kind from the realised response "
                   "of the fitted model in a slow upward sweep).")
        out.append("")
        out.append("| f [Hz] | measured d_rms [um] | data | model | fitted as | model d_rms [um] "
                   "| (model - data) / sigma |")
        out.append("|---|---|---|---|---|---|---|")
        ev_fr = {e["source"]: e for e in result.evaluation.get("frequency_response", [])}
        curves = {id(c["sine"]): c for c in result.curves.get("sines", [])}
        for c in result.classification:
            sine = [x for x in exp.sines if x.source == c["source"]][0]
            item = curves.get(id(sine))
            model = item["model_at_data_m"][c["index"]] if item is not None else float("nan")
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
        _ = ev_fr
        out.append("")
    # ---- metrics
    out.append("## Quality of the fit")
    out.append("")
    ev = result.evaluation
    if "static" in ev:
        out.append(f"Static (Fig. 6): RMS error {_fmt(ev['static']['rms_error_um'])} um, max "
                   f"{_fmt(ev['static']['max_error_um'])} um over {st.mass_kg.size if st else '?'} points.")
        out.append("")
    if "steps" in ev:
        out.append("Step responses (Table III; error = model - data):")
        out.append("")
        out.append(
            "| Record | IAE [mm s] | ISE [mm^2 s] | ITAE [mm s^2] | RMS error [um] | max error [um] | noise [um] |")
        out.append("|---|---|---|---|---|---|---|")
        for s_ in ev["steps"]:
            out.append(f"| {Path(s_['source']).name} | {_fmt(s_['IAE_mm_s'])} | {_fmt(s_['ISE_mm2_s'])} | "
                       f"{_fmt(s_['ITAE_mm_s2'])} | {_fmt(s_['rms_error_um'])} | {_fmt(s_['max_error_um'])} | "
                       f"{_fmt(s_['noise_um'])} |")
        out.append("")
    if "transient_solver_max_difference_um" in ev:
        out.append(f"Fast transient solver (used in the fit) vs adaptive integration at the optimum: max "
                   f"difference {_fmt(ev['transient_solver_max_difference_um'])} um.")
        out.append("")
    for entry in ev.get("frequency_response", []):
        norm = entry.get("normalised_rms_error")
        out.append(f"Frequency response ({Path(entry['source']).name}, {entry['frequencies']} frequencies, "
                   f"{entry.get('compared', entry['frequencies'])} compared with a periodic model response): RMS error "
                   f"{_fmt(entry['rms_error_um'])} um, max {_fmt(entry['max_error_um'])} um "
                   f"(max {_fmt(entry['max_relative_error_percent'], 3)} % of the RMS)"
                   + (f"; RMS of (model - data) / d_rms_std: {_fmt(norm, 3)}" if norm is not None else "") + ".")
        out.append("")
        if entry.get("resonance"):
            out.append("| Amplitude | Resonance peak, model [Hz] | Resonance peak, data [Hz] | Error (Table IV) |")
            out.append("|---|---|---|---|")
            for r in entry["resonance"]:
                meas = (_fmt(r["measured_peak_Hz"]) if r.get("measured")
                        else f"not measured ({r.get('measured_note')})")
                errs = f"{_fmt(r['error_percent'], 3)} %" if r.get("error_percent") is not None else "-"
                out.append(f"| {r['amplitude_V'] / 1e3:g} kV | {_fmt(r['simulated_peak_Hz'], 6)} "
                           f"({_fmt(r['simulated_peak_rms_m'] * 1e6)} um) | {meas} | {errs} |")
            out.append("")
            out.append("The model peak is located on the continued branch (the extremum of d_rms along it), not on a "
                       "frequency grid.")
            out.append("")
        if entry.get("bands"):
            out.append("Bands of the fitted model (what a measurement sees): "
                       + "; ".join(f"{b['f_start_Hz']:.3f}-{b['f_end_Hz']:.3f} Hz {b['kind']}" for b in entry["bands"])
                       + ".")
            out.append("")
        for k, v in entry.get("series_rms_error_um", {}).items():
            out.append(f"- sampled record at {k}: RMS error {_fmt(v)} um (model "
                       f"{entry.get('series_model', 'aligned on the phase of u^2')})")
        if entry.get("series_rms_error_um"):
            out.append("")
    if result.uncertainty:
        out += _uncertainty_section(result.uncertainty)
    # ---- fits
    if st is not None:
        out.append("## Static fit (eqs. 19-20)")
        out.append("")
        out.append(f"Method `{st.method}`, {st.n_evaluations} model evaluations, {_fmt(st.wall_time_s * 1e3, 3)} ms.")
        if st.starts:
            out.append("")
            out.append("| Start | Result |")
            out.append("|---|---|")
            for s_ in st.starts:
                out.append(f"| {s_.get('start')} | " + ", ".join(f"{k} = {_fmt(v)}" for k, v in s_.items()
                                                                 if k != "start") + " |")
        out.append("")
        out.append(_stats_table(st.statistics))
    if dy is not None:
        out.append("## Dynamic fit, stage 1 (eqs. 22-24)" if jt is not None else "## Dynamic fit (eqs. 22-24)")
        out.append("")
        pts = ", ".join(f"{f:g}" for f in dy.fit_frequencies_Hz)
        out.append(f"Method `{dy.method}`, frequency response by `{dy.frequency_method}`; "
                   f"fit frequencies {pts or 'none'} Hz; "
                   f"cost J (eq. 22) = {_fmt(dy.cost)} (step {_fmt(dy.step_cost)}, "
                   f"frequency {_fmt(dy.frequency_cost)}); "
                   f"{dy.n_evaluations} evaluations ({dy.n_jacobians} with Jacobian).")
        init = dy.initial
        out.append("")
        out.append(f"Initial guess from the {init.get('source')}: oscillation {_fmt(init.get('oscillation_Hz'))} Hz, "
                   f"decay {_fmt(init.get('decay_rate_per_s'))} 1/s, then a scan of eta1/k1.")
        out.append("")
        if jt is None:
            out.append(_stats_table(dy.statistics))
    if jt is not None:
        out.append("## Joint refinement (all identifiable parameters, statistical weights)")
        out.append("")
        blocks = ", ".join(f"{k} {_fmt(v)}" for k, v in jt.block_chi2.items())
        out.append(f"chi-square {_fmt(jt.cost)} for {jt.dof} degrees of freedom ({blocks}); fitted records: "
                   + ", ".join(f"{pt.frequency_Hz:g} Hz ({pt.kind})" for pt in jt.frequency_points)
                   + f"; {jt.n_evaluations} evaluations, {_fmt(jt.wall_time_s, 3)} s. Weights: static points "
                   f"{_fmt(jt.sigmas['static_m'] * 1e6)} um (static fit residual), step samples "
                   + ", ".join(_fmt(x * 1e6) for x in jt.sigmas["step_m"]) + " um (laser noise), RMS values their "
                   "stated uncertainty. Stress combinations in s = lambda_r^2.")
        out.append("")
        out.append(_stats_table(jt.statistics))
    # ---- timings
    out.append("## Timings")
    out.append("")
    out.append("| Stage | Wall time [s] |")
    out.append("|---|---|")
    timings = dict(result.timings_s)
    timings.update(timings_extra or {})
    for k, v in timings.items():
        out.append(f"| {k} | {v:.3f} |")
    out.append("")
    out.append(f"Machine: {platform.machine()}, Python {platform.python_version()}.")
    out.append("")
    if figures:
        out.append("## Figures")
        out.append("")
        for title, name in figures.items():
            out.append(f"### {title}")
            out.append("")
            out.append(f"![{title}]({name})")
            out.append("")
    return "\n".join(out)


def _uncertainty_section(bands) -> list:
    """report.md lines: the confidence of the frequency response and the resonance peak (Monte Carlo)."""
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


def write_report(result: IdentificationResult, out_dir: str | Path, plots: bool = True) -> dict:
    """Write params.yaml, the figures, report.md and result.json into ``out_dir``; return the paths
    and the time spent (``report_s``)."""
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"params": write_parameters(result, out / "params.yaml")}
    figures = {}
    if plots:
        for title, name, fn in (("Static displacement (Fig. 6)", "static.png", plot_static),
                                ("Step response (Fig. 8, left)", "step.png", plot_steps),
                                ("Frequency response (Fig. 8, right)", "frequency.png", plot_frequency),
                                ("Sampled sine records", "sine_series.png", plot_sine_series)):
            written = fn(result, out / name)
            if written is not None:
                figures[title] = name
                paths[name] = written
    report_time = time.perf_counter() - t0
    text = report_markdown(result, figures, {"report (plots, files)": report_time})
    (out / "report.md").write_text(text)
    paths["report"] = out / "report.md"
    data = result.to_dict()
    data["timings_s"]["report"] = report_time
    (out / "result.json").write_text(json.dumps(data, indent=2))
    paths["json"] = out / "result.json"
    paths["report_s"] = time.perf_counter() - t0
    return paths
