"""Identify many membranes at once: experiment folders or bags in parallel, a summary table, the spread.

``dea-ros identify IN1 IN2 ... --out OUT`` (more than one input) runs :func:`identify_input` for
every input on an engine (one task per input; the CLI passes the study's
:class:`~dea_ros.study.engine.Engine`, local processes or Dask: any object with
``map_unordered(fn, items)`` yielding ``(key, result, exception)`` and ``describe()``; without one, in
this process) and writes

* ``OUT/<input name>/``: what ``dea-ros identify`` writes for one input (params.yaml, report);
* ``OUT/summary.csv`` and ``OUT/summary.md``: one row per input: the identified parameters with
  their 95 % intervals, the model's resonance peak (with its interval when the uncertainty band
  was computed), the number of warnings and the warnings themselves, or why the input failed;
* ``OUT/spread.png``: every parameter per membrane with its interval, the batch's median marked.

:func:`identify_input` is also the single-input path's core for folders (load, identify, report)
and dispatches bags to :func:`~dea_ros.identify.from_bag.identify_bag`. With ``--scheduler`` the
inputs and OUT must be paths the cluster's workers can reach (a shared file system).
"""
from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import BagError, ExperimentError, NoEquilibriumError, ParameterError
from .bag_experiments import BagTopics
from .experiments import load_experiment_set
from .from_bag import identify_bag, is_bag
from .pipeline import identify
from .report import write_report

__all__ = ["identify_input", "identify_many", "SUMMARY_PARAMETERS", "labels_for"]

#: Parameters of the summary table: (column, key in identification metadata or parameters, unit scale, unit).
SUMMARY_PARAMETERS = (
    ("eps_r", "eps_r", 1.0, ""),
    ("k1_Pa", "k1_Pa", 1e-6, "MPa"),
    ("eta1_Pa_s", "eta1_Pa_s", 1e-6, "MPa s"),
    ("eta2_Pa_s", "eta2_Pa_s", 1e-3, "kPa s"),
    ("sigma_h(1)_Pa", "sigma_h(1)_Pa", 1e-3, "kPa"),
    ("dsigma_h_dlambda(1)_Pa", "dsigma_h_dlambda(1)_Pa", 1e-3, "kPa"),
)
_BAD_INPUT = "bad input"
_FIT_FAILED = "fit failed"


def labels_for(inputs) -> list:
    """Folder names for the inputs' outputs: their base names, made unique (``name``, ``name_2``, ...)."""
    seen: dict = {}
    out = []
    for item in inputs:
        p = Path(str(item))
        base = (p.stem if p.suffix == ".mcap" else p.name) or "input"
        k = seen.get(base, 0) + 1
        seen[base] = k
        out.append(base if k == 1 else f"{base}_{k}")
    return out


def _row_from(label: str, data: str, identification: dict, parameters: dict, metrics, warnings: list,
              bands: list) -> dict:
    row = {"input": str(data), "name": label, "status": "ok", "error": ""}
    for col, key, _scale, _unit in SUMMARY_PARAMETERS:
        if key == "eps_r":
            value = parameters.get("relative_permittivity")
        elif key in parameters:
            value = parameters[key]
        else:
            value = identification.get(key)
        ci = identification.get(f"{key}_ci95") or [math.nan, math.nan]
        row[col] = float(value) if isinstance(value, (int, float)) else math.nan
        row[f"{col}_ci95_low"], row[f"{col}_ci95_high"] = float(ci[0]), float(ci[1])
    peak = math.nan
    for entry in (metrics or {}).get("frequency_response", []) if isinstance(metrics, dict) else []:
        for res in entry.get("resonance", []):
            if not math.isfinite(peak) and res.get("simulated_peak_Hz") is not None:
                peak = float(res["simulated_peak_Hz"])
    row["peak_frequency_Hz"] = peak
    lo, hi = (bands[0]["peak_frequency_ci_Hz"] if bands else [math.nan, math.nan])
    row["peak_frequency_Hz_ci95_low"], row["peak_frequency_Hz_ci95_high"] = float(lo), float(hi)
    row["n_warnings"] = len(warnings)
    row["warnings"] = " | ".join(warnings)
    return row


