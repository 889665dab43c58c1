"""Uncertainty of the identified model: the Monte Carlo band on the frequency response and the peak.

Synthetic round trip: data of the A2 membrane (1 um noise) are identified; the 95 % band drawn from
the fit's covariance must contain the response of the true parameters (computed independently by a
continuation sweep with stability), and the truth's resonance peak must lie in the peak's interval.
Negative control: the band of a model with a wrong permittivity (2 %) misses the truth near resonance.
"""
from dataclasses import replace

import numpy as np
import pytest

from dea_ros.identify import write_report
from dea_ros.identify.static_fit import EXTENDED_COMBINATION_MATRIX
from dea_ros.identify.uncertainty import response_band, sample_parameters
from dea_ros.model import preset
from dea_ros.solvers import SinePeriodic, frequency_sweep

AMPLITUDE_V = 2500.0


@pytest.fixture(scope="module")
def fit(identified):
    return identified("A2")


@pytest.fixture(scope="module")
def grid():
    return np.union1d(np.linspace(2.0, 20.0, 10), np.linspace(8.8, 10.4, 12))


@pytest.fixture(scope="module")
def band(fit, grid):
    return response_band(fit.parameters, fit.statistics, AMPLITUDE_V, grid, n_samples=24, seed=3)


def test_samples_follow_the_fit_covariance(fit):
    stats = fit.statistics
    cov = stats.covariance()
    assert cov is not None and np.all(np.linalg.eigvalsh(cov) > -1e-12 * np.max(np.abs(cov)))
    members = sample_parameters(fit.parameters, stats, 3000, seed=1)
    assert all(m is not None for m in members)
    stress = ("sigma_h(1)_Pa", "sigma_h'(1)_Pa", "sigma_h''(1)_Pa", "sigma_h'''(1)_Pa")
    coords = []
    for m in members:   # back to the fit's coordinates (eq. 10 combinations, ln of the viscous parameters)
        c = dict(zip(stress, EXTENDED_COMBINATION_MATRIX @ np.r_[m.beta_Pa, m.gamma_Pa]))
        c.update({"eps_r": m.relative_permittivity, "k1_Pa": np.log(m.k1_Pa), "eta1_Pa_s": np.log(m.eta1_Pa_s),
                  "eta2_Pa_s": np.log(m.eta2_Pa_s)})
        coords.append([c[n] for n in stats.names])
    emp = np.cov(np.array(coords).T)
    sd = np.sqrt(np.diag(cov))
    assert np.allclose(np.sqrt(np.diag(emp)), sd, rtol=0.1)
    assert np.allclose(emp / np.outer(sd, sd), cov / np.outer(sd, sd), atol=0.08)


def test_band_contains_the_truth_response_and_peak(band, grid):
    truth = frequency_sweep(preset("A2"), SinePeriodic(AMPLITUDE_V, 2.0), grid)
    d_true = truth.realised_d_rms_m
    assert band.samples == 24 and band.n_failed == 0
    assert np.all(band.lower_m <= band.nominal_m * (1 + 1e-9))
    assert np.all(band.upper_m >= band.nominal_m * (1 - 1e-9))
    inside = band.contains(grid, d_true, slack=0.05)
    assert inside.mean() >= 0.9, grid[~inside]
    lo, hi = band.peak_frequency_ci_Hz
    f_true = truth.resonance_peak(True)["frequency_Hz"]
    width = hi - lo
    assert lo - 0.1 * width <= f_true <= hi + 0.1 * width
    assert width < 0.01 * f_true          # an informative interval: the data pin the peak down


def test_band_of_a_wrong_model_misses_the_truth(fit, grid):
    wrong = fit.parameters.replace(relative_permittivity=fit.parameters.relative_permittivity * 1.02)
    b = response_band(wrong, fit.statistics, AMPLITUDE_V, grid, n_samples=8, seed=3)
    truth = frequency_sweep(preset("A2"), SinePeriodic(AMPLITUDE_V, 2.0), grid).realised_d_rms_m
    near = (grid > 8.8) & (grid < 10.4)
    assert not np.all(b.contains(grid, truth)[near])
    f_true = frequency_sweep(preset("A2"), SinePeriodic(AMPLITUDE_V, 8.8), np.linspace(8.8, 10.4, 5)) \
        .resonance_peak(True)["frequency_Hz"]
    lo, hi = b.peak_frequency_ci_Hz
    assert not lo <= f_true <= hi


def test_report_draws_the_band(fit, band, tmp_path):
    paths = write_report(replace(fit, uncertainty=[band]), tmp_path)
    text = (tmp_path / "report.md").read_text()
    assert "## Uncertainty of the frequency response" in text and "24 samples" in text
    assert paths["frequency.png"].stat().st_size > 1000
    assert "uncertainty" in (tmp_path / "result.json").read_text()
