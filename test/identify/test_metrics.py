"""Metrics: error indices (Tables III-IV), static errors, parameter statistics."""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.identify.metrics import (
    parameter_statistics,
    resonance_peak_Hz,
    static_errors_um,
    step_error_indices,
)


def test_step_indices_in_table_iii_units():
    t = np.linspace(0.0, 4.0, 4001)
    measured = np.zeros_like(t)
    simulated = np.full_like(t, 2e-6)  # a constant 2 um = 0.002 mm error
    idx = step_error_indices(t, measured, simulated, step_time_s=1.0)
    assert idx["IAE_mm_s"] == pytest.approx(0.002 * 4.0)
    assert idx["ISE_mm2_s"] == pytest.approx(0.002**2 * 4.0)
    assert idx["ITAE_mm_s2"] == pytest.approx(0.002 * 3.0**2 / 2)  # weight t - t_step after the step
    assert idx["rms_error_um"] == pytest.approx(2.0) and idx["max_error_um"] == pytest.approx(2.0)


def test_resonance_peak_parabola():
    f = np.array([8.0, 8.5, 9.0, 9.5, 10.0])
    r = -(f - 9.2) ** 2 + 5.0
    assert resonance_peak_Hz(f, r) == pytest.approx(9.2)
    assert resonance_peak_Hz([1.0, 2.0], [3.0, 1.0]) == 1.0  # edge: no refinement
    assert resonance_peak_Hz(f[::-1], r[::-1]) == pytest.approx(9.2)  # order does not matter


def test_static_errors():
    e = static_errors_um([1e-3, 2e-3], [1e-3 + 1e-6, 2e-3 - 3e-6])
    assert e["max_error_um"] == pytest.approx(3.0)
    assert e["rms_error_um"] == pytest.approx(np.sqrt(5.0))


def test_statistics_of_a_linear_regression_match_the_textbook():
    rng = np.random.default_rng(0)
    x = np.linspace(0, 1, 50)
    a = np.column_stack([np.ones_like(x), x])
    y = a @ [2.0, 3.0] + rng.normal(0, 0.1, x.size)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = a @ coef - y
    st = parameter_statistics(a, res, ("a", "b"), coef)
    s2 = res @ res / 48
    cov = s2 * np.linalg.inv(a.T @ a)
    np.testing.assert_allclose(st.std_error, np.sqrt(np.diag(cov)), rtol=1e-10)
    assert st.correlation[0, 1] == pytest.approx(cov[0, 1] / np.sqrt(cov[0, 0] * cov[1, 1]), rel=1e-8)
    from scipy import stats

    t = stats.t.ppf(0.975, 48)
    np.testing.assert_allclose(st.ci_high - coef, t * np.sqrt(np.diag(cov)), rtol=1e-10)
    np.testing.assert_allclose(coef - st.ci_low, t * np.sqrt(np.diag(cov)), rtol=1e-10)
    assert st.rank == 2 and not st.warnings


def test_log_parameters_give_asymmetric_intervals():
    jac = np.array([[1.0], [1.0], [1.0], [1.0]])
    st = parameter_statistics(jac, np.array([0.1, -0.1, 0.1, -0.1]), ("k",), [10.0], log_parameters=True)
    assert st.ci_low[0] * st.ci_high[0] == pytest.approx(100.0)  # symmetric in ln k
    assert st.std_error[0] == pytest.approx(10.0 * np.sqrt(0.04 / 3 / 4))


def test_rank_deficiency_and_correlation_warnings():
    x = np.linspace(0, 1, 20)
    jac = np.column_stack([x, 2 * x, np.ones_like(x)])  # columns 0 and 1 are the same direction
    st = parameter_statistics(jac, np.full(20, 0.01), ("p", "q", "c"), [1.0, 1.0, 1.0])
    assert st.rank == 2
    assert not np.isfinite(st.std_error[0]) and not np.isfinite(st.std_error[1])
    assert np.isfinite(st.std_error[2])
    assert any("cannot be pinned down" in w for w in st.warnings)
    assert any("p and q trade off" in w for w in st.warnings)
    jac2 = np.column_stack([x, x + 1e-3 * x**2])
    st2 = parameter_statistics(jac2, np.full(20, 0.01), ("p", "q"), [1.0, 1.0], correlation_limit=0.99)
    assert st2.rank == 2 and abs(st2.correlation[0, 1]) > 0.99
    assert any("poorly determined" in w for w in st2.warnings)