def identify_input(data, out_dir, membrane=None, topics=None, segments_file=None, plots: bool = True,
                   label: str | None = None, **identify_options) -> dict:
    """Identify one experiment folder or bag into ``out_dir`` (params.yaml and the report); return a summary
    row (parameters, 95 % intervals, resonance peak, warnings). Errors propagate."""
    path = Path(str(data))
    label = label or labels_for([path])[0]
    if is_bag(path) and not (path / "manifest.yaml").is_file():
        summary = identify_bag(path, out_dir, membrane=membrane, topics=topics or BagTopics(),
                               segments_file=segments_file, plots=plots, **identify_options)
        return _row_from(label, str(data), summary.get("identification", {}), summary["parameters"],
                         summary.get("metrics"), summary.get("warnings", []), summary.get("uncertainty", []))
    result = identify(load_experiment_set(path), **identify_options)
    write_report(result, out_dir, plots=plots)
    return _row_from(label, str(data), result.identification_metadata(), result.parameters.to_dict(),
                     result.evaluation.to_dict(), list(result.warnings), [b.to_dict() for b in result.uncertainty])


def _task(task: dict) -> dict:
    """Engine task: one input; never raises (the row says what went wrong)."""
    t0 = time.perf_counter()
    label, data = task["label"], task["data"]
    try:
        row = identify_input(data, task["out_dir"], membrane=task.get("membrane"), segments_file=task.get("segments"),
                             plots=task.get("plots", True), label=label, **task.get("options", {}))
    except (ExperimentError, ParameterError, BagError, OSError, UnicodeDecodeError, RecursionError) as exc:
        row = {"input": str(data), "name": label, "status": _BAD_INPUT, "error": f"{type(exc).__name__}: {exc}"}
    except (RuntimeError, ArithmeticError, ValueError, NoEquilibriumError) as exc:
        row = {"input": str(data), "name": label, "status": _FIT_FAILED, "error": f"{type(exc).__name__}: {exc}"}
    row["wall_time_s"] = time.perf_counter() - t0
    return row


def _columns() -> list:
    cols = ["name", "input", "status"]
    for col, _k, _s, _u in SUMMARY_PARAMETERS:
        cols += [col, f"{col}_ci95_low", f"{col}_ci95_high"]
    cols += ["peak_frequency_Hz", "peak_frequency_Hz_ci95_low", "peak_frequency_Hz_ci95_high", "n_warnings",
             "error", "warnings"]
    return cols


def _write_summary(rows: list, out: Path) -> dict:
    cols = _columns()
    with open(out / "summary.csv", "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(cols)
        for r in rows:
            w.writerow([_cell(r.get(c, "")) for c in cols])
    heads = [f"{c} [{u}] (95 % interval)" if u else f"{c} (95 % interval)" for c, _k, _s, u in SUMMARY_PARAMETERS]
    n_cols = len(SUMMARY_PARAMETERS) + 2
    lines = ["# Identification of many inputs", "",
             "| membrane | status | " + " | ".join(heads) + " | resonance peak [Hz] | warnings |",
             "|---|---|" + "---|" * n_cols]
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"| {r['name']} | {r['status']}: {r.get('error', '')[:200]} |" + " |" * n_cols)
            continue
        cells = []
        for c, _k, s, _u in SUMMARY_PARAMETERS:
            lo, hi = r[f"{c}_ci95_low"], r[f"{c}_ci95_high"]
            ci = f" [{lo * s:.4g}, {hi * s:.4g}]" if math.isfinite(lo) and math.isfinite(hi) else ""
            cells.append(f"{r[c] * s:.5g}{ci}")
        lo, hi = r["peak_frequency_Hz_ci95_low"], r["peak_frequency_Hz_ci95_high"]
        peak = f"{r['peak_frequency_Hz']:.4f}" + (f" [{lo:.4f}, {hi:.4f}]" if math.isfinite(lo) else "")
        lines.append(f"| {r['name']} | ok | " + " | ".join(cells) + f" | {peak} | {r['n_warnings']} |")
    lines.append("")
    warned = [r for r in rows if r.get("warnings")]
    if warned:
        lines += ["## Warnings per membrane", ""]
        for r in warned:
            lines.append(f"### {r['name']}")
            lines.append("")
            lines += [f"- {w}" for w in r["warnings"].split(" | ")]
            lines.append("")
    (out / "summary.md").write_text("\n".join(lines))
    return {"csv": out / "summary.csv", "md": out / "summary.md"}


