"""The fast collocation transient solver: accuracy against adaptive integration, exact sensitivities."""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.model import preset
from dea_ros.solvers.inputs import SampledVoltage
from dea_ros.solvers.integrate import simulate
from dea_ros.solvers.transient import TransientCollocation, TransientError, record_substeps, simulate_collocation

T = np.arange(3201) / 1000.0            # 3.2 s at 1 kHz
U = np.where(T < 0.2 - 1e-12, 0.0, 2200.0)  # 2.2 kV step at 0.2 s (zero-order hold)


@pytest.mark.parametrize("name", ["LP1", "A1", "A2"])
def test_step_matches_adaptive_integration_within_5_nm(name):
    # Measured: max |collocation - DOP853(rtol 1e-11)| = 0.97 nm (LP1), 1.2 nm (A1, A2) over 4.2 s.
    params = preset(name)
    ref = simulate(params, SampledVoltage(T, U, hold="zoh"), T[-1], t_eval=T, rtol=1e-11, atol_scale=1e-11)
    sol = simulate_collocation(params, T, U)
    assert np.max(np.abs(sol.displacement_m - ref.displacement_m)) < 5e-9
    assert sol.state.shape == (3, T.size)


def test_a_record_sampled_slowly_for_its_membrane_gets_a_finer_grid():
    """A step record at 250 Hz of a membrane whose linear oscillation is at 19 Hz (A2's; omega h = 0.48 with
    one interval per sample): 0.19 um RMS from converged integration, which biased eta1 by +2 % in
    identification from 250 Hz records; :meth:`TransientCollocation.for_record` splits each sample interval
    (omega h <= MAX_OMEGA_H) and is within the noise's hundredth."""
    params = preset("A2")
    t = np.arange(1376) / 250.0
    u = np.where(t < 0.5 - 1e-12, 0.0, 2200.0)
    ref = simulate(params, SampledVoltage(t, u, hold="zoh"), t[-1], t_eval=t, rtol=1e-11, atol_scale=1e-11)
    coarse = TransientCollocation(t, u).solve(params)
    fitted = TransientCollocation.for_record(params, t, u)
    assert fitted.substeps == record_substeps(params, t, u) == 2
    rms = [np.sqrt(np.mean((s.displacement_m - ref.displacement_m) ** 2)) for s in (coarse, fitted.solve(params))]
    assert rms[0] > 0.1e-6 and rms[1] < 0.02e-6
    assert record_substeps(params, T, U) == 1               # 1 kHz: one interval per sample, as before


def test_linear_hold_and_substeps_converge_to_the_adaptive_solution():
    params = preset("A2")
    u = np.clip((T - 0.2) / 0.05, 0.0, 1.0) * 2200.0  # a 50 ms ramp
    ref = simulate(params, SampledVoltage(T, u, hold="linear"), T[-1], t_eval=T, rtol=1e-11, atol_scale=1e-11)
    coarse = simulate_collocation(params, T, u, hold="linear")
    fine = simulate_collocation(params, T, u, hold="linear", substeps=2)
    err_coarse = np.max(np.abs(coarse.displacement_m - ref.displacement_m))
    err_fine = np.max(np.abs(fine.displacement_m - ref.displacement_m))
    assert err_coarse < 5e-9
    assert err_fine < err_coarse / 4  # 4th-order method: halving h gains ~16x


def test_sensitivities_match_finite_differences():
    params = preset("LP1").replace(eta1_Pa_s=2e7)  # a relaxation time inside the record
    t, u = T[:1500], U[:1500]
    sol = TransientCollocation(t, u).solve(params, sensitivities=True)
    for k, field in enumerate(("k1_Pa", "eta1_Pa_s", "eta2_Pa_s")):
        h = 1e-6
        plus = TransientCollocation(t, u).solve(params.replace(**{field: getattr(params, field) * np.exp(h)}))
        fd = (plus.displacement_m - sol.displacement_m) / h
        scale = np.max(np.abs(fd))
        assert scale > 0
        assert np.max(np.abs(fd - sol.displacement_sensitivity_m[k])) < 1e-4 * scale + 1e-13


def test_stress_direction_sensitivity_includes_the_moving_rest_state():
    params = preset("A1")
    direction = np.array([1.0, 0.5, 0.2, -0.3, 0.1, 0.05])  # arbitrary (beta, gamma) direction
    t, u = T[:800], U[:800]
    sol = TransientCollocation(t, u).solve(params, sensitivities=True, stress_directions=direction[None, :])
    c = 50.0  # Pa per unit of the direction
    bg = np.r_[params.beta_Pa, params.gamma_Pa] + c * direction
    moved = TransientCollocation(t, u).solve(params.replace(beta_Pa=tuple(bg[:3]), gamma_Pa=tuple(bg[3:])))
    fd = (moved.displacement_m - sol.displacement_m) / c
    assert abs(fd[0]) > 0  # the rest position moves too
    assert np.max(np.abs(fd - sol.displacement_sensitivity_m[3])) < 1e-3 * np.max(np.abs(fd))


def test_warm_start_with_predictor_needs_few_newton_iterations():
    params = preset("A2")
    solver = TransientCollocation(T, U)
    solver.solve(params, sensitivities=True)
    again = solver.solve(params.replace(k1_Pa=params.k1_Pa * 1.01), sensitivities=True)
    assert again.newton_iterations <= 2
    cold = TransientCollocation(T, U).solve(params.replace(k1_Pa=params.k1_Pa * 1.01))
    assert np.max(np.abs(again.displacement_m - cold.displacement_m)) < 1e-11


def test_bad_inputs_are_rejected_with_the_field_named():
    with pytest.raises(ValueError, match="lengths differ"):
        TransientCollocation(T, U[:-1])
    with pytest.raises(ValueError, match="strictly increasing"):
        TransientCollocation(T[::-1], U)
    with pytest.raises(ValueError, match="hold"):
        TransientCollocation(T, U, hold="cubic")
    with pytest.raises(ValueError, match="voltage_V"):
        TransientCollocation(T, U * np.nan)


def test_unbounded_response_raises_instead_of_returning_garbage():
    # 6 kV with a 3 g mass on LP1 exceeds the electromechanical limit: no bounded trajectory.
    params = preset("LP1")
    u = np.where(T[:400] < 0.1, 0.0, 6000.0)
    with pytest.raises(TransientError):
        TransientCollocation(T[:400], u, max_iter=8).solve(params)
