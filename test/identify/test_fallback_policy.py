"""Where forward integration replaces a failed harmonic balance in the dynamic fit (issue 21, session 16).

On slow-creep membranes unlike the presets (F04, F13 of the coverage family) harmonic balance fails at one
frequency for many trial parameters (past a fold of the branch), and every such evaluation integrated to the
periodic state, (1 + parameters) times: one identification took 25 min (F04) or did not end in 20 min (F13).
Now the initial guess's profile scan skips a creep time whose start fails (integrating only if every one
does), and a local fit rejects a trial point where harmonic balance fails (least_squares shrinks its step,
as in the joint refinement); starts and the result integrate.

Here harmonic balance is made to fail on purpose (the objective's solve raises) where the creep time
eta1/k1 exceeds a threshold, and forward integration is counted: the fit ends with every integration
accounted for by the rule, the skipped creep times named, and the parameters those of the data.
"""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.errors import HarmonicBalanceError
from dea_ros.identify.dynamic_fit import fit_dynamic, initial_guess, select_fit_frequencies
from dea_ros.identify.dynamic_objective import DynamicObjective
from dea_ros.model import preset


def _failing_above(monkeypatch, creep_limit_s: float, frequency_Hz: float):
    """Harmonic balance fails at ``frequency_Hz`` wherever eta1/k1 > creep_limit_s; forward integration
    is replaced by the harmonic-balance value (the same number, cheaply) and counted."""
    calls = {"integrations": 0, "failures": 0}
    solve, integrate = DynamicObjective._hbm_solve, DynamicObjective._hbm_solve

    def failing_solve(self, params, k, point):
        if point.frequency_Hz == frequency_Hz and params.eta1_Pa_s / params.k1_Pa > creep_limit_s:
            calls["failures"] += 1
            raise HarmonicBalanceError(f"made to fail at {frequency_Hz} Hz")
        return solve(self, params, k, point)

    def counted_integration(self, params, point):
        calls["integrations"] += 1
        d0 = self.rest(params, point.mass_kg)[0]
        k = self.points.index(point)
        return integrate(self, params, k, point).displacement_rms(d0)

    monkeypatch.setattr(DynamicObjective, "_hbm_solve", failing_solve)
    monkeypatch.setattr(DynamicObjective, "_integration_rms", counted_integration)
    return calls


def test_the_scan_skips_creep_times_whose_start_fails_and_the_fit_bounds_its_integrations(synthetic, monkeypatch):
    _folder, exp = synthetic("A2")
    truth = preset("A2")
    tau_true = truth.eta1_Pa_s / truth.k1_Pa
    points = select_fit_frequencies(exp.sines)
    frequency = max(points, key=lambda p: p.measured_rms_m).frequency_Hz   # (the resonance: where folds are)
    calls = _failing_above(monkeypatch, 3.0 * tau_true, frequency)
    objective = DynamicObjective(truth, exp.steps, points)
    starts, info = initial_guess(objective)
    assert info["scan_skipped_tau_s"] and min(info["scan_skipped_tau_s"]) > 3.0 * tau_true
    assert calls["integrations"] == 0 and calls["failures"] > 0   # the scan integrates nowhere

    calls["integrations"] = calls["failures"] = 0
    result = fit_dynamic(truth, exp.steps, exp.sines)
    assert calls["integrations"] == 0 and calls["failures"] > 0   # trial points there rejected, not integrated
    assert result.parameters.k1_Pa == pytest.approx(truth.k1_Pa, rel=0.01)
    assert result.parameters.eta2_Pa_s == pytest.approx(truth.eta2_Pa_s, rel=0.02)


def _failing_everywhere(synthetic, monkeypatch):
    """(truth, objective, calls): A2's synthetic data, harmonic balance failing at every creep time."""
    _folder, exp = synthetic("A2")
    truth = preset("A2")
    points = select_fit_frequencies(exp.sines)
    calls = _failing_above(monkeypatch, 0.0, points[-1].frequency_Hz)
    return truth, DynamicObjective(truth, exp.steps, points), calls


def test_when_every_start_fails_the_scan_integrates(synthetic, monkeypatch):
    _truth, objective, calls = _failing_everywhere(synthetic, monkeypatch)
    starts, info = initial_guess(objective)
    assert starts and "scan_skipped_tau_s" not in info and calls["integrations"] > 0
    assert np.all(np.isfinite(starts[0]))


def test_a_trial_point_where_harmonic_balance_fails_is_rejected_and_counted(synthetic, monkeypatch):
    truth, objective, calls = _failing_everywhere(synthetic, monkeypatch)
    theta = np.log([truth.k1_Pa, truth.eta1_Pa_s, truth.eta2_Pa_s])
    with objective.integration_fallback(False):
        residuals = objective.trial_residuals(theta)
    assert not np.any(np.isfinite(residuals)) and calls["integrations"] == 0
    assert objective.rejected_trials == 1 and objective.integrate_failures      # restored after the block
    assert np.all(np.isfinite(objective.residuals(theta))) and calls["integrations"] > 0   # a start integrates
