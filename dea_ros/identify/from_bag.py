"""Offline identification from a bag: bag -> experiments -> two-stage fit -> params.yaml + report.

Used by identifier_node when its protocol ends and by ``dea-ros identify BAG``. Works for bags
recorded by identifier_node and for any rosbag2 MCAP bag with compatible topic types when the
experiments are described by a segments YAML (see :mod:`dea_ros.identify.bag_experiments`).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from .adaptive import adaptive_headline, adaptive_markdown, adaptive_summary
from .bag_experiments import BagTopics, experiments_from_bag
from .pipeline import identify
from .report import write_report
from .result import IdentificationResult

__all__ = ["identify_bag", "fit_bag", "is_bag"]


def is_bag(path) -> bool:
    """A bag directory (metadata.yaml or *.mcap inside) or an .mcap file."""
    p = Path(path)
    if p.is_file():
        return p.suffix == ".mcap"
    return p.is_dir() and ((p / "metadata.yaml").is_file() or any(p.glob("*.mcap")))


def _headline(result: IdentificationResult) -> list:
    """The lines a node logs when the identification of a bag ends: parameters, peaks, steps, warnings."""
    p = result.parameters
    headline = [
        f"eps_r {p.relative_permittivity:.4g}, k1 {p.k1_Pa / 1e6:.4g} MPa, eta1 {p.eta1_Pa_s / 1e6:.4g} MPa s, "
        f"eta2 {p.eta2_Pa_s / 1e3:.4g} kPa s",
    ]
    for fr in result.evaluation.sines:
        for res in fr.resonance:
            if res.get("measured"):
                headline.append(
                    f"resonance at {res['amplitude_V']:g} V: measured {res['measured_peak_Hz']:.3f} Hz, "
                    f"model {res['simulated_peak_Hz']:.3f} Hz ({res['error_percent']:.2f} % apart)")
            else:
                headline.append(f"resonance at {res['amplitude_V']:g} V: model {res['simulated_peak_Hz']:.3f} Hz; "
                                f"measured peak {res.get('measured_note', 'not measured')}")
    for k, st in enumerate(result.evaluation.steps):
        headline.append(f"step {k + 1}: model vs measured RMS error {st.indices['rms_error_um']:.2f} um "
                        f"(IAE {st.indices['IAE_mm_s']:.4f} mm s)")
    if result.warnings:
        headline += [f"warning: {w}" for w in result.warnings[:5]]
    return headline


def fit_bag(bag, membrane: str | None = None, topics: BagTopics = BagTopics(), segments_file=None,
            progress: Callable[[str], None] | None = None, events: Callable[[dict], None] | None = None,
            **identify_options) -> tuple:
    """Bag -> experiments -> fit (every pass the bag records, :func:`~.bag_experiments.experiments_from_bag`):
    (result, timings in s). ``progress``/``events`` as :func:`identify_bag`. The bag may be open and
    still recorded (the adaptive first fit): its complete prefix is read."""
    say = progress or (lambda _msg: None)
    tell = events or (lambda _event: None)
    t0 = time.perf_counter()
    tell({"stage": "extract"})
    experiments = experiments_from_bag(bag, topics=topics, segments_file=segments_file, membrane=membrane)
    t_extract = time.perf_counter() - t0
    say(f"extracted from the bag in {t_extract:.2f} s: {experiments.summary()}")

    def fit_progress(event):
        tell(event)
        if isinstance(event, dict) and event.get("stage") and event.get("iteration") is not None \
                and event["iteration"] % 10 == 0:
            say(f"{event['stage']}: iteration {event['iteration']}, cost {event.get('cost', float('nan')):.4g}")

    notes = []
    masses = {float(m) for st in experiments.static for m in st.mass_kg if m > 0}
    if "stress_terms" not in identify_options and len(masses) <= 1:
        # One mass on the rig: the staircase d(u) determines sigma_h(1) and eps_r, but its slope
        # sigma_h'(1) only as a combination with them (correlation ~ -0.9996; a 400 % interval). The static
        # fit and stage 1 hold it at the base value (stage 1 started from the static fit's unconstrained
        # slope failed on a demo bag: harmonic balance at 9.5 Hz at every start); the joint refinement
        # fits it with the step and the sines, which determine it: held there too, the base's -3.9 % put
        # sigma_h(1) outside its interval on four of six seeds of the demo's protocol and k1 on two
        # (docs/benchmarks.md, issue 21 session 17).
        identify_options["stress_terms"] = 1
        dynamic = bool(experiments.steps or experiments.sines)
        identify_options.setdefault("joint_slope", dynamic)
        notes.append("static fit: one mass only, so sigma_h(1) and eps_r are fitted there and sigma_h'(1) is "
                     "held at the base value" + ("; the joint refinement fits sigma_h'(1) with the step and "
                                                 "the sines" if identify_options["joint_slope"] else
                                                 " (static points at other masses would determine it)"))
    t1 = time.perf_counter()
    result = identify(experiments, progress=fit_progress, **identify_options)
    result.warnings = notes + list(result.warnings)
    return result, {"extract": t_extract, "fit": time.perf_counter() - t1}


def identify_bag(bag, out_dir, membrane: str | None = None, topics: BagTopics = BagTopics(),
                 segments_file=None, progress: Callable[[str], None] | None = None, plots: bool = True,
                 events: Callable[[dict], None] | None = None, **identify_options) -> dict:
    """Identify from a bag; write ``out_dir/params.yaml`` and ``out_dir/report/``. Returns a summary dict.

    ``progress``: called with log lines; ``events``: called with every event dict of the fits (``stage``,
    ``evaluation``, ...) and ``{"stage": "extract"}``, ``{"stage": "report"}`` before those steps.
    A bag with an adaptive second pass (:mod:`~dea_ros.identify.adaptive`) is fitted from both passes;
    the report and the summary's ``adaptive`` say so (the plan, expected and realised widths)."""
    tell = events or (lambda _event: None)
    result, timings = fit_bag(bag, membrane, topics, segments_file, progress, events, **identify_options)
    out = Path(out_dir)
    report_dir = out / "report"
    tell({"stage": "report"})
    paths = write_report(result, report_dir, plots=plots)
    adaptive = None if segments_file is not None else adaptive_summary(bag, result)
    if adaptive is not None:
        with open(paths["report"], "a") as f:
            f.write("\n" + adaptive_markdown(adaptive))
    params_file = out / "params.yaml"
    params_file.write_text(Path(paths["params"]).read_text())
    p = result.parameters
    return {
        "params_file": str(params_file),
        "report_dir": str(report_dir),
        "report_file": str(paths["report"]),
        "figures": sorted(str(v) for k, v in paths.items() if str(k).endswith(".png")),
        "parameters": p.to_dict(),
        "metrics": result.to_dict().get("metrics"),
        "identification": result.to_dict().get("identification"),
        "uncertainty": [b.to_dict() for b in result.uncertainty],
        "warnings": list(result.warnings),
        "timings_s": {**timings, "report": paths.get("report_s", 0.0)},
        "headline": _headline(result) + (adaptive_headline(adaptive) if adaptive else []),
        **({"adaptive": adaptive.to_dict()} if adaptive is not None else {}),
    }
