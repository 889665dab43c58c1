"""Issue 21, item 3: the Fisher-information experiment planner (dea_ros.identify.planning) and ``dea-ros plan``.

The first fit: the softening membrane unlike the presets (conftest.SOFTENING, creep time 0.13 s) from the
paper's four sine frequencies, a step and static points; data by converged forward integration (synth),
1 um noise. There eta1 and eta2 trade off (correlation ~0.85) and eta1's interval is the widest of the
four material parameters. The planner must pick records that shrink eta1's predicted interval, better
than the same time spent on other candidates, and a re-fit with those records' synthetic data (forward
integration again, another noise seed) must narrow the realised interval.
"""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import yaml

from dea_ros.cli import program
from dea_ros.errors import PlanningError, ProtocolError
from dea_ros.identify.pipeline import identify
from dea_ros.identify.planning import (CandidateRecord, ExperimentPlan, PlanLimits, PlannedRecord,
                                       candidate_information, candidate_records, first_fit_from_file,
                                       first_fit_from_result, plan_experiments, plan_protocol, sine_record_cost,
                                       step_rest_s)
from dea_ros.identify.protocols import Protocol, load_protocol
from dea_ros.identify.report.parameters_file import write_parameters
from dea_ros.identify.synth import synthesize_experiments

from .conftest import NOISE_M, PAPER_FREQUENCIES_HZ, SOFTENING

LIMITS = PlanLimits(measure_s=2.0, settle_s=8.0, step_pre_s=0.2, step_hold_s=4.0, offsets=False,
                    static_fractions=(), n_frequencies=16)
BUDGET_S = 40.0


@pytest.fixture(scope="module")
def first(tmp_path_factory):
    exp = synthesize_experiments(SOFTENING, NOISE_M, seed=3, sine_frequencies_Hz=PAPER_FREQUENCIES_HZ,
                                 series_frequencies_Hz=())
    res = identify(exp, evaluate_fit=False)
    path = write_parameters(res, tmp_path_factory.mktemp("plan") / "params.yaml")
    fit = first_fit_from_result(res)
    info, notes = candidate_information(fit, candidate_records(fit.parameters, LIMITS), LIMITS)
    return {"exp": exp, "res": res, "path": path, "fit": fit, "info": info, "notes": notes}


def _eta1(stats):
    i = stats.names.index("eta1_Pa_s")
    return stats.relative_ci[i], stats.ci_low[i], stats.ci_high[i]


def test_params_yaml_carries_the_information_and_the_predicted_widths_are_the_reported_ones(first):
    from_file = first_fit_from_file(first["path"])
    assert from_file.names == first["fit"].names
    np.testing.assert_allclose(from_file.information, first["fit"].information, rtol=1e-12)
    plan = plan_experiments(from_file, BUDGET_S, LIMITS, information=first["info"])
    st = first["res"].statistics
    for name in ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"):
        lo, hi = from_file.reported_ci95[name]
        value = st.values[st.names.index(name)]
        reported = (hi - lo) / 2 / value if name == "eps_r" else math.log(hi / lo) / 2   # ln scale for k1, eta
        assert plan.widths_before[name] == pytest.approx(reported, rel=0.05), name


