"""Dynamic fit (eqs. 22-24): objective, harmonic-balance sensitivities, frequency selection, options."""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.identify.dynamic_fit import DynamicFitError, fit_dynamic, select_fit_frequencies
from dea_ros.identify.dynamic_objective import DynamicObjective, resolve_weights
from dea_ros.identify.experiments import SineData
from dea_ros.identify.frequency_points import FrequencyPoint
from dea_ros.identify.static_fit import OgdenRepresentation
from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers.newton import solve_native
from dea_ros.solvers.inputs import SinePeriodic


def _theta(p):
    return np.log([p.k1_Pa, p.eta1_Pa_s, p.eta2_Pa_s])


def test_select_frequencies_defaults_to_the_papers_set_in_the_data():
    sine = SineData([0.2, 2.0, 8.3, 9.0, 11.2, 40.0], [2500.0] * 6, [1e-4] * 6, mass_kg=0.003)
    assert [p.frequency_Hz for p in select_fit_frequencies([sine])] == [0.2, 8.3, 11.2, 40.0]
    assert len(select_fit_frequencies([sine], "all")) == 6
    assert [p.frequency_Hz for p in select_fit_frequencies([sine], [9.0, 2.0])] == [2.0, 9.0]
    other = SineData([1.0, 3.0], [2500.0] * 2, [1e-4] * 2, mass_kg=0.003)
    assert [p.frequency_Hz for p in select_fit_frequencies([other])] == [1.0, 3.0]  # none of the paper's
    with pytest.raises(DynamicFitError, match="7 Hz is not in the sine data; available: 0.2, 2, 8.3"):
        select_fit_frequencies([sine], [7.0])


def test_objective_is_eq22_with_the_papers_weights(synthetic):
    _folder, exp = synthetic("A2")
    truth = preset("A2")
    points = select_fit_frequencies(exp.sines)
    obj = DynamicObjective(truth, exp.steps, points)
    res, jac, details = obj.evaluate(_theta(truth))
    step = exp.steps[0]
    e = details["step_simulated_m"][0] - step.displacement_m
    rms_meas = np.array([p.measured_rms_m for p in points])
    j22 = 6.6e6 * np.sum(e**2) + 0.1e6 * np.sum((details["simulated_rms_m"] - rms_meas) ** 2)
    assert obj.cost(_theta(truth)) == pytest.approx(j22, rel=1e-12)
    assert res.size == step.n_samples + len(points) and jac.shape == (res.size, 3)
    # at the true parameters the step error is the laser noise
    assert np.sqrt(np.mean(e**2)) == pytest.approx(1e-6, rel=0.05)


def test_harmonic_balance_rms_gradient_matches_finite_differences():
    truth = preset("LP1")
    rep = OgdenRepresentation(truth.prestretch, 3, np.r_[truth.beta_Pa, truth.gamma_Pa])
    point = FrequencyPoint(8.3, 2500.0, 4e-4, truth.mass_kg, "test", 3e-8)
    obj = DynamicObjective(truth, [], [point], curvature_direction=rep._gain[:, 2])
    theta = np.r_[_theta(truth), 0.0]
    res, jac, _ = obj.evaluate(theta)
    for j, h in enumerate((1e-3, 1e-3, 1e-3, 1e-2)):  # central differences
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (obj.evaluate(tp, jacobian=False)[0][0] - obj.evaluate(tm, jacobian=False)[0][0]) / (2 * h)
        assert jac[0, j] == pytest.approx(fd, rel=1e-4)


def test_harmonic_balance_and_integration_agree_on_the_objective():
    truth = preset("A2")
    point = FrequencyPoint(8.3, 2500.0, 2.2e-4, truth.mass_kg, "test", 3e-8)
    hbm = DynamicObjective(truth, [], [point], frequency_method="hbm")
    fi = DynamicObjective(truth, [], [point], frequency_method="integration")
    r_hbm = hbm.evaluate(_theta(truth), jacobian=False)[2]["simulated_rms_m"][0]
    r_fi = fi.evaluate(_theta(truth), jacobian=False)[2]["simulated_rms_m"][0]
    assert r_hbm == pytest.approx(r_fi, abs=1e-9)  # < 1 nm
    d0 = static_equilibrium(truth, 0.0).displacement_m
    direct = solve_native(truth, SinePeriodic(2500.0, 8.3), 8).displacement_rms(d0)
    assert r_hbm == pytest.approx(direct, rel=1e-9)
    assert fi.time_frequency_s > 20 * hbm.time_frequency_s


def test_noise_weights_need_the_uncertainties():
    sine = SineData([8.3], [2500.0], [2e-4], mass_kg=0.003)
    with pytest.raises(DynamicFitError, match="d_rms_std_m"):
        resolve_weights("noise", [], select_fit_frequencies([sine]), 1e-6)
    with pytest.raises(ValueError, match="unknown key"):
        resolve_weights({"steps": 1.0}, [], [], None)
    kind, sq_steps, sq_points = resolve_weights({"hbm": 4.0}, [], select_fit_frequencies([sine]))
    assert kind[0] == "custom" and sq_points[0] == pytest.approx(2.0)


def test_fit_needs_data():
    with pytest.raises(DynamicFitError, match="at least one step or sine"):
        fit_dynamic(preset("A1"), [], [])
    sine = SineData([8.3, 11.2], [2500.0] * 2, [2e-4, 1e-4], mass_kg=0.003)
    with pytest.raises(DynamicFitError, match=">= 3 sine frequencies"):
        fit_dynamic(preset("A1"), [], [sine])


def test_paper_nelder_mead_option_runs_with_its_tolerances(synthetic):
    _folder, exp = synthetic("A2")
    truth = preset("A2")
    paper = fit_dynamic(truth, exp.steps, exp.sines, method="paper")
    lsq = fit_dynamic(truth, exp.steps, exp.sines)
    assert paper.method == "paper" and not paper.curvature_fitted
    assert lsq.cost <= paper.cost * (1 + 1e-9)  # same objective, the Jacobian-based optimizer is not worse
    assert lsq.parameters.k1_Pa == pytest.approx(truth.k1_Pa, rel=0.01)


def test_progress_reports_every_new_evaluation(synthetic):
    _folder, exp = synthetic("A2")
    events = []
    res = fit_dynamic(preset("A2"), exp.steps, exp.sines, progress=events.append)
    assert len(events) == res.n_evaluations
    assert [e["evaluation"] for e in events] == list(range(1, res.n_evaluations + 1))
    assert min(e["cost"] for e in events) == pytest.approx(res.cost, rel=1e-6)
