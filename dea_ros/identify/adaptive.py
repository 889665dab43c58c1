"""The adaptive second pass (issue 21, item 3): plan it from the first fit, record it, report it.

A protocol with ``adaptive: true`` (:mod:`~dea_ros.identify.protocols`) runs in two passes on the rig:

1. the protocol's own segments (pass 1); then 0 V while the first fit runs on what is recorded;
2. the records the Fisher-information planner picks from that fit (:func:`plan_second_pass`: the
   planner of :mod:`~dea_ros.identify.planning` within ``adaptive_budget_s`` seconds, recorded like the
   first pass -- the settle/measure/hold times of its segments, no voltage above its peak or the rig's
   maximum), run as a second schedule from the clock at which the plan was ready;

then the identification from both passes together. Both passes are in the same bag: pass 1's
schedule in the metadata record ``dea_ros.experiment`` and pass 2's in ``dea_ros.experiment.pass2``, each
with its own start time t0 (:func:`~dea_ros.identify.bag_experiments.experiment_record`); pass 2's record
also carries the plan (``plan_json``) and the first fit (``first_fit_json``). So ``dea-ros identify BAG``
cuts and fits both passes offline as the node did (:func:`~dea_ros.identify.bag_experiments.experiments_from_bag`)
and writes the same :class:`AdaptiveSummary` into the summary and the report.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..bag import BagReader
from .bag_experiments import experiment_passes
from .planning import ExperimentPlan, PlanLimits, first_fit_from_result, fit_widths, plan_experiments, plan_protocol
from .protocols import Protocol, Segment

__all__ = ["SecondPass", "AdaptiveSummary", "limits_for_protocol", "plan_second_pass", "adaptive_summary",
           "adaptive_markdown", "adaptive_headline"]

_SHORT = {"eps_r": "eps_r", "k1_Pa": "k1", "eta1_Pa_s": "eta1", "eta2_Pa_s": "eta2", "sigma_h''(1)_Pa": "sigma_h''(1)"}


def _peak_V(segments) -> float:
    """The highest voltage a schedule commands (V)."""
    peak = 0.0
    for s in segments:
        i = s.info
        peak = max(peak, i.get("voltage_V", 0.0), i.get("initial_V", 0.0), i.get("final_V", 0.0),
                   i.get("offset_V", 0.0) + i.get("amplitude_V", 0.0))
    return float(peak)


def _rest_before_step_s(segments) -> float:
    """The time at 0 V before the schedule's first step (rest segments and static holds at 0 V), s."""
    k = next((i for i, s in enumerate(segments) if s.kind == "step"), 0)
    rest = 0.0
    while k > 0 and (segments[k - 1].kind == "rest" or segments[k - 1].info.get("voltage_V", 1.0) == 0.0):
        k -= 1
        rest += segments[k].end_s - segments[k].start_s
    return rest


def limits_for_protocol(base: Protocol, max_voltage_V: float | None = None,
                        sample_rate_Hz: float | None = None) -> PlanLimits:
    """The planner's limits for a second pass of ``base``: no voltage above the first pass's peak (nor
    ``max_voltage_V``, the rig's maximum, where given), the laser's ``sample_rate_Hz`` (the samples a
    record's RMS and a step are measured with; default PlanLimits'), and every record as long as the first pass's of
    its kind (its sines' settle/measure with at least two periods measured, its step's pre/hold, its
    static hold/measure; a step after at least the rest at 0 V the first pass gave its step), held longer
    where the fitted membrane needs it to settle (:func:`~.planning.record_settle`), at most the protocol's
    ``adaptive_max_settle_s``."""
    schedule = base.schedule()
    peak = _peak_V(schedule)
    kw = {"max_voltage_V": min(peak, max_voltage_V) if max_voltage_V else peak,
          "step_rest_min_s": max(2.0, _rest_before_step_s(schedule)), "max_settle_s": base.adaptive_max_settle_s}
    if sample_rate_Hz:
        kw["sample_rate_Hz"] = float(sample_rate_Hz)
    fields = {"sine": (("settle_s", "settle_s"), ("measure_s", "measure_s")),
              "step": (("pre_s", "step_pre_s"), ("hold_s", "step_hold_s")),
              "static": (("hold_s", "static_hold_s"), ("measure_s", "static_measure_s"))}
    for seg in base.raw_segments:
        for key, name in fields.get(seg.get("kind"), ()):
            if key in seg and name not in kw:
                kw[name] = float(seg[key])
    # at least two measured periods: the bag extraction's guard at a window's end (the command lead) leaves
    # a one-period record less than a period, which it refuses
    kw["min_frequency_Hz"] = max(PlanLimits.min_frequency_Hz, 1.01 / kw.get("measure_s", PlanLimits.measure_s))
    return PlanLimits(**kw)


