"""Issue 21, item 3: the adaptive second pass in the core (no ROS).

A bag with two passes, as identifier_node records an adaptive protocol: pass 1's schedule in
``dea_ros.experiment``, a rest at 0 V (the first fit), pass 2's schedule in ``dea_ros.experiment.pass2`` with
its own t0. The data come from forward integration of the held voltage (A2, 1 um noise); the extraction must
cut every segment of both passes on its own time line, the offset sine of pass 2 apart from the |U sin| ones,
and a pass 2 aborted keeps its completed segments only. Then the planning of a second pass from a real first
fit (the softening membrane of test_planning) and the summary a two-pass bag reports.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from dea_ros.bag import BagReader
from dea_ros.identify.adaptive import adaptive_markdown, adaptive_summary, limits_for_protocol, plan_second_pass
from dea_ros.identify.bag_experiments import experiment_passes, experiment_record, experiments_from_bag, \
    pass_metadata_name
from dea_ros.identify.pipeline import identify
from dea_ros.identify.planning import PlanLimits
from dea_ros.identify.protocols import Protocol, load_protocol
from dea_ros.identify.synth import synthesize_experiments
from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers.integrate import simulate_held

from fakes.recorded_bag import T0_NS, write_rig_bag

from .conftest import NOISE_M, PAPER_FREQUENCIES_HZ, SOFTENING

GAP_S = 1.3   # 0 V between the passes (the first fit)
#: the extraction's guard at the 500 Hz command rate (bag_experiments: max(10 ms, two periods))
GUARD_S = 0.01

PASS1 = Protocol.from_dict({"name": "two_pass", "membrane": "A2", "mass_kg": 0.003, "adaptive": True,
                            "adaptive_budget_s": 10.0, "segments": [
                                {"kind": "static", "voltages_V": [0, 2000, 2500, 0], "hold_s": 1.5,
                                 "measure_s": 0.5},
                                {"kind": "step", "initial_V": 0, "final_V": 2200, "pre_s": 0.3, "hold_s": 2.0},
                                {"kind": "sine", "amplitude_V": 2500, "frequencies_Hz": [9.0], "settle_s": 2.0,
                                 "measure_s": 1.0}]})
PASS2 = Protocol.from_dict({"name": "two_pass-planned", "membrane": "A2", "mass_kg": 0.003, "segments": [
    {"kind": "static", "voltages_V": [2300], "hold_s": 1.5, "measure_s": 0.5},
    {"kind": "sine", "amplitude_V": 1250, "offset_V": 1250, "frequencies_Hz": [9.5], "settle_s": 2.0,
     "measure_s": 1.0},
    {"kind": "sine", "amplitude_V": 2000, "frequencies_Hz": [8.0], "settle_s": 2.0, "measure_s": 1.0},
    {"kind": "rest", "hold_s": 0.5}]})


def _voltage(segs1, segs2, t2_0):
    """The commanded voltage of both passes and the rest between them at time t (s from pass 1's t0)."""
    def at(t):
        segs, tt = (segs1, t) if t < segs1[-1].end_s else ((segs2, t - t2_0) if t >= t2_0 else (None, 0.0))
        if segs is None:
            return 0.0
        k = min(int(np.searchsorted([s.end_s for s in segs], tt, side="right")), len(segs) - 1)
        return segs[k].voltage_at(tt) if tt < segs[-1].end_s else 0.0
    return at


@pytest.fixture(scope="module")
def two_passes(tmp_path_factory):
    segs1, segs2 = PASS1.schedule(), PASS2.schedule()
    t2_0 = segs1[-1].end_s + GAP_S
    duration = t2_0 + segs2[-1].end_s
    at = _voltage(segs1, segs2, t2_0)
    tv = np.arange(0.0, duration, 2e-3)
    uv = np.array([at(t) for t in tv])
    td = np.arange(0.0, duration, 1e-3)
    # the held voltage integrated hold by hold (the compiled kernel of the mock's truth), each 2 ms hold as two
    # 1 ms holds of the same voltage so that the states fall on the laser's samples
    resp = simulate_held(preset("A2"), np.repeat(uv, 2), 1e-3)
    assert td.size <= resp.time_s.size - 1 and np.allclose(resp.time_s[:td.size], td, rtol=0.0, atol=1e-9)
    d_true = resp.displacement_m[:td.size]
    d = d_true + np.random.default_rng(5).normal(0, 1e-6, td.size)
    rec1 = experiment_record(PASS1, segs1, T0_NS, len(segs1), False, 500.0, "A2", 1)
    t2_ns = T0_NS + int(round(t2_0 * 1e9))
    extra = {"plan_json": json.dumps({"picks": [], "relative_ci95_before": {}}), "first_fit_json": "{}"}
    rec2 = experiment_record(PASS2, segs2, t2_ns, len(segs2), False, 500.0, "A2", 2, extra)
    out = tmp_path_factory.mktemp("passes")
    full = write_rig_bag(out / "full", tv, uv, td, d, [(pass_metadata_name(1), rec1), (pass_metadata_name(2), rec2)])
    aborted = dict(rec2, aborted="true", segments_completed="2")   # pass 2 stopped in its third segment
    cut = td < t2_0 + segs2[2].start_s + 0.5
    part = write_rig_bag(out / "aborted", tv[tv < td[cut][-1]], uv[tv < td[cut][-1]], td[cut], d[cut],
                         [(pass_metadata_name(1), rec1), (pass_metadata_name(2), aborted)])
    return {"full": full, "aborted": part, "segs1": segs1, "segs2": segs2, "t2_0": t2_0, "td": td,
            "d_true": d_true}


def test_both_passes_are_cut_each_on_its_own_time_line(two_passes):
    exp = experiments_from_bag(two_passes["full"])
    a2 = preset("A2")
    static = exp.static[0]
    # pass 1's staircase, then pass 2's level: a wrong t0 for pass 2 would average 0 V or a sine
    np.testing.assert_allclose(static.voltage_V, [0, 2000, 2500, 0, 2300], atol=1e-3)
    eq = static_equilibrium(a2, static.voltage_V).displacement_m
    assert np.max(np.abs(static.displacement_m - eq)) < 5e-6
    assert len(exp.steps) == 1 and exp.steps[0].final_V == pytest.approx(2200)
    # |U sin| of both passes in one record set, the offset sine of pass 2 apart
    assert len(exp.sines) == 2
    plain, offset = exp.sines
    assert list(plain.frequency_Hz) == [9.0, 8.0] and list(plain.amplitude_V) == [2500.0, 2000.0]
    assert plain.waveform == "abs_sine" and offset.waveform == "sine"
    assert list(offset.frequency_Hz) == [9.5] and "pass 2" in offset.series[0].source
    # each window holds the samples of the times pass 2's schedule names (its own t0): the recorded
    # displacement there is the integration's plus the 1 um noise, the held voltage the nominal one's
    td, d_true, t2_0 = two_passes["td"], two_passes["d_true"], two_passes["t2_0"]
    for sd, k, seg in ((plain, 1, two_passes["segs2"][2]), (offset, 0, two_passes["segs2"][1])):
        series = sd.series[k]
        # (the window starts 10 ms before the measuring start, in the same sine's settling, and ends
        # 10 ms before the segment's end: it keeps the planned whole periods)
        start = seg.measure_start_s - GUARD_S
        first = int(np.searchsorted(td, t2_0 + start - 1e-9))
        # (a sample on the window's start is a tie the epoch stamps' rounding resolves either way)
        spread = min(np.std(series.displacement_m - d_true[first + lag:first + lag + series.time_s.size])
                     for lag in (-1, 0, 1))
        assert spread == pytest.approx(1e-6, rel=0.15)
        assert sd.d_rms_m[k] > 20e-6
        nominal = np.array([seg.voltage_at(start + t) for t in series.time_s])
        assert np.sqrt(np.mean(series.voltage_V ** 2)) == pytest.approx(np.sqrt(np.mean(nominal ** 2)), rel=0.02)


def test_an_aborted_second_pass_keeps_its_completed_segments(two_passes):
    with BagReader(two_passes["aborted"], warn=False) as reader:
        passes = experiment_passes(reader.metadata(), two_passes["aborted"])
    assert [len(p[2]) for p in passes] == [len(two_passes["segs1"]), 2]
    exp = experiments_from_bag(two_passes["aborted"])
    assert [list(s.frequency_Hz) for s in exp.sines] == [[9.0], [9.5]]   # the 8 Hz record was not completed


def test_limits_follow_the_first_pass():
    limits = limits_for_protocol(PASS1)
    assert limits.max_voltage_V == 2500.0 and limits.settle_s == 2.0 and limits.measure_s == 1.0
    assert (limits.step_pre_s, limits.step_hold_s) == (0.3, 2.0)
    assert (limits.static_hold_s, limits.static_measure_s) == (1.5, 0.5)
    assert limits.step_rest_min_s == 2.0          # pass 1's step follows 2500 V directly: the default
    quick = limits_for_protocol(load_protocol("quick_adaptive"))
    assert quick.step_rest_min_s == 17.0           # its step: 10 s at 0 V (the staircase's last level) + 7 s rest
    # every planned sine has two periods measured at least (pass 1: 1 s measured, quick: 2 s)
    assert limits.min_frequency_Hz == pytest.approx(1.01) and quick.min_frequency_Hz == pytest.approx(0.505)
    assert limits_for_protocol(PASS1, max_voltage_V=2100.0).max_voltage_V == 2100.0
    # the holds: as long as the membrane needs to settle, at most the protocol's adaptive_max_settle_s
    assert limits.max_settle_s == 60.0
    capped = Protocol.from_dict({**PASS1.to_dict()["protocol"], "adaptive_max_settle_s": 5.0})
    assert limits_for_protocol(capped).max_settle_s == 5.0
    assert capped.to_dict()["protocol"]["adaptive_max_settle_s"] == 5.0


@pytest.fixture(scope="module")
def planned():
    exp = synthesize_experiments(SOFTENING, NOISE_M, seed=3, sine_frequencies_Hz=PAPER_FREQUENCIES_HZ,
                                 series_frequencies_Hz=())
    res = identify(exp, evaluate_fit=False)
    base = Protocol.from_dict({"name": "soft", "membrane": "A2", "mass_kg": SOFTENING.mass_kg, "adaptive": True,
                               "adaptive_budget_s": 40.0, "segments": [
                                   {"kind": "static", "voltages_V": [0, 2500], "hold_s": 4.0, "measure_s": 1.0},
                                   {"kind": "step", "initial_V": 0, "final_V": 2200, "pre_s": 0.2, "hold_s": 4.0},
                                   {"kind": "sine", "amplitude_V": 2500, "frequencies_Hz": [8.3],
                                    "settle_s": 8.0, "measure_s": 2.0}]})
    return res, base, plan_second_pass(res, base)


def test_the_second_pass_runs_the_planners_picks_within_the_budget(planned):
    res, base, second = planned
    plan = second.plan
    assert plan.picks and plan.total_s <= base.adaptive_budget_s + 1e-9
    segs = second.segments()
    sines = sorted((s.info["frequency_Hz"], s.info["amplitude_V"], s.info["offset_V"]) for s in segs
                   if s.kind == "sine")
    picked = sorted((p.record.frequency_Hz, p.record.amplitude_V, p.record.offset_V) for p in plan.picks
                    if p.record.kind == "sine")
    assert sines == picked
    assert sum(s.kind == "step" for s in segs) == sum(p.record.kind == "step" for p in plan.picks)
    assert max(s.info.get("offset_V", 0) + s.info.get("amplitude_V", 0) for s in segs) <= 2500.0
    # the widest interval of the first fit shrinks in expectation (eta1, correlated with eta2)
    name = max(plan.targets, key=lambda n: min(plan.widths_before[n], 100.0))
    assert plan.widths_after[name] < plan.widths_before[name]
    extra = second.record_extra()
    assert json.loads(extra["plan_json"])["picks"][0]["label"] == plan.picks[0].record.label()
    assert json.loads(extra["first_fit_json"])["parameters"]["eta1_Pa_s"] == pytest.approx(res.parameters.eta1_Pa_s)
    # planned as the first pass was measured: its step's sample rate (not PlanLimits' 1 kHz; session 20)
    step_rate = 1.0 / np.median(np.diff(res.experiments.steps[0].time_s))
    assert second.limits.sample_rate_Hz == pytest.approx(step_rate) and step_rate != PlanLimits().sample_rate_Hz


def test_a_two_pass_bag_reports_the_plan_and_the_realised_widths(two_passes, planned, tmp_path):
    res, _base, second = planned
    segs1, segs2 = two_passes["segs1"], two_passes["segs2"]
    rec1 = experiment_record(PASS1, segs1, T0_NS, len(segs1), False, 500.0, "A2", 1)
    rec2 = experiment_record(PASS2, segs2, T0_NS + 10**9, len(segs2), False, 500.0, "A2", 2, second.record_extra())
    bag = write_rig_bag(tmp_path / "meta", np.arange(0, 0.1, 2e-3), np.zeros(50), np.arange(0, 0.1, 1e-3),
                        np.zeros(100), [(pass_metadata_name(1), rec1), (pass_metadata_name(2), rec2)])
    summary = adaptive_summary(bag, res)
    data = summary.to_dict()
    assert data["passes"] == 2 and [r["segments"] for r in data["pass_records"]] == [len(segs1), len(segs2)]
    assert [p["label"] for p in data["plan"]["picks"]] == [p.record.label() for p in second.plan.picks]
    assert set(data["realised_relative_ci95"]) >= {"eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"}
    text = adaptive_markdown(summary)
    assert "## Adaptive second pass" in text and second.plan.picks[0].record.label() in text
    assert "expected after plan" in text and "eta1/eta2" in text
