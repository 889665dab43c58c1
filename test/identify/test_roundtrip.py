"""Round trips: synthetic data from each preset (1 um laser noise) -> identify -> compare with the truth.

The data come from forward integration (shooting on DOP853, adaptive integration of the step);
the fit uses harmonic balance and the collocation solver. Default: the paper's stage 1 (paper
weights, 0.2/8.3/11.2/40 Hz) then the joint refinement of every identifiable parameter with
statistical weights on all records.
"""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers.sweep import frequency_sweep
from dea_ros.solvers.inputs import SinePeriodic

NOISE_M = 1e-6  # the laser noise of the conftest data sets


def _rel(a, b):
    return abs(a / b - 1.0)


def _true_peak(params):
    return frequency_sweep(params, SinePeriodic(2500.0, 1.0), np.linspace(8.0, 11.0, 31), n_harmonics=8,
                           branch_switching=False, realised=False).resonance_peak()


@pytest.mark.parametrize("name", ["LP1", "A1", "A2"])
def test_default_identification_recovers_the_parameters(identified, name):
    truth = preset(name)
    res = identified(name, "paper")
    p = res.parameters
    assert res.joint is not None
    assert _rel(p.relative_permittivity, truth.relative_permittivity) < 0.005
    assert _rel(p.k1_Pa, truth.k1_Pa) < 0.01
    assert _rel(p.eta1_Pa_s, truth.eta1_Pa_s) < 0.06
    assert _rel(p.eta2_Pa_s, truth.eta2_Pa_s) < (0.2 if name == "A1" else 0.01)  # A1: eta1/eta2 trade off
    for field in ("prestretch", "thickness_m", "plate_radius_m", "electrode_width_m", "mass_kg"):
        assert getattr(p, field) == getattr(truth, field)  # geometry copied from the manifest
    u = np.linspace(0.0, 2500.0, 26)
    curve = static_equilibrium(p, u).displacement_m - static_equilibrium(truth, u).displacement_m
    assert np.max(np.abs(curve)) < 0.5e-6   # static points: 0.1 um noise
    assert _true_peak(p)["frequency_Hz"] == pytest.approx(_true_peak(truth)["frequency_Hz"], rel=1e-3)
    # the intervals are honest: the truth within 2 CI half-widths of every parameter
    st = res.statistics
    for n in ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"):
        i = st.names.index(n)
        true = truth.relative_permittivity if n == "eps_r" else getattr(truth, n)
        assert abs(st.values[i] - true) < 2.0 * (st.ci_high[i] - st.ci_low[i]) / 2


@pytest.mark.parametrize("name", ["LP1", "A2"])
def test_default_fit_reproduces_the_data_within_the_noise(identified, name):
    ev = identified(name, "paper").evaluation.to_dict()
    step = ev["steps"][0]
    assert step["rms_error_um"] / (NOISE_M * 1e6) == pytest.approx(1.0, abs=0.05)
    assert ev["static"]["rms_error_um"] < 0.25  # points are 100-sample means: 0.1 um noise
    fr = ev["frequency_response"][0]
    assert fr["compared"] == fr["frequencies"]  # every record of the presets is periodic at T/2
    if identified(name, "paper").curvature_identified:
        assert fr["normalised_rms_error"] < 2.0  # within the stated uncertainty of the RMS values
    assert ev["transient_solver_max_difference_um"] < 0.005


def test_two_stage_option_is_the_papers_procedure(identified):
    res = identified("A2", "two-stage")
    assert res.joint is None and res.options["refine"] == "none"
    assert res.statistics.names == ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
    assert res.curvature_identified is False
    assert _rel(res.parameters.k1_Pa, preset("A2").k1_Pa) < 0.01


def test_noise_weights_in_stage_one(identified):
    res = identified("A2", "noise")
    truth = preset("A2")
    p = res.parameters
    assert _rel(p.k1_Pa, truth.k1_Pa) < 0.01 and _rel(p.eta2_Pa_s, truth.eta2_Pa_s) < 0.01
    assert res.options["weights"] == "noise"
    # no warning recommends what is already in use
    assert not any("--weights noise" in w or "--fit-frequencies all" in w for w in res.warnings)


def test_warnings_name_the_known_identifiability_limits(identified):
    res = identified("A1", "paper")
    text = "\n".join(res.warnings)
    assert "beta_i and gamma_i are not individually identifiable" in text
    stats = res.statistics
    assert stats.names[:2] == ("sigma_h(1)_Pa", "sigma_h'(1)_Pa")
    assert np.all(stats.ci_low < stats.values) and np.all(stats.values < stats.ci_high)
    if not res.curvature_identified:
        assert "sigma_h''(1)" in text and "not identified" in text


def test_identification_time(identified):
    res = identified("LP1", "paper")
    t = res.timings_s
    assert t["dynamic_fit"] < t["identification_total"]
    assert res.dynamic.time_frequency_s < t["dynamic_fit"]