def _cell(v):
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return str(v)


def plot_spread(rows: list, path) -> Path | None:
    """Every summary parameter per membrane with its 95 % interval; the batch's median dashed."""
    ok = [r for r in rows if r["status"] == "ok"]
    if not ok:
        return None
    from matplotlib.figure import Figure

    params = list(SUMMARY_PARAMETERS) + [("peak_frequency_Hz", "", 1.0, "Hz")]
    ncols = 4
    nrows = int(math.ceil(len(params) / ncols))
    fig = Figure(figsize=(3.6 * ncols, 3.0 * nrows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols)).reshape(-1)
    x = np.arange(len(ok))
    names = [r["name"] for r in ok]
    for ax, (col, _k, s, unit) in zip(axes, params):
        v = np.array([r[col] for r in ok], float) * s
        lo = np.array([r.get(f"{col}_ci95_low", math.nan) for r in ok], float) * s
        hi = np.array([r.get(f"{col}_ci95_high", math.nan) for r in ok], float) * s
        has = np.isfinite(lo) & np.isfinite(hi)
        ax.plot(x, v, "o", color="C0")
        if np.any(has):
            ax.errorbar(x[has], v[has], yerr=[v[has] - lo[has], hi[has] - v[has]], fmt="none", ecolor="C0",
                        capsize=3)
        if np.any(np.isfinite(v)):
            ax.axhline(float(np.nanmedian(v)), color="k", ls="--", lw=0.7)
        ax.set_title(col + (f" [{unit}]" if unit else ""), fontsize=9)
        ax.set_xticks(x)
        ax.set_xticklabels(names, rotation=45, ha="right", fontsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[len(params):]:
        ax.set_visible(False)
    fig.suptitle(f"spread of the identified parameters over {len(ok)} membranes (95 % intervals; dashed: median)")
    fig.savefig(path, dpi=110)
    return Path(path)


def _in_process(tasks):
    """``(key, row, None)`` of every task, one after the other in this process (no engine)."""
    for key, task in tasks:
        yield key, _task(task), None


def identify_many(inputs, out_dir, engine=None, membrane=None, segments_file=None, plots: bool = True,
                  progress: Callable[[str], None] | None = None, **identify_options) -> dict:
    """Identify every input into ``out_dir/<name>/``; write the summary table and the spread plot; return
    {"rows", "summary_csv", "summary_md", "spread", "wall_time_s", "engine"}.

    ``engine``: an open engine to run the inputs on (module docstring); None: one after the other in this
    process. ``progress``: called with the name of each input when it is done."""
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    inputs = [str(i) for i in inputs]
    labels = labels_for(inputs)
    tasks = [(k, {"label": lab, "data": data, "out_dir": str(out / lab), "membrane": membrane,
                  "segments": segments_file, "plots": plots, "options": dict(identify_options)})
             for k, (lab, data) in enumerate(zip(labels, inputs))]
    rows: dict = {}
    for k, row, exc in (engine.map_unordered(_task, tasks) if engine is not None else _in_process(tasks)):
        if exc is not None:
            row = {"input": inputs[k], "name": labels[k], "status": _FIT_FAILED,
                   "error": f"{type(exc).__name__}: {exc}"}
        rows[k] = row
        if progress:
            progress(row["name"])
    ordered = [rows[k] for k in sorted(rows)]
    paths = _write_summary(ordered, out)
    spread = plot_spread(ordered, out / "spread.png") if plots else None
    return {"rows": ordered, "summary_csv": str(paths["csv"]), "summary_md": str(paths["md"]),
            "spread": str(spread) if spread else None, "wall_time_s": time.perf_counter() - t0,
            "engine": engine.describe() if engine is not None else "serial (this process)"}