@dataclass
class SecondPass:
    """The planned second pass: the plan (why), the protocol it runs and its schedule (s from its t0)."""

    plan: ExperimentPlan
    protocol: Protocol
    limits: PlanLimits
    first_fit: dict              # the first fit's parameters (SI) and relative 95 % half-widths

    def segments(self, max_voltage_V: float | None = None) -> list[Segment]:
        return self.protocol.schedule(max_voltage_V)

    def record_extra(self) -> dict:
        """What pass 2's metadata record adds to :func:`~.bag_experiments.experiment_record` (JSON strings)."""
        return {"plan_json": json.dumps(self.plan.to_dict(), default=_json_float),
                "first_fit_json": json.dumps(self.first_fit, default=_json_float)}


def _json_float(value):
    return float(value)


def _sample_rate_Hz(result) -> float | None:
    """The sample rate of the first step record the result was fitted with (Hz), None without one (session 20:
    the planner assumed PlanLimits' 1 kHz for a rig sampled at 500 Hz; its expected widths were 1.3x narrow)."""
    steps = result.experiments.steps
    return float(1.0 / np.median(np.diff(steps[0].time_s))) if steps else None


def plan_second_pass(first_result, base: Protocol, max_voltage_V: float | None = None) -> SecondPass:
    """The second pass of an adaptive protocol from its first fit (an
    :class:`~dea_ros.identify.result.IdentificationResult`): :func:`plan_experiments` within
    ``base.adaptive_budget_s`` and :func:`limits_for_protocol` (the laser's sample rate that of the first pass's
    step record: the planned records are measured as those were), as :func:`plan_protocol` segments.
    PlanningError when the first fit has no Fisher information or nothing can be planned."""
    limits = limits_for_protocol(base, max_voltage_V, _sample_rate_Hz(first_result))
    first = first_fit_from_result(first_result)
    plan = plan_experiments(first, budget_s=base.adaptive_budget_s, limits=limits)
    protocol = plan_protocol(plan, base, limits)
    first_fit = {"parameters": first_result.parameters.to_dict(), "relative_ci95": plan.widths_before,
                 "correlation": plan.correlation_before}
    return SecondPass(plan, protocol, limits, first_fit)


@dataclass
class AdaptiveSummary:
    """What a two-pass identification did: its passes, the plan (picks, expected widths before/after) and
    the realised result (relative 95 % half-widths of the two-pass fit, its intervals)."""

    passes: list                 # per pass: number, protocol, segments, duration_s, aborted
    plan: dict                   # ExperimentPlan.to_dict() as recorded
    first_fit: dict
    realised_relative_ci95: dict = field(default_factory=dict)
    realised_correlation: dict = field(default_factory=dict)
    final_ci95: dict = field(default_factory=dict)   # name -> {status, ci95}

    def to_dict(self) -> dict:
        return {"passes": len(self.passes), "pass_records": list(self.passes), "plan": self.plan,
                "first_fit": self.first_fit, "realised_relative_ci95": dict(self.realised_relative_ci95),
                "realised_correlation": dict(self.realised_correlation), "final_ci95": dict(self.final_ci95)}


