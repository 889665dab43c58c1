"""Harmonic balance: spectral operators, agreement with integration, mousai and the linearised model."""
import numpy as np
import pytest

from dea_ros.model import DEAModel, preset, static_equilibrium
from dea_ros.errors import HarmonicBalanceError
from dea_ros.solvers.collocation import (
    CollocationSystem,
    fourier_differentiation_matrix,
    model_setup,
    periodic_interpolation_matrix,
)
from dea_ros.solvers.floquet import classify_stability, floquet_multipliers
from dea_ros.solvers.newton import solve_native, solve_native_batch
from dea_ros.solvers.inputs import SampledPeriodic, SinePeriodic
from dea_ros.solvers.mousai_backend import mousai_available, solve_mousai
from dea_ros.solvers.steady_state import integrate_to_steady_state, solve_periodic


def test_spectral_differentiation_and_interpolation_are_exact_for_trig_polynomials():
    m = 11
    theta = 2 * np.pi * np.arange(m) / m
    x = 0.3 + np.sin(2 * theta) - 0.5 * np.cos(5 * theta)
    dx = 2 * np.cos(2 * theta) + 2.5 * np.sin(5 * theta)
    np.testing.assert_allclose(fourier_differentiation_matrix(m) @ x, dx, atol=1e-12)
    phi = np.linspace(0, 7, 40)
    exact = 0.3 + np.sin(2 * phi) - 0.5 * np.cos(5 * phi)
    np.testing.assert_allclose(periodic_interpolation_matrix(m, phi) @ x, exact, atol=1e-12)
    with pytest.raises(ValueError):
        fourier_differentiation_matrix(4)


@pytest.fixture(scope="module")
def a2():
    return preset("A2")


@pytest.mark.parametrize("f_Hz", [3.0, 9.3, 15.0])  # 9.3 Hz: on the resonance peak
def test_native_hbm_matches_forward_integration(a2, f_Hz):
    inp = SinePeriodic(2500.0, f_Hz)
    d0 = static_equilibrium(a2, 0.0).displacement_m
    hbm = solve_native(a2, inp, n_harmonics=10)
    fi = integrate_to_steady_state(a2, inp, tol=1e-8)
    rel = abs(hbm.displacement_rms(d0) - fi.displacement_rms(d0)) / fi.displacement_rms(d0)
    assert rel < 1e-5
    assert hbm.stable
    # The whole waveform, not only its RMS.
    t = np.linspace(0, 1 / f_Hz, 50, endpoint=False)
    fi_wave = fi.evaluate(t)[0]
    assert np.max(np.abs(hbm.evaluate(t)[0] - fi_wave)) < 1e-4 * np.ptp(fi_wave) + 1e-9


needs_mousai = pytest.mark.skipif(not mousai_available(), reason="mousai not installed (optional extra [mousai])")


@needs_mousai
@pytest.mark.parametrize("f_Hz", [2.0, 12.0])
def test_native_and_mousai_agree(a2, f_Hz):
    inp = SinePeriodic(2500.0, f_Hz)
    native = solve_native(a2, inp, n_harmonics=8)
    paper = solve_mousai(a2, inp, n_harmonics=8)
    assert paper.method == "mousai" and paper.period_divisor == 1
    assert native.displacement_rms() == pytest.approx(paper.displacement_rms(), rel=1e-5)
    assert native.mean_displacement_m == pytest.approx(paper.mean_displacement_m, rel=1e-8)


def test_small_amplitude_response_matches_linear_transfer_function(a2):
    """u = U0 + dU sin(wt), dU << U0: first harmonic of d = |G(jw)| dU with G from the linearisation."""
    u0, du = 2000.0, 4.0
    model = DEAModel.from_parameters(a2)
    x_eq = static_equilibrium(a2, u0).state
    a = model.jacobian(x_eq, u0)
    b = model.input_jacobian(x_eq, u0)
    for f in (1.0, 8.0, 9.6, 14.0):
        w = 2 * np.pi * f
        g = np.linalg.solve(1j * w * np.eye(3) - a, b)[0]
        sol = solve_native(a2, SinePeriodic(du, f, offset_V=u0), n_harmonics=4)
        assert sol.period_divisor == 1  # offset: no half-period symmetry
        first = sol.harmonic_amplitudes_m()[1]
        assert first == pytest.approx(abs(g) * du, rel=2e-3)


def test_symmetry_reduction_gives_the_same_solution(a2):
    inp = SinePeriodic(2500.0, 6.0)
    half = solve_native(a2, inp, n_harmonics=6)
    full = solve_native(a2, inp, n_harmonics=12, use_symmetry=False)
    assert half.period_divisor == 2 and full.period_divisor == 1
    assert half.displacement_rms() == pytest.approx(full.displacement_rms(), rel=1e-9)
    # odd harmonics of the excitation vanish in the full-period solution
    amps = full.harmonic_amplitudes_m()
    assert np.max(amps[1::2]) < 1e-9 * np.max(amps[2::2])


def test_sampled_period_input_equals_the_sine(a2):
    f = 4.0
    phase = 2 * np.pi * np.arange(64) / 64
    sampled = SampledPeriodic(2500.0 * np.sin(phase), f)
    a = solve_native(a2, sampled, n_harmonics=8)
    b = solve_native(a2, SinePeriodic(2500.0, f), n_harmonics=8)
    assert a.displacement_rms() == pytest.approx(b.displacement_rms(), rel=1e-9)


