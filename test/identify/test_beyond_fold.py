"""A record beyond the model's fold (issue 21): left out for a round, fitted once the model reaches it.

F07 of the family benchmark (bench/bench_coverage_family.py): softening at stretch 1 (sigma_h'(1) < 0),
creep time 13 s, resonance 12.0 Hz, identified from 17 sine frequencies placed on its resonance. Its
record at 12 Hz is on the upper branch just before the response jumps down (1.73 mm RMS); the
two-stage result (within 1 % of the truth) has its fold a little below 12 Hz, so the model there has
only the lower branch (0.36 mm). Fitted with that branch, the record's residual (thousands of standard
errors) dragged the joint refinement to eps_r +38 %, eta1 -98 %, with intervals excluding the truth.
Data by converged forward integration (the step from rest, DOP853; the sine records from the converged
periodic orbit), 1 um laser noise, the ILD1320 quantisation, a random start phase, two noise seeds;
never the harmonic balance the fit uses.
"""
from __future__ import annotations

import pytest

from dea_ros.identify.classification import leave_out_unreproduced
from dea_ros.identify.pipeline import identify
from dea_ros.identify.synth import synthesize_experiments
from dea_ros.sim.plant import LASER_QUANTISATION_M
from fakes.membranes import F07

#: the paper's four fit frequencies and 13 on F07's own resonance (bench_coverage_family.seventeen)
FREQUENCIES_HZ = (0.2, 3.0, 6.0, 8.3, 8.4, 10.2, 10.65, 11.1, 11.2, 11.55, 12.0, 12.45, 12.9, 13.35, 13.8, 18.0, 40.0)


@pytest.mark.parametrize("seed", [1, 2])
def test_the_record_beyond_the_fold_does_not_drag_the_fit(seed):
    exp = synthesize_experiments(F07, 1e-6, seed=seed, sine_frequencies_Hz=FREQUENCIES_HZ, series_frequencies_Hz=(),
                                 quantisation_m=LASER_QUANTISATION_M, random_start_phase=True)
    res = identify(exp, evaluate_fit=False)
    assert res.joint is not None
    st = res.statistics
    truth = {"eps_r": F07.relative_permittivity, "k1_Pa": F07.k1_Pa, "eta1_Pa_s": F07.eta1_Pa_s,
             "eta2_Pa_s": F07.eta2_Pa_s}
    # eta1: a creep time of 13 s seen by a 4 s step (its standard error ~0.6 %); the dragged fit was -98 %
    tolerance = {"eps_r": 0.005, "k1_Pa": 0.005, "eta1_Pa_s": 0.03, "eta2_Pa_s": 0.005}
    for name, true_value in truth.items():
        i = st.names.index(name)
        assert abs(st.values[i] / true_value - 1.0) < tolerance[name], (name, st.values[i], true_value)
        # a 95 % interval misses the truth in 1 of 20 cases: the test asks for the truth within 4 standard
        # errors (the dragged fit was hundreds off); the share that holds is the coverage benchmark's
        z = (st.values[i] - true_value) / st.std_error[i]
        assert abs(z) < 4.0, (name, st.values[i], st.std_error[i], true_value)
    # the final round fits the 12 Hz record on the branch it is on
    at_12 = next(c for c in res.classification if abs(c["frequency_Hz"] - 12.0) < 1e-9)
    assert at_12["used"] == "periodic"
    assert abs(at_12["fitted_model_rms_m"] / at_12["measured_rms_m"] - 1.0) < 0.05, at_12


def _entry(f_hz: float, measured_m: float, model_m: float) -> dict:
    return {"frequency_Hz": f_hz, "measured_rms_m": measured_m, "used": "periodic", "branch": "T/2",
            "fitted_model_rms_m": model_m, "guess": None}


def test_an_isolated_unreproduced_record_is_left_out_with_the_reason():
    entries = [_entry(f, 1e-4, 1.05e-4) for f in range(1, 9)] + [_entry(12.0, 1.73e-3, 0.36e-3)]
    leave_out_unreproduced(entries)
    assert [e["used"] for e in entries[:8]] == ["periodic"] * 8
    assert entries[8]["used"] == "left out" and "beyond a fold" in entries[8]["reason"]
    assert "1730 um measured" in entries[8]["reason"] and "guess" not in entries[8]


def test_when_many_records_are_off_the_parameters_are_and_all_stay_in():
    entries = [_entry(f, 1e-4, 1.05e-4) for f in range(1, 6)] + [_entry(f, 1e-4, 0.3e-4) for f in range(6, 9)]
    leave_out_unreproduced(entries)
    assert all(e["used"] == "periodic" for e in entries)
