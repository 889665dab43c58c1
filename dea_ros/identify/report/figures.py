"""The figures of the report (Figs. 6-8 style), drawn from the evaluation of an identification.

Each ``plot_*`` reads :attr:`IdentificationResult.evaluation <dea_ros.identify.result.IdentificationResult>`
(an :class:`~dea_ros.identify.evaluation.Evaluation`), writes one PNG and returns its path, or None
when the identification has nothing to draw for it. Figures are drawn on
:class:`matplotlib.figure.Figure` objects (Agg), without pyplot state; matplotlib (an optional
dependency of the core) is imported when the first figure is drawn.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...solvers.sweep_results import stability_segments
from ..result import IdentificationResult

__all__ = ["plot_static", "plot_steps", "plot_frequency", "plot_sine_series", "KIND_MARKERS"]


def _fig(width=7.0, height=4.5, nrows=1, ncols=1, **kw):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    axes = fig.subplots(nrows, ncols, **kw)
    return fig, axes


def plot_static(result: IdentificationResult, path: str | Path) -> Path | None:
    """Fig. 6: rest displacement vs voltage at the loaded mass(es), and vs mass at 0 V."""
    curves = result.evaluation.static
    if curves is None:
        return None
    data = curves.data
    fig, (ax1, ax2, ax3) = _fig(13.0, 4.2, 1, 3)
    volt = np.abs(data.voltage_V) > 0
    for m, (u, d) in curves.voltage_curves.items():
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
    masses, d_mass = curves.mass_curve
    sel = ~volt
    ax2.plot(masses * 1e3, d_mass * 1e3, "-", label="model, 0 V")
    ax2.plot(data.mass_kg[sel] * 1e3, data.displacement_m[sel] * 1e3, "x", ms=8, label="data, 0 V")
    ax2.set_xlabel("mass (g)")
    ax2.set_ylabel("displacement d (mm)")
    ax2.set_title("static displacement vs mass")
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8, loc="upper left")
    err = (curves.predicted_m - data.displacement_m) * 1e6
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
    steps = result.evaluation.steps
    if not steps:
        return None
    n = len(steps)
    fig, axes = _fig(9.0, 3.2 * n + 1.5, 2 * n, 1, squeeze=False, sharex=False,
                     gridspec_kw={"height_ratios": [3, 1] * n})
    axes = axes[:, 0]
    for k, item in enumerate(steps):
        step, sim = item.step, item.simulated_m
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
    sines = result.evaluation.sines
    if not sines:
        return None
    fig, ax = _fig(8.5, 5.0)
    for k, item in enumerate(sines):
        sine = item.sine
        for amp, sweep, offset in item.dense:
            for br in sweep.branches:
                col = ("C2" if offset else "C0") if br.kind == "periodic" else "C1"
                (fs, ds), (fu, du) = stability_segments(br, sweep.bifurcations)
                # an offset sine's u^2 has period T: its primary orbit has period T, not T/2
                name = ("primary (period T)" if br.kind == "periodic" else "period-doubled (2T)") if offset \
                    else f"{br.name} branch ({br.kind})"
                ax.plot(fs, ds * 1e3, "-", color=col, lw=1.0, label=f"model {name}, {amp / 1e3:g} kV"
                        + (f" + {offset / 1e3:g} kV offset" if offset else ""))
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
                # (the identified model's peak can lie outside its samples' interval: no bar on that side)
                ax.errorbar([band.peak_frequency_Hz], [band.peak_d_rms_m * 1e3],
                            xerr=np.maximum([[band.peak_frequency_Hz - lo], [hi - band.peak_frequency_Hz]], 0.0),
                            yerr=np.maximum([[(band.peak_d_rms_m - band.peak_d_rms_ci_m[0]) * 1e3],
                                             [(band.peak_d_rms_ci_m[1] - band.peak_d_rms_m) * 1e3]], 0.0),
                            fmt="D", color="C0", ms=4, capsize=3, lw=0.8,
                            label=f"model peak, {100 * band.confidence:.0f} % interval")
        used = np.array(item.used)
        for kind, (marker, col) in KIND_MARKERS.items():
            sel = used == kind
            if np.any(sel):
                ax.plot(sine.frequency_Hz[sel], sine.d_rms_m[sel] * 1e3, marker,
                        color="k" if kind != "left out" else col,
                        mfc="none" if kind != "periodic" else "k", ms=6,
                        label=(f"data, fitted as {kind}" if kind != "left out"
                               else "data, left out (no periodic response)"))
    for item in sines:
        for res in item.resonance:
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
    items = [s for item in result.evaluation.sines for s in item.series]
    if not items:
        return None
    fig, axes = _fig(9.0, 2.8 * len(items) + 0.8, len(items), 1, squeeze=False)
    for ax, item in zip(axes[:, 0], items):
        ser = item.series
        show = ser.time_s <= ser.time_s[0] + max(3.0 / ser.frequency_Hz, 0.2)
        ax.plot(ser.time_s[show], ser.displacement_m[show] * 1e3, ".", ms=2, color="0.55", label="data")
        if item.model_m is not None:
            ax.plot(ser.time_s[show], item.model_m[show] * 1e3, "-", color="C0",
                    label=f"model ({item.kind})")
            ax.set_title(f"{ser.frequency_Hz:g} Hz: RMS error {item.rms_error_um:.3g} um (model "
                         f"{item.how})")
        else:
            ax.set_title(f"{ser.frequency_Hz:g} Hz: no periodic model response ({item.note})")
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