def test_the_planner_picks_what_shrinks_eta1_and_a_refit_with_the_picks_confirms_it(first):
    fit, res = first["fit"], first["res"]
    i1, i2 = res.statistics.names.index("eta1_Pa_s"), res.statistics.names.index("eta2_Pa_s")
    assert res.statistics.correlation[i1, i2] > 0.7          # the trade-off the plan has to break
    plan = plan_experiments(fit, BUDGET_S, LIMITS, information=first["info"])
    assert plan.picks and plan.total_s <= BUDGET_S
    assert plan.widths_after["eta1_Pa_s"] < 0.8 * plan.widths_before["eta1_Pa_s"]
    # better than the same time spent on randomly drawn candidates (the greedy picks' criterion is lower)
    rng = np.random.default_rng(0)
    picked = sum(math.log(plan.widths_after[n]) for n in plan.targets)
    for _ in range(6):
        order = rng.permutation(len(first["info"]))
        chosen, spent = [], 0.0
        for k in order:
            c, g = first["info"][k]
            if spent + c.duration_s <= BUDGET_S:
                chosen.append((c, g))
                spent += c.duration_s
        rand = plan_experiments(fit, BUDGET_S, LIMITS, information=chosen, max_records=len(chosen))
        assert picked <= sum(math.log(rand.widths_after[n]) for n in rand.targets) + 1e-9
    # the realised gain: the picks' data by forward integration, identified with the first pass
    sines, steps = [], []
    for k, pick in enumerate(plan.picks):
        r = pick.record
        extra = synthesize_experiments(SOFTENING, NOISE_M, seed=100 + k, series_frequencies_Hz=(),
                                       sine_frequencies_Hz=(r.frequency_Hz,) if r.kind == "sine" else (),
                                       sine_amplitude_V=r.amplitude_V if r.kind == "sine" else 2500.0,
                                       step_voltage_V=r.final_V if r.kind == "step" else 2200.0,
                                       step_time_s=LIMITS.step_pre_s, step_duration_s=LIMITS.step_hold_s)
        if r.kind == "sine":
            sines.append(dataclasses.replace(extra.sines[0], source=f"planned {k}"))
        else:
            steps.append(dataclasses.replace(extra.steps[0], source=f"planned {k}"))
    exp = first["exp"]
    both = dataclasses.replace(exp, sines=list(exp.sines) + sines, steps=list(exp.steps) + steps)
    again = identify(both, evaluate_fit=False)
    before, after = _eta1(res.statistics)[0], _eta1(again.statistics)
    assert after[0] < 0.85 * before, (before, after[0])
    assert after[1] <= SOFTENING.eta1_Pa_s <= after[2]


def test_a_budget_shorter_than_every_settled_record_says_so(first):
    plan = plan_experiments(first["fit"], 5.0, LIMITS, information=first["info"])
    assert not plan.picks and any("longer than the 5 s budget" in n for n in plan.notes), plan.notes


def _plan_of(records) -> ExperimentPlan:
    picks = [PlannedRecord(r, 1.0, 1.0 / r.duration_s, {}) for r in records]
    return ExperimentPlan(("eta1_Pa_s",), ("eta1_Pa_s",), "widths", 100.0, {}, {}, {}, {}, picks, len(picks))