def test_sampled_period_symmetry_is_computed_once_and_right():
    """u2_half_periodic of a sampled period is cached per instance (asked for at every solve): the same
    answer as the generic test, for a symmetric sine, one with an offset, and a new frequency's copy."""
    theta = 2 * np.pi * np.arange(96) / 96
    sym = SampledPeriodic(1500.0 * np.sin(theta) + 40.0 * np.sin(3 * theta), 7.0)
    offset = SampledPeriodic(200.0 + 1500.0 * np.sin(theta), 7.0)
    for inp, expected in ((sym, True), (offset, False), (offset.with_frequency(9.0), False)):
        generic = super(SampledPeriodic, inp).u2_half_periodic()
        assert generic is expected
        assert inp.u2_half_periodic() is expected and inp.u2_half_periodic() is expected
        assert inp.u2_half_periodic(samples=31) is expected


def test_floquet_multipliers_converge_and_match_linear_limit(a2):
    """Tiny amplitude: multipliers -> eigenvalues of exp(A T) of the linearisation."""
    u0, f = 1500.0, 3.0
    sol = solve_native(a2, SinePeriodic(1e-3, f, offset_V=u0), n_harmonics=3)
    model = DEAModel.from_parameters(a2)
    a = model.jacobian(static_equilibrium(a2, u0).state, u0)
    expected = np.sort(np.abs(np.exp(np.linalg.eigvals(a) / f)))
    np.testing.assert_allclose(np.sort(np.abs(sol.multipliers)), expected, rtol=1e-6)
    s = model_setup(a2)
    coarse = floquet_multipliers(s.model, sol, steps=400, scale=s.scale)
    fine = floquet_multipliers(s.model, sol, steps=3000, scale=s.scale)
    np.testing.assert_allclose(np.abs(coarse), np.abs(fine), rtol=1e-7)


def test_stability_classification():
    assert classify_stability([0.5, 0.2 + 0.1j, 0.2 - 0.1j]) == "stable"
    assert classify_stability([1.2, 0.5, 0.1]) == "unstable (saddle)"
    assert classify_stability([1.2, 1.1, 0.1]) == "unstable (real pair)"
    assert classify_stability([-1.05, 0.5, 0.1]) == "unstable (period-doubling)"
    assert classify_stability([1.01 + 0.1j, 1.01 - 0.1j, 0.3]) == "unstable (torus)"
    assert classify_stability(None) == "unknown"


def test_newton_failure_is_reported(a2):
    s = model_setup(a2)
    system = CollocationSystem(s.model, 5, s.scale, s.omega_n)
    z0 = np.zeros(15)  # the flat membrane: far from the solution
    with pytest.raises(HarmonicBalanceError, match="Newton iterations"):
        system.newton(z0, 2 * np.pi * 18.0, np.full(5, 2500.0**2), max_iter=2)


def test_cold_solve_on_a_resonance_fold_still_converges():
    """LP1 at 9.3 Hz: direct Newton fails from the linear guess; the solver continues in frequency."""
    sol = solve_native(preset("LP1"), SinePeriodic(2500.0, 9.3), n_harmonics=8)
    assert sol.residual < 1e-8
    fi_rms = 605.045e-6  # checked against integrate_to_steady_state (slow for LP1: 400 s simulated)
    assert sol.displacement_rms() == pytest.approx(fi_rms, rel=2e-3)


def test_front_end_methods_and_errors(a2):
    inp = SinePeriodic(2500.0, 5.0)
    for method in ("native", "mousai") if mousai_available() else ("native",):  # mousai: optional extra
        assert solve_periodic(a2, inp, method=method, n_harmonics=4).method == method
    with pytest.raises(ValueError, match="method"):
        solve_periodic(a2, inp, method="shooting")
    with pytest.raises(ValueError, match="n_harmonics"):
        solve_native(a2, inp, n_harmonics=0)
    with pytest.raises(ValueError, match="frequency_Hz"):
        SinePeriodic(2500.0, 0.0)


def test_batch_solver_equals_single_solves(a2):
    inputs = [SinePeriodic(2500.0, f) for f in (0.5, 4.0, 9.0, 14.0, 19.0)]
    batch = solve_native_batch(a2, inputs, n_harmonics=6, stability=True)
    for inp, b in zip(inputs, batch):
        single = solve_native(a2, inp, n_harmonics=6)
        assert b.displacement_rms() == pytest.approx(single.displacement_rms(), rel=1e-9)
        assert b.stability == single.stability
    with pytest.raises(ValueError, match="symmetric"):
        solve_native_batch(a2, [SinePeriodic(2500.0, 1.0), SinePeriodic(100.0, 1.0, offset_V=2000.0)])


def test_auto_harmonics_reach_spectral_convergence(a2):
    """N = 2 near resonance is under-resolved (a solution of the truncated equations only, several
    per cent off); the truncation indicator shows it and 'auto' fixes it."""
    coarse = solve_native(a2, SinePeriodic(2500.0, 9.5), n_harmonics=2)
    fine = solve_native(a2, SinePeriodic(2500.0, 9.5), n_harmonics=16)
    assert coarse.truncation_ratio > 1e-2
    assert abs(coarse.displacement_rms() / fine.displacement_rms() - 1.0) > 0.05
    auto = solve_native(a2, SinePeriodic(2500.0, 9.5), n_harmonics="auto")
    assert auto.truncation_ratio < 1e-4 and auto.n_harmonics >= 4
    assert auto.displacement_rms() == pytest.approx(fine.displacement_rms(), rel=1e-4)
    with pytest.raises(ValueError, match="auto"):
        solve_native(a2, SinePeriodic(2500.0, 9.5), n_harmonics="many")