def adaptive_summary(bag, result) -> AdaptiveSummary | None:
    """The :class:`AdaptiveSummary` of a bag with a second pass and its two-pass ``result`` (None for one pass)."""
    with BagReader(bag, warn=False) as reader:
        metadata = reader.metadata()
    passes = experiment_passes(metadata, bag)
    if len(passes) < 2:
        return None
    records = [{"pass": n, "protocol": info.get("protocol", ""), "segments": len(segs),
                "duration_s": float(segs[-1]["end_s"]) if segs else 0.0,
                "aborted": str(info.get("aborted", "false")).lower() == "true"}
               for n, (info, _t0, segs) in enumerate(passes, 1)]
    extra = passes[1][0]
    plan = json.loads(extra.get("plan_json", "{}"))
    first = json.loads(extra.get("first_fit_json", "{}"))
    widths, corr = {}, {}
    if result.fisher_information() is not None:
        widths, corr = fit_widths(first_fit_from_result(result))
    elif result.statistics is not None:
        # no joint refinement to take them from (rejected: the two-stage result is reported): the reported
        # intervals' relative half-widths
        widths = dict(zip(result.statistics.names, map(float, result.statistics.relative_ci)))
    meta = result.identification_metadata().get("parameters") or {}
    return AdaptiveSummary(records, plan, first, widths, corr, {k: dict(v) for k, v in meta.items()})


def _pct(w) -> str:
    return "unbounded" if w is None or not math.isfinite(float(w)) else f"+-{float(w) * 100:.3g} %"


def adaptive_headline(summary: AdaptiveSummary) -> list:
    """The log lines of a two-pass identification."""
    picks = summary.plan.get("picks", [])
    lines = [f"adaptive: {len(summary.passes)} passes; the planner picked {len(picks)} records "
             f"({summary.plan.get('total_s', 0.0):.1f} s): " + "; ".join(p["label"] for p in picks)]
    before, after = summary.plan.get("relative_ci95_before", {}), summary.plan.get("relative_ci95_after", {})
    lines.append("95 % half-widths first fit -> expected -> two-pass: " + ", ".join(
        f"{_SHORT[n]} {_pct(before.get(n))} -> {_pct(after.get(n))} -> {_pct(summary.realised_relative_ci95.get(n))}"
        for n in _SHORT if n in before))
    return lines


def adaptive_markdown(summary: AdaptiveSummary) -> str:
    """The report's section on the two passes: what the planner picked and why, expected and realised widths."""
    plan = summary.plan
    lines = ["## Adaptive second pass", ""]
    for r in summary.passes:
        lines.append(f"- pass {r['pass']}: protocol `{r['protocol']}`, {r['segments']} segments, "
                     f"{r['duration_s']:.1f} s{' (aborted)' if r['aborted'] else ''}")
    lines += ["", f"The second pass was planned from the first fit's Fisher information (criterion "
              f"`{plan.get('criterion')}`, budget {plan.get('budget_s', 0):g} s, {plan.get('candidates')} "
              "candidate records): each pick is the record that shrinks the target intervals most per second "
              "of experiment time.", "", "| # | record | s | criterion decrease |", "|---|---|---|---|"]
    for k, p in enumerate(plan.get("picks", []), 1):
        lines.append(f"| {k} | {p['label']} | {p['duration_s']:.1f} | {p['criterion_decrease']:.3g} |")
    before, after = plan.get("relative_ci95_before", {}), plan.get("relative_ci95_after", {})
    lines += ["", "Relative 95 % half-widths (ln for k1, eta1, eta2): the first fit's, those the plan expected "
              "(linearised at the first fit), and the realised ones of the fit from both passes (its own Fisher "
              "information); the final intervals are those of the parameter table above.", "",
              "| parameter | first fit | expected after plan | two-pass fit | final 95 % interval | status |",
              "|---|---|---|---|---|---|"]
    for name in before:
        final = summary.final_ci95.get(name, {})
        ci = final.get("ci95")
        ci_text = f"[{ci[0]:.5g}, {ci[1]:.5g}]" if ci and None not in ci else "-"
        lines.append(f"| {name} | {_pct(before.get(name))} | {_pct(after.get(name))} | "
                     f"{_pct(summary.realised_relative_ci95.get(name))} | {ci_text} | {final.get('status', '-')} |")
    for pair, value in plan.get("correlation_before", {}).items():
        lines.append(f"\ncorrelation {pair}: first fit {value:+.3f}, expected "
                     f"{plan.get('correlation_after', {}).get(pair, float('nan')):+.3f}, two-pass "
                     f"{summary.realised_correlation.get(pair, float('nan')):+.3f}")
    lines += [f"\nnote: {n}" for n in plan.get("notes", [])]
    return "\n".join(lines) + "\n"