def test_planned_records_become_protocol_segments_the_node_runs():
    params = SOFTENING
    rest = step_rest_s(params)
    recs = [c for c in candidate_records(params, PlanLimits(other_masses_kg=(0.005,)))]
    sine = next(c for c in recs if c.kind == "sine" and c.offset_V == 0 and c.amplitude_V == 2500)
    offset = next(c for c in recs if c.kind == "sine" and c.offset_V > 0)
    step = next(c for c in recs if c.kind == "step")
    static = next(c for c in recs if c.kind == "static" and c.mass_kg == params.mass_kg)
    other = next(c for c in recs if c.kind == "static" and c.mass_kg == 0.005)
    assert step.duration_s == pytest.approx(rest + 0.5 + 5.0)
    base = Protocol.from_dict({"protocol": {"name": "p", "mass_kg": params.mass_kg,
                                            "segments": [{"kind": "rest", "hold_s": 1}]}})
    # a second 2500 V sine held 30 s longer (a record near a fold): its own segment, so the first is not
    # held as long (before session 22 the shape's group held every frequency for the longest hold)
    near = next(c for c in recs if c.kind == "sine" and c.offset_V == 0 and c.amplitude_V == 2500
                and c.frequency_Hz > sine.frequency_Hz)
    limits = PlanLimits()
    near = dataclasses.replace(near, settle_s=near.settle_s + 30.0,
                               duration_s=sine_record_cost(limits, near.frequency_Hz, near.settle_s + 30.0)[0])
    proto = plan_protocol(_plan_of([sine, offset, step, static, other, near]), base)
    segs = proto.schedule(max_voltage_V=2500.0)
    kinds = [s.kind for s in segs]
    assert kinds.count("sine") == 3 and kinds.count("step") == 1 and kinds.count("static") == 1
    # the step starts from rest: a rest segment of step_rest_s just before it
    k = kinds.index("step")
    assert kinds[k - 1] == "rest" and segs[k - 1].end_s - segs[k - 1].start_s == pytest.approx(rest)
    sines = {(s.info["frequency_Hz"], s.info["amplitude_V"], s.info["offset_V"]) for s in segs if s.kind == "sine"}
    assert sines == {(sine.frequency_Hz, 2500.0, 0.0), (offset.frequency_Hz, offset.amplitude_V, offset.offset_V),
                     (near.frequency_Hz, 2500.0, 0.0)}
    # the other mass cannot be run by the node: left out; the rest costs what the plan said (+ the final rest)
    total = sine.duration_s + offset.duration_s + step.duration_s + static.duration_s + near.duration_s + 1.0
    assert proto.duration_s() == pytest.approx(total, abs=1e-6)
    with pytest.raises(PlanningError, match="mass"):
        plan_protocol(_plan_of([other]), base)


def test_candidates_respect_the_amplifier_limits():
    lim = PlanLimits(max_voltage_V=2000.0, slew_rate_V_per_s=2.0e5, max_frequency_Hz=30.0)
    recs = candidate_records(SOFTENING, lim)
    sines = [c for c in recs if c.kind == "sine"]
    assert sines and all(c.amplitude_V + c.offset_V <= 2000.0 + 1e-9 for c in sines)
    assert all(c.amplitude_V * 2 * math.pi * c.frequency_Hz <= 2.0e5 for c in sines)
    assert {c.frequency_Hz for c in sines if c.amplitude_V == 2000.0} != {c.frequency_Hz for c in sines}  # slew
    assert all(c.final_V <= 2000.0 for c in recs if c.kind == "step")
    assert not [c for c in recs if c.kind == "static" and c.mass_kg != SOFTENING.mass_kg]   # no other mass given
    with pytest.raises(PlanningError, match="max_voltage_V"):
        PlanLimits(max_voltage_V=-1.0)


def test_protocol_adaptive_field_and_yaml_round_trip(tmp_path):
    seg = [{"kind": "sine", "amplitude_V": 2000, "frequencies_Hz": [5.0], "settle_s": 1, "measure_s": 1}]
    p = Protocol.from_dict({"protocol": {"name": "a", "adaptive": True, "adaptive_budget_s": 30, "segments": seg}})
    assert p.adaptive and p.adaptive_budget_s == 30.0
    again = load_protocol(p.write_yaml(tmp_path / "a.yaml"))
    assert (again.adaptive, again.adaptive_budget_s, again.raw_segments) == (True, 30.0, p.raw_segments)
    assert not load_protocol("paper").adaptive
    with pytest.raises(ProtocolError, match="adaptive"):
        Protocol.from_dict({"protocol": {"adaptive": "yes", "segments": seg}})
    with pytest.raises(ProtocolError, match="adaptive_budget_s"):
        Protocol.from_dict({"protocol": {"adaptive": True, "adaptive_budget_s": -5, "segments": seg}})
    with pytest.raises(ProtocolError, match="unknown field"):
        Protocol.from_dict({"protocol": {"adaptiv": True, "segments": seg}})


