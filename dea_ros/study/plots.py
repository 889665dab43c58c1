"""Maps of a study over two varied parameters: resonance-peak frequency and static stroke.

Up to :data:`SCATTER_MAX` designs, each design is a marker coloured by its value; designs with a
torus (quasi-periodic) band are ringed red, with a period-doubled band orange, with folds
(hysteresis) marked by a black triangle; failed designs are grey crosses (by reason in the
legend). Beyond that markers would hide each other, so the plane is cut into bins: each bin is
coloured by the median over its designs (the other parameters vary within a bin), and the
regions where at least half of the designs (counted over a bin and its neighbours) have a torus
band (red), a period-doubled band (orange) or folds (black, dashed) are hatched and outlined;
failed designs stay crosses. Figures use :class:`matplotlib.figure.Figure` (Agg), without pyplot
state.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_maps", "binned_panel", "SCATTER_MAX"]

#: Largest study drawn design by design; larger ones are drawn as binned maps.
SCATTER_MAX = 400

_SCALE = {"thickness_m": (1e6, "um"), "plate_radius_m": (1e3, "mm"), "electrode_width_m": (1e3, "mm"),
          "mass_kg": (1e3, "g"), "amplitude_V": (1e-3, "kV"), "offset_V": (1e-3, "kV"),
          "k1_Pa": (1e-6, "MPa"), "eta1_Pa_s": (1e-6, "MPa s"), "eta2_Pa_s": (1e-3, "kPa s"),
          "breakdown_field_V_per_m": (1e-6, "V/um")}


def _axis(name: str):
    scale, unit = _SCALE.get(name, (1.0, ""))
    return scale, f"{name}" + (f" [{unit}]" if unit else "")


def _bins(x, y, n_bins: int):
    """Bin edges over the range of x and y, and each point's bin index (ix, iy)."""
    edges = []
    index = []
    for v in (x, y):
        lo, hi = float(np.min(v)), float(np.max(v))
        if hi <= lo:
            hi = lo + 1.0
        e = np.linspace(lo, hi, n_bins + 1)
        edges.append(e)
        index.append(np.clip(np.searchsorted(e, v, side="right") - 1, 0, n_bins - 1))
    return edges, index


def _histogram(ix, iy, weights, n_bins: int) -> np.ndarray:
    out = np.zeros((n_bins, n_bins))
    np.add.at(out, (iy, ix), weights)
    return out


def _box3(a: np.ndarray) -> np.ndarray:
    """Sum over each cell and its 8 neighbours (cells beyond the edge count as empty)."""
    p = np.pad(a, 1)
    return sum(p[1 + di:p.shape[0] - 1 + di, 1 + dj:p.shape[1] - 1 + dj] for di in (-1, 0, 1) for dj in (-1, 0, 1))


