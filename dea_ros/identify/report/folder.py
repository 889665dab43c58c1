"""The report folder of an identification: params.yaml, the figures, report.md and result.json."""
from __future__ import annotations

import json
import time
from pathlib import Path

from ..result import IdentificationResult
from .figures import plot_frequency, plot_sine_series, plot_static, plot_steps
from .markdown import report_markdown
from .parameters_file import write_parameters

__all__ = ["write_report", "FIGURES"]

#: The figures of a report: (title in report.md, file name, drawing function).
FIGURES = (("Static displacement (Fig. 6)", "static.png", plot_static),
           ("Step response (Fig. 8, left)", "step.png", plot_steps),
           ("Frequency response (Fig. 8, right)", "frequency.png", plot_frequency),
           ("Sampled sine records", "sine_series.png", plot_sine_series))


def write_report(result: IdentificationResult, out_dir: str | Path, plots: bool = True) -> dict:
    """Write params.yaml, the figures, report.md and result.json into ``out_dir``; return the paths
    and the time spent (``report_s``)."""
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"params": write_parameters(result, out / "params.yaml")}
    figures = {}
    if plots:
        for title, name, fn in FIGURES:
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