def test_cli_plan_text_json_protocol_and_exit_codes(first, tmp_path, capsys):
    path = str(first["path"])
    assert program.main(["plan", "--from", path, "--budget-s", "25", "--fmax", "30"]) == 0
    out = capsys.readouterr().out
    assert "expected 95 % interval half-widths" in out and "eta1_Pa_s" in out and "correlation eta1/eta2" in out
    assert "slowest time constant" in out and "held" in out
    proto_out = tmp_path / "second.yaml"
    assert program.main(["plan", "--from", path, "--budget-s", "25", "--fmax", "30", "--json",
                         "--protocol-out", str(proto_out)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["picks"] and data["total_s"] <= 25.0
    # each pick's hold before its measurement, from the slowest time constant of the fitted membrane
    assert all(p["settle_s"] >= 2.0 and p["time_constant_s"] > 0 for p in data["picks"])
    assert data["relative_ci95_after"]["eta1_Pa_s"] < data["relative_ci95_before"]["eta1_Pa_s"]
    assert load_protocol(proto_out).schedule(max_voltage_V=2500.0)
    # a first fit that doubts itself: the plan says so
    doubt = yaml.safe_load(first["path"].read_text())
    doubt["identification"]["fisher_information"]["first_fit_warnings"] = ["joint refinement: eta2_Pa_s ended at "
                                                                           "the search bound"]
    doubtful = tmp_path / "doubtful.yaml"
    doubtful.write_text(yaml.safe_dump(doubt))
    assert program.main(["plan", "--from", str(doubtful), "--budget-s", "12", "--fmax", "30"]) == 0
    assert "note: the first fit warned: joint refinement: eta2_Pa_s ended at the search bound" in \
        capsys.readouterr().out
    # bad input: exit 2 with a message naming the problem
    no_info = tmp_path / "plain.yaml"
    no_info.write_text(yaml.safe_dump({"membrane": SOFTENING.to_dict()}))
    bad = yaml.safe_load(first["path"].read_text())
    bad["identification"]["fisher_information"]["matrix"] = [[1.0, 2.0]]
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text(yaml.safe_dump(bad))
    for argv, message in ((["--from", str(no_info)], "fisher_information"),
                          (["--from", str(malformed)], "matrix"),
                          (["--from", str(tmp_path / "missing.yaml")], "no such file"),
                          (["--from", path, "--budget-s", "-3"], "--budget-s"),
                          (["--from", path, "--max-voltage", "nan"], "--max-voltage"),
                          (["--from", path, "--fmin", "50"], "min_frequency_Hz"),
                          (["--from", path, "--targets", "nonsense"], "target"),
                          (["--from", path, "--max-correlation", "1.5"], "--max-correlation"),
                          (["--from", path, "--max-correlation", "0"], "--max-correlation")):
        assert program.main(["plan"] + argv) == 2, argv
        assert message in capsys.readouterr().err, argv


def _trade_off_case(fit):
    """A known answer: eta1 and eta2 correlated 0.99 (information in relative units), and two 10 s records --
    one pins k1 (a large decrease of the widths criterion, the eta1/eta2 correlation untouched), the other adds
    a little information along eta1 - eta2 (a smaller decrease, the correlation 0.99 -> 0.895)."""
    names, n = fit.names, len(fit.names)
    i1, i2, ik = names.index("eta1_Pa_s"), names.index("eta2_Pa_s"), names.index("k1_Pa")
    rel = np.eye(n) * 1e4
    rel[np.ix_([i1, i2], [i1, i2])] = 1e4 * np.array([[1.0, 0.99], [0.99, 1.0]])
    scale = fit.scale()
    crafted = dataclasses.replace(fit, information=rel / np.outer(scale, scale))
    pins_k1 = np.zeros((n, n))
    pins_k1[ik, ik] = 1e8
    v = np.zeros(n)
    v[i1], v[i2] = 1.0, -1.0
    separates = 0.05 * 1e4 * np.outer(v, v)
    k1_record = CandidateRecord("step", 10.0, fit.parameters.mass_kg, final_V=2500.0)
    sine = CandidateRecord("sine", 10.0, fit.parameters.mass_kg, 1.0, 1250.0, 1250.0, measured_samples=2000)
    return crafted, [(k1_record, pins_k1), (sine, separates)]


def test_the_correlation_goal_comes_first_then_the_widths(first):
    fit, info = _trade_off_case(first["fit"])
    # the widths alone: the k1 record (its decrease per second is larger); the goal first: the separating sine
    plain = plan_experiments(fit, 10.0, LIMITS, information=info, max_correlation=None)
    assert [p.record.kind for p in plain.picks] == ["step"]
    assert abs(plain.correlation_after["eta1/eta2"]) > 0.98
    goal = plan_experiments(fit, 10.0, LIMITS, information=info)
    assert [p.record.kind for p in goal.picks] == ["sine"] and goal.max_correlation == 0.9
    assert abs(goal.correlation_after["eta1/eta2"]) == pytest.approx(0.94 / 1.05, rel=1e-6)
    assert goal.to_dict()["max_correlation"] == 0.9
    # with time for both: the goal, then the widths (the k1 record keeps the correlation at the goal)
    both = plan_experiments(fit, 20.0, LIMITS, information=info)
    assert [p.record.kind for p in both.picks] == ["sine", "step"]
    assert all(p.criterion_decrease > 0 for p in both.picks)
    # nothing lowers it: the plan says so and plans for the widths
    alone = plan_experiments(fit, 20.0, LIMITS, information=info[:1])
    assert [p.record.kind for p in alone.picks] == ["step"]
    assert any("lowers the eta1_Pa_s/eta2_Pa_s correlation below 0.9" in n for n in alone.notes), alone.notes
    with pytest.raises(PlanningError, match="max_correlation"):
        plan_experiments(fit, 20.0, LIMITS, information=info, max_correlation=1.2)


def test_an_unknown_direction_is_bounded_not_infinite(first):
    fit = first["fit"]
    blind = dataclasses.replace(fit, information=np.zeros_like(fit.information))
    c = CandidateRecord("sine", 10.0, fit.parameters.mass_kg, 5.0, 2500.0, measured_samples=2000)
    plan = plan_experiments(blind, 20.0, LIMITS, information=[(c, np.zeros_like(fit.information))])
    assert not plan.picks and all(math.isinf(w) for w in plan.widths_before.values())


def test_a_record_measured_before_it_settles_counts_with_its_leftover_transient_and_an_unstable_one_not_at_all(first):
    """Session 20: records at the resonance peak held at the cap (0.2-0.4 um of the transient left) were planned
    with the information of settled ones and biased the second pass. The leftover is an uncertainty of the
    record (in quadrature with the noise); where the membrane is not stable the record is no candidate."""
    fit = first["fit"]
    sine = next(c for c, _g in first["info"] if c.kind == "sine" and not c.transient_left_m)
    settled = dict(candidate_information(fit, [sine], LIMITS)[0])[sine]
    sigma = fit.laser_noise_m / math.sqrt(sine.measured_samples)
    left = 3.0 * sigma
    capped = dataclasses.replace(sine, transient_left_m=left)
    (rec, g), = candidate_information(fit, [capped], LIMITS)[0]
    np.testing.assert_allclose(g, settled * sigma ** 2 / (sigma ** 2 + left ** 2), rtol=1e-9,
                               atol=1e-12 * abs(settled).max())
    unstable = dataclasses.replace(sine, transient_left_m=math.inf)
    info, notes = candidate_information(fit, [unstable], LIMITS)
    assert info == [] and "not stable" in notes[0]
    # candidate_records states the leftover where a short cap bites (held 0.3 s: the creep, 0.13 s, is not over)
    short = dataclasses.replace(LIMITS, settle_s=0.3, max_settle_s=0.3, step_rest_min_s=0.3)
    cands = candidate_records(fit.parameters, short)
    assert any(c.transient_left_m > 0 for c in cands if c.kind == "step")
    assert all((c.transient_left_m > 0) == bool(c.settle_warning) for c in cands)