def binned_panel(fig, ax, x, y, val, flags, label: str) -> list:
    """Median of val per bin (designs with finite values) and the regions where >= 50 % of the
    designs have each flag; returns the legend handles of those regions."""
    from matplotlib.patches import Patch

    n_bins = int(np.clip(np.sqrt(x.size / 8.0), 6, 40))    # ~8 designs per bin
    (ex, ey), (ix, iy) = _bins(x, y, n_bins)
    med = np.full(n_bins * n_bins, np.nan)
    sel = np.isfinite(val)
    flat = (iy * n_bins + ix)[sel]
    order = np.argsort(flat, kind="stable")
    bins, first = np.unique(flat[order], return_index=True)
    for b, group in zip(bins, np.split(val[sel][order], first[1:])):   # designs sorted by bin
        med[b] = np.median(group)
    med = med.reshape(n_bins, n_bins)
    mesh = ax.pcolormesh(ex, ey, med, cmap="viridis", shading="flat")
    fig.colorbar(mesh, ax=ax, label=f"{label}, median per bin")
    cx, cy = 0.5 * (ex[1:] + ex[:-1]), 0.5 * (ey[1:] + ey[:-1])
    count = _box3(_histogram(ix, iy, np.ones(x.size), n_bins))
    handles = []
    for has, colour, style, hatch, text in flags:
        # share of designs with the flag over each bin and its 8 neighbours (~70 designs: less noise)
        share = _box3(_histogram(ix, iy, has.astype(float), n_bins))
        share = np.divide(share, count, out=np.zeros_like(share), where=count > 0)
        if np.max(share) < 0.5:
            continue
        # the region (hatched) and its edge (line)
        region = ax.contourf(cx, cy, share, levels=[0.5, 1.5], colors="none", hatches=[hatch])
        for coll in getattr(region, "collections", None) or [region]:   # matplotlib < 3.8: .collections
            coll.set_edgecolor(colour)
            coll.set_linewidth(0.0)
        if np.min(share) < 0.5:
            ax.contour(cx, cy, share, levels=[0.5], colors=colour, linestyles=style, linewidths=1.6)
        handles.append(Patch(facecolor="none", edgecolor=colour, hatch=hatch, linestyle=style,
                             label=f"{text} in >= 50 % of designs"))
    return handles


def plot_maps(spec, rows: list, out_dir) -> list:
    """One PNG per pair in ``spec.plots`` (two panels: peak frequency, stroke); returns the paths."""
    from matplotlib.figure import Figure

    paths = []
    ok = np.array([r["status"] == "ok" for r in rows], dtype=bool)
    binned = len(rows) > SCATTER_MAX
    for xname, yname in spec.plots:
        sx, xlabel = _axis(xname)
        sy, ylabel = _axis(yname)
        x = np.array([r[xname] for r in rows]) * sx
        y = np.array([r[yname] for r in rows]) * sy
        fig = Figure(figsize=(12.0, 5.0), layout="constrained")
        axes = fig.subplots(1, 2)
        marks = (("quasi_periodic_width_Hz", "tab:red", "o", "-", "\\\\", "torus (quasi-periodic) band"),
                 ("period_doubled_width_Hz", "tab:orange", "s", "-", "////", "period-doubled band"))
        has_band = {col: ok & np.array([r[col] > 0 for r in rows], dtype=bool) for col, *_ in marks}
        folds = ok & np.array([r["n_folds"] > 0 for r in rows], dtype=bool)
        for ax, key, scale, label in ((axes[0], "peak_frequency_Hz", 1.0, "resonance peak frequency [Hz]"),
                                      (axes[1], "stroke_m", 1e6, "static stroke [um]")):
            val = np.array([r[key] for r in rows], float) * scale
            sel = ok & np.isfinite(val)
            regions = []
            if binned:
                flags = [(has_band[col][ok], colour, style, hatch, text)
                         for col, colour, _m, style, hatch, text in marks]
                flags.append((folds[ok], "k", "--", "..", "folds (hysteresis)"))
                if np.any(ok):
                    regions = binned_panel(fig, ax, x[ok], y[ok], val[ok], flags, label)
            else:
                if np.any(sel):
                    sc = ax.scatter(x[sel], y[sel], c=val[sel], s=36, cmap="viridis")
                    fig.colorbar(sc, ax=ax, label=label)
                for col, colour, marker, _style, _hatch, text in marks:
                    if np.any(has_band[col]):
                        ax.scatter(x[has_band[col]], y[has_band[col]], s=110, facecolors="none", edgecolors=colour,
                                   marker=marker, linewidths=1.2, label=text)
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
            handles = regions + ax.get_legend_handles_labels()[0]
            if handles:
                ax.legend(handles=handles, fontsize=7, loc="best")
        how = "binned: median per bin over the other parameters" if binned else "one marker per design"
        fig.suptitle(f"study {spec.name}: {len(rows)} designs ({spec.method}; {how})")
        path = Path(out_dir) / f"map_{xname}_{yname}.png"
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths
