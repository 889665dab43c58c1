"""Round trips: synthetic data from each preset (1 um laser noise) -> identify -> compare with the truth.

Tolerances (measured over 5 noise seeds, then given ~2-3x margin; the data sets here use seed 7):

default (paper weights w_step = 6.6e6, w_hbm = 0.1e6, fit at 0.2, 8.3, 11.2, 40 Hz)
  eps_r <= 0.1 % (tol 0.5 %), k1 <= 0.25 % (tol 1 %), eta1 <= 2 % (tol 6 %),
  eta2 <= 0.15 % for LP1/A2 (tol 1 %) but <= 7.3 % for A1 (tol 20 %: eta1 and eta2 trade off,
  correlation > 0.99, which the fit reports), resonance peak within 0.012 Hz of the true model's
  (tol 0.05 Hz), static curve within 0.1 um (tol 0.3 um); the step is reproduced within the noise
  (RMS error / sigma = 0.994-1.008, tol +-5 %), the static points within their 0.1 um noise (RMS
  < 0.16 um, tol 0.25 um); the frequency response within 1.6 % of the RMS (tol 2.5 %): the curvature
  sigma_h''(1) is not identified with these weights and matters at the resonance amplitude.
weights="noise", all frequencies (sigma_h''(1) identified)
  every RMS value within 0.33 um / 0.13 % (tol 0.6 um, 0.3 %); resonance peak within 0.02 Hz;
  eta2 of A1 within 21 % (tol 35 %, flagged), the others as above.
"""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.identify.metrics import resonance_peak_Hz
from dea_ros.identify.pipeline import frequency_sweep
from dea_ros.model import preset, static_equilibrium

NOISE_M = 1e-6  # the laser noise of the conftest data sets

TOL_ETA2 = {"LP1": 0.01, "A1": 0.20, "A2": 0.01}


def _rel(a, b):
    return abs(a / b - 1.0)


def _true_peak(params):
    f = np.linspace(8.0, 11.0, 301)
    return resonance_peak_Hz(f, frequency_sweep(params, 2500.0, f)[0])


@pytest.mark.parametrize("name", ["LP1", "A1", "A2"])
def test_default_identification_recovers_the_parameters(identified, name):
    truth = preset(name)
    res = identified(name, "paper")
    p = res.parameters
    assert _rel(p.relative_permittivity, truth.relative_permittivity) < 0.005
    assert _rel(p.k1_Pa, truth.k1_Pa) < 0.01
    assert _rel(p.eta1_Pa_s, truth.eta1_Pa_s) < 0.06
    assert _rel(p.eta2_Pa_s, truth.eta2_Pa_s) < TOL_ETA2[name]
    # geometry copied from the manifest
    for field in ("prestretch", "thickness_m", "plate_radius_m", "electrode_width_m", "mass_kg"):
        assert getattr(p, field) == getattr(truth, field)
    u = np.linspace(0.0, 2500.0, 26)
    curve = static_equilibrium(p, u).displacement_m - static_equilibrium(truth, u).displacement_m
    assert np.max(np.abs(curve)) < 0.3e-6
    assert abs(_true_peak(p) - _true_peak(truth)) < 0.05


@pytest.mark.parametrize("name", ["LP1", "A1", "A2"])
def test_default_fit_reproduces_the_data_within_the_noise(identified, name):
    ev = identified(name, "paper").evaluation
    step = ev["steps"][0]
    assert step["rms_error_um"] / (NOISE_M * 1e6) == pytest.approx(1.0, abs=0.05)
    assert ev["static"]["rms_error_um"] < 0.25  # points are 100-sample means: 0.1 um noise
    assert ev["frequency_response"][0]["max_relative_error_percent"] < 2.5
    assert ev["transient_solver_max_difference_um"] < 0.005


@pytest.mark.parametrize("name", ["LP1", "A2"])
def test_noise_weights_identify_the_curvature_and_fit_every_frequency(identified, name):
    truth = preset(name)
    res = identified(name, "noise")
    assert res.dynamic.curvature_fitted
    fr = res.evaluation["frequency_response"][0]
    assert fr["max_error_um"] < 0.6 and fr["max_relative_error_percent"] < 0.3
    p = res.parameters
    assert _rel(p.k1_Pa, truth.k1_Pa) < 0.01 and _rel(p.eta2_Pa_s, truth.eta2_Pa_s) < 0.01
    assert _rel(p.eta1_Pa_s, truth.eta1_Pa_s) < 0.08
    assert abs(_true_peak(p) - _true_peak(truth)) < 0.05
    k = res.dynamic.statistics.names.index("sigma_h''(1)_Pa")
    assert res.dynamic.statistics.relative_ci[k] < 0.5  # determined, unlike with the paper's weights


def test_warnings_name_the_known_identifiability_limits(identified):
    res = identified("A1", "paper")
    text = "\n".join(res.warnings)
    assert "beta_i and gamma_i are not individually identifiable" in text
    assert "sigma_h''(1)" in text and "not identified" in text
    assert "eta1_Pa_s and eta2_Pa_s trade off" in text  # A1's fast relaxation
    stats = res.dynamic.statistics
    assert stats.names == ("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")
    assert np.all(stats.ci_low < stats.values) and np.all(stats.values < stats.ci_high)
    # the truth lies within a few CI half-widths (the intervals are honest, not decorative)
    truth = preset("A1")
    for n, lo, hi, v in zip(stats.names, stats.ci_low, stats.ci_high, stats.values):
        assert abs(getattr(truth, n) - v) < 3 * (hi - lo) / 2


def test_identification_is_fast(identified):
    res = identified("LP1", "paper")
    t = res.timings_s
    assert t["dynamic_fit"] < 5.0 and t["identification_total"] < 8.0
    assert res.dynamic.time_frequency_s < t["dynamic_fit"]
