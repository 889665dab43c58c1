"""Maps of a study over two varied parameters: resonance-peak frequency and static stroke.

Each design is a marker coloured by its value; designs with a torus (quasi-periodic) band are
ringed red, with a period-doubled band orange, with folds (hysteresis) marked by a black
triangle; failed designs are grey crosses (by reason in the legend). Figures use
:class:`matplotlib.figure.Figure` (Agg), without pyplot state.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_maps"]

_SCALE = {"thickness_m": (1e6, "um"), "plate_radius_m": (1e3, "mm"), "electrode_width_m": (1e3, "mm"),
          "mass_kg": (1e3, "g"), "amplitude_V": (1e-3, "kV"), "offset_V": (1e-3, "kV"),
          "k1_Pa": (1e-6, "MPa"), "eta1_Pa_s": (1e-6, "MPa s"), "eta2_Pa_s": (1e-3, "kPa s"),
          "breakdown_field_V_per_m": (1e-6, "V/um")}


def _axis(name: str):
    scale, unit = _SCALE.get(name, (1.0, ""))
    return scale, f"{name}" + (f" [{unit}]" if unit else "")


def plot_maps(spec, rows: list, out_dir) -> list:
    """One PNG per pair in ``spec.plots`` (two panels: peak frequency, stroke); returns the paths."""
    from matplotlib.figure import Figure

    paths = []
    ok = np.array([r["status"] == "ok" for r in rows], dtype=bool)
    for xname, yname in spec.plots:
        sx, xlabel = _axis(xname)
        sy, ylabel = _axis(yname)
        x = np.array([r[xname] for r in rows]) * sx
        y = np.array([r[yname] for r in rows]) * sy
        fig = Figure(figsize=(12.0, 5.0), layout="constrained")
        axes = fig.subplots(1, 2)
        for ax, key, scale, label in ((axes[0], "peak_frequency_Hz", 1.0, "resonance peak frequency [Hz]"),
                                      (axes[1], "stroke_m", 1e6, "static stroke [um]")):
            val = np.array([r[key] for r in rows], float) * scale
            sel = ok & np.isfinite(val)
            if np.any(sel):
                sc = ax.scatter(x[sel], y[sel], c=val[sel], s=36, cmap="viridis")
                fig.colorbar(sc, ax=ax, label=label)
            marks = (("quasi_periodic_width_Hz", "tab:red", "o", "torus (quasi-periodic) band"),
                     ("period_doubled_width_Hz", "tab:orange", "s", "period-doubled band"))
            for col, colour, marker, text in marks:
                has = ok & np.array([r[col] > 0 for r in rows], dtype=bool)
                if np.any(has):
                    ax.scatter(x[has], y[has], s=110, facecolors="none", edgecolors=colour, marker=marker,
                               linewidths=1.2, label=text)
            folds = ok & np.array([r["n_folds"] > 0 for r in rows], dtype=bool)
            if np.any(folds):
                ax.scatter(x[folds], y[folds], s=14, marker="^", color="k", label="folds (hysteresis)")
            for reason in sorted({r["failure"] for r in rows if r["status"] != "ok"}):
                sel_f = np.array([r["status"] != "ok" and r["failure"] == reason for r in rows], dtype=bool)
                ax.scatter(x[sel_f], y[sel_f], s=30, marker="x", color="0.5" if reason != "breakdown limit"
                           else "tab:brown", label=f"failed: {reason}")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
            ax.set_title(label)
            ax.grid(alpha=0.3)
            handles, labels = ax.get_legend_handles_labels()
            if handles:
                ax.legend(fontsize=7, loc="best")
        fig.suptitle(f"study {spec.name}: {len(rows)} designs ({spec.method})")
        path = Path(out_dir) / f"map_{xname}_{yname}.png"
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths
