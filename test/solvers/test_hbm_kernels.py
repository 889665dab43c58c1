"""Compiled harmonic-balance kernels (optional numba) against the numpy path and forward integration.

The solvers run the compiled kernels when numba is installed; the numpy path is the reference
written with whole-array operations. Both must give the same solutions, iterations, Floquet
multipliers and sweeps (to rounding), and both must match converged forward integration.
Without numba the comparisons skip and the numpy path is checked against integration alone.
"""
import numpy as np
import pytest

from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers import hbm_kernels
from dea_ros.solvers.continuation import frequency_sweep
from dea_ros.solvers.harmonic_balance import (
    floquet_multipliers_batch,
    model_setup,
    monodromy_matrix,
    solve_native,
    solve_native_batch,
    sorted_eigenvalues,
)
from dea_ros.solvers.inputs import SinePeriodic
from dea_ros.solvers.realised import realised_response
from dea_ros.solvers.steady_state import integrate_to_steady_state

needs_numba = pytest.mark.skipif(not hbm_kernels.available(), reason="numba not installed (optional extra [fast])")
PATHS = [False, pytest.param(True, marks=needs_numba)]


@pytest.fixture(scope="module")
def a2():
    return preset("A2")


@pytest.fixture
def path():
    """Restore the kernels' switch after a test that flips it."""
    old = hbm_kernels.enabled()
    yield hbm_kernels.set_enabled
    hbm_kernels.set_enabled(old)


def both(path, fn):
    """fn() on the numpy path and on the compiled one."""
    path(False)
    ref = fn()
    path(True)
    return ref, fn()


def scaled_diff(a2, x, y):
    return float(np.max(np.abs(np.asarray(x) - np.asarray(y)) / model_setup(a2).scale[:, None]))


@pytest.mark.parametrize("compiled", PATHS)
def test_both_paths_match_converged_forward_integration(a2, path, compiled):
    path(compiled)
    inp = SinePeriodic(2500.0, 3.0)      # (on the peak: test_harmonic_balance, on the default path)
    d0 = static_equilibrium(a2, 0.0).displacement_m
    hbm = solve_native(a2, inp, n_harmonics=8)
    batch = solve_native_batch(a2, [inp, SinePeriodic(2500.0, 4.0)], n_harmonics=8, stability=True)
    fi = integrate_to_steady_state(a2, inp, tol=1e-8)
    ref = fi.displacement_rms(d0)
    assert abs(hbm.displacement_rms(d0) - ref) / ref < 1e-5
    assert abs(batch[0].displacement_rms(d0) - ref) / ref < 1e-5
    assert hbm.stable and batch[0].stable and batch[1].stable


@needs_numba
@pytest.mark.parametrize("n", [2, 4, 8])
def test_single_solves_are_the_same_on_both_paths(a2, path, n):
    for f in (0.1, 3.0, 9.5, 17.0):
        ref, fast = both(path, lambda: solve_native(a2, SinePeriodic(2500.0, f), n, stability=True))
        assert fast.iterations == ref.iterations
        assert scaled_diff(a2, fast.state, ref.state) < 1e-10
        np.testing.assert_allclose(fast.multipliers, ref.multipliers, rtol=0, atol=1e-10)
        assert fast.stability == ref.stability


@needs_numba
def test_batched_solves_and_stability_are_the_same_on_both_paths(a2, path):
    inputs = [SinePeriodic(2500.0, f) for f in np.linspace(0.1, 20.0, 17)]
    ref, fast = both(path, lambda: solve_native_batch(a2, inputs, 4, stability=True))
    for r, s in zip(ref, fast):
        assert s.iterations == r.iterations
        assert scaled_diff(a2, s.state, r.state) < 1e-10
        np.testing.assert_allclose(s.multipliers, r.multipliers, rtol=0, atol=1e-10)
    # with initial guesses, and without the symmetry (full period: the half-period multipliers too)
    guesses = [s.state for s in ref]
    ref_g, fast_g = both(path, lambda: solve_native_batch(a2, inputs[:5], 4, x_guesses=guesses[:5]))
    for r, s in zip(ref_g, fast_g):
        assert scaled_diff(a2, s.state, r.state) < 1e-10
    ref_f, fast_f = both(path, lambda: solve_native_batch(a2, inputs[3:6], 6, use_symmetry=False, stability=True))
    for r, s in zip(ref_f, fast_f):
        np.testing.assert_allclose(s.multipliers, r.multipliers, rtol=0, atol=1e-10)
        assert (s.half_period_multipliers is None) == (r.half_period_multipliers is None)
        if r.half_period_multipliers is not None:
            np.testing.assert_allclose(s.half_period_multipliers, r.half_period_multipliers, rtol=0, atol=1e-10)


@needs_numba
def test_one_batch_of_mixed_waveforms_has_each_items_own_multipliers(a2, path):
    """The batched Floquet step evaluates a waveform once for all items that share it
    (``waveform_key``): items with other amplitudes, offsets or sampled waveforms must still get
    their own input, i.e. the multipliers each item gets alone."""
    from dea_ros.solvers.harmonic_balance import attach_floquet
    from dea_ros.solvers.inputs import SampledPeriodic

    assert SinePeriodic(2500.0, 3.0).waveform_key() == SinePeriodic(2500.0, 7.0).waveform_key()
    assert SinePeriodic(2500.0, 3.0).waveform_key() != SinePeriodic(2000.0, 3.0).waveform_key()
    assert SinePeriodic(2500.0, 3.0).waveform_key() != SinePeriodic(2500.0, 3.0, 300.0).waveform_key()
    theta = 2 * np.pi * np.arange(16) / 16
    inputs = [SinePeriodic(2500.0, 3.0, 400.0), SinePeriodic(1500.0, 3.0, 400.0), SinePeriodic(2500.0, 9.0, 400.0),
              SampledPeriodic(1800.0 + 500.0 * np.sin(theta) + 200.0 * np.cos(2 * theta), 3.0),
              SampledPeriodic(1800.0 + 500.0 * np.sin(theta), 3.0), SinePeriodic(2500.0, 0.2, 400.0)]
    path(True)
    batch = solve_native_batch(a2, inputs, 6, stability=True)
    for sol in batch:
        alone = attach_floquet(model_setup(a2).model, solve_native_batch(a2, [sol.periodic_input], 6)[0],
                               scale=model_setup(a2).scale)
        np.testing.assert_allclose(sol.multipliers, alone.multipliers, rtol=0, atol=1e-12)
    # and the same as the numpy path
    path(False)
    ref = solve_native_batch(a2, inputs, 6, stability=True)
    for r, s in zip(ref, batch):
        np.testing.assert_allclose(s.multipliers, r.multipliers, rtol=0, atol=1e-10)


@needs_numba
def test_coarse_batch_multipliers_are_the_same_on_both_paths(a2, path):
    sols = solve_native_batch(a2, [SinePeriodic(2500.0, f) for f in (0.3, 2.0, 9.4, 14.0)], 6)
    states = np.stack([s.state for s in sols])
    periods = np.array([s.response_period_s for s in sols])
    setup = model_setup(a2)
    ref, fast = both(path, lambda: floquet_multipliers_batch(setup.model, states, periods, SinePeriodic(2500.0, 1.0),
                                                             2, scale=setup.scale))
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-10)


@needs_numba
def test_sweep_with_bands_is_the_same_on_both_paths(a2, path):
    """Folds, bifurcations, bands and the realised (integrated) responses in the torus band."""
    grid = np.linspace(0.1, 20.0, 60)
    ref, fast = both(path, lambda: frequency_sweep(a2, SinePeriodic(2500.0, 0.1), grid, n_harmonics=8))
    assert len(fast.points) == len(ref.points)
    np.testing.assert_allclose(fast.d_rms_m, ref.d_rms_m, rtol=1e-8)
    assert [p.stability for p in fast.points] == [p.stability for p in ref.points]
    np.testing.assert_allclose([f.frequency_Hz for f in fast.folds], [f.frequency_Hz for f in ref.folds], rtol=1e-8)
    assert [(b.kind, round(b.f_start_Hz, 6), round(b.f_end_Hz, 6)) for b in fast.bands] == \
        [(b.kind, round(b.f_start_Hz, 6), round(b.f_end_Hz, 6)) for b in ref.bands]
    assert [(b.kind, round(b.frequency_Hz, 6)) for b in fast.bifurcations] == \
        [(b.kind, round(b.frequency_Hz, 6)) for b in ref.bifurcations]
    np.testing.assert_allclose(fast.realised_d_rms_m, ref.realised_d_rms_m, rtol=1e-8, equal_nan=True)
    assert fast.resonance_peak()["frequency_Hz"] == pytest.approx(ref.resonance_peak()["frequency_Hz"], rel=1e-9)


@pytest.mark.parametrize("compiled", PATHS)
def test_a_branch_longer_than_max_branch_steps_is_an_error_on_both_paths(a2, path, compiled):
    from dea_ros.solvers.continuation import ContinuationError
    path(compiled)
    with pytest.raises(ContinuationError, match="more than 5 branch steps"):
        frequency_sweep(a2, SinePeriodic(2500.0, 0.1), np.linspace(0.1, 20.0, 20), n_harmonics=4,
                        max_branch_steps=5)


@needs_numba
def test_compiled_branch_trace_takes_the_same_steps(a2, path):
    """The compiled continuation loop against the Python one: same steps, grid points, folds, tangents."""
    from dea_ros.solvers.continuation import _Tracer
    from dea_ros.solvers.harmonic_balance import response_layout
    setup = model_setup(a2)
    inp = SinePeriodic(2500.0, 8.0)
    divisor, m = response_layout(inp, 6, True)
    p_grid = np.log(2 * np.pi * np.linspace(8.0, 12.0, 30) * divisor)
    start = solve_native(a2, inp, 6)
    traces = []
    for compiled in (False, True):
        path(compiled)
        tracer = _Tracer(setup, inp, divisor, m, 1e-10, 0.05, p_grid)
        z0 = tracer.system.to_z(start.state)
        tz, tp = tracer.tangent(z0, p_grid[0], np.zeros(tracer.n), 1.0)
        traces.append(tracer.trace(z0, p_grid[0], tz, tp, p_grid[0] - 1.0, p_grid[-1], 2000))
    ref, fast = traces
    assert fast["steps"] == ref["steps"] and fast["fold_steps"] == ref["fold_steps"] and len(ref["fold_steps"]) == 2
    np.testing.assert_allclose(fast["p"], ref["p"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast["z"], ref["z"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast["tp"], ref["tp"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast["h"], ref["h"], rtol=1e-8)
    assert [g[0] for g in fast["grid"]] == [g[0] for g in ref["grid"]]
    assert [g[4] for g in fast["grid"]] == [g[4] for g in ref["grid"]]
    np.testing.assert_allclose([g[1] for g in fast["grid"]], [g[1] for g in ref["grid"]], rtol=0, atol=1e-9)


@needs_numba
def test_realised_integration_is_the_same_on_both_paths(a2, path):
    d0 = static_equilibrium(a2, 0.0).displacement_m
    ref, fast = both(path, lambda: realised_response(a2, SinePeriodic(2500.0, 9.5), [1.2 * d0, 0.0, 0.0], d0,
                                                     settle_periods=20, window_periods=10))
    assert fast.d_rms_m == pytest.approx(ref.d_rms_m, rel=1e-12)
    assert fast.kind == ref.kind
    np.testing.assert_allclose(fast.final_state, ref.final_state, rtol=1e-10)


def test_spectral_radius_of_3x3_matrices_matches_eigenvalues():
    rng = np.random.default_rng(7)
    for _ in range(300):
        a = rng.normal(size=(3, 3)) * rng.choice([1e-2, 1.0, 1e2])
        want = np.max(np.abs(np.linalg.eigvals(a)))
        assert hbm_kernels.spectral_radius3(a) == pytest.approx(want, rel=1e-7)
    assert hbm_kernels.spectral_radius3(np.diag([3.0, -5.0, 1.0])) == pytest.approx(5.0)
    assert hbm_kernels.spectral_radius3(np.array([[0.0, -2.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 1.0]])) == \
        pytest.approx(2.0)


def test_eigenvalues_of_3x3_matrices_match_lapack_and_its_conventions():
    """hbm_kernels.eigenvalues3 (characteristic cubic) against numpy's eigvals (LAPACK dgeev): matrices with
    known spectra unlike monodromies too (a complex pair, three real ones, one tiny multiplier, zero),
    badly scaled by a similarity; dgeev's conventions: real eigenvalues with imaginary part exactly 0,
    pairs exactly conjugate with + imaginary part first, sorted by decreasing modulus."""
    rng = np.random.default_rng(11)
    spectra = []
    for _ in range(200):
        r, th = rng.uniform(0.3, 1.5), rng.uniform(0.05, 3.0)
        spectra.append(("pair", [r * np.exp(1j * th), r * np.exp(-1j * th), rng.uniform(-1.2, 1.2)]))
        spectra.append(("real", list(rng.uniform(-1.5, 1.5, size=3))))
    spectra.append(("tiny", [0.9 * np.exp(0.3j), 0.9 * np.exp(-0.3j), 1e-12]))
    for kind, lam in spectra:
        block = np.diag(np.real(lam)).astype(float)
        if kind != "real":
            block[:2, :2] = [[lam[0].real, lam[0].imag], [-lam[0].imag, lam[0].real]]
        v = rng.normal(size=(3, 3)) @ np.diag([1.0, 10.0, 0.1])
        a = v @ block @ np.linalg.inv(v)
        got = hbm_kernels.eigenvalues3(a[None])[0]
        want = np.linalg.eigvals(a)
        want = want[np.argsort(-np.abs(want), kind="stable")]
        np.testing.assert_allclose(np.abs(got), np.abs(want), rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.sort_complex(got), np.sort_complex(want), rtol=0, atol=1e-8)
        assert np.all(np.diff(np.abs(got)) <= 0.0)
        real = np.abs(np.imag(want)) == 0.0
        assert np.all(np.imag(got)[real] == 0.0)
        if not real.all():
            i = int(np.argmax(np.imag(got)))
            assert np.imag(got[i]) > 0 and np.conj(got[i]) in got and np.nonzero(got == got[i])[0][0] < \
                np.nonzero(got == np.conj(got[i]))[0][0]
    assert np.all(hbm_kernels.eigenvalues3(np.zeros((1, 3, 3))) == 0.0)


@needs_numba
def test_multipliers_of_monodromies_are_the_same_on_both_paths(a2, path):
    """sorted_eigenvalues: the compiled cubic and numpy's eigvals on the monodromies of a resonance sweep
    (where the multipliers cluster and cross the unit circle) within 1e-10."""
    setup = model_setup(a2)
    sols = solve_native_batch(a2, [SinePeriodic(2500.0, f) for f in np.linspace(8.0, 12.0, 41)], 8)
    mats = np.stack([monodromy_matrix(setup.model, sol, scale=setup.scale) for sol in sols])
    ref, fast = both(path, lambda: sorted_eigenvalues(mats))
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize("compiled", PATHS)
def test_a_monodromy_with_nan_is_a_linalg_error_on_both_paths(path, compiled):
    path(compiled)
    with pytest.raises(np.linalg.LinAlgError):
        sorted_eigenvalues(np.full((1, 3, 3), np.nan))


def test_switch_without_numba_says_how_to_get_it(monkeypatch):
    monkeypatch.setattr(hbm_kernels, "numba", None)
    with pytest.raises(RuntimeError, match="pip install numba"):
        hbm_kernels.set_enabled(True)


@needs_numba
def test_a_numba_that_cannot_compile_the_kernels_falls_back_to_numpy(a2, monkeypatch):
    """E.g. an older distribution numba: one warning, then the numpy path with the same answers."""
    ref = solve_native(a2, SinePeriodic(2500.0, 5.0), 4)

    def broken():
        raise TypeError("no implementation for this numba")

    monkeypatch.setattr(hbm_kernels, "_self_check", broken)
    monkeypatch.setattr(hbm_kernels, "_checked", False)
    monkeypatch.setattr(hbm_kernels, "_enabled", True)
    monkeypatch.setattr(hbm_kernels, "_failure", None)
    with pytest.warns(RuntimeWarning, match="using the numpy path"):
        assert not hbm_kernels.enabled()
    sol = solve_native(a2, SinePeriodic(2500.0, 5.0), 4)
    assert scaled_diff(a2, sol.state, ref.state) < 1e-10
    with pytest.raises(RuntimeError, match="could not run"):
        hbm_kernels.set_enabled(True)


def test_model_jacobian_has_the_pattern_the_structured_solve_uses(a2):
    """The reduction of the collocation systems (hbm_kernels._structured_solve) needs eq. 18's pattern:
    d' = v (row 0: 0, 0, 1) and eps1' = a (lambda(d) - 1 - eps1) (row 1: *, -a constant, 0)."""
    from dea_ros.model.dynamics import state_equation

    constants = model_setup(a2).system(5).constants
    rng = np.random.default_rng(3)
    d = rng.uniform(-4e-3, 8e-3, 50)
    eps1 = rng.uniform(-0.05, 0.1, 50)
    v = rng.uniform(-0.5, 0.5, 50)
    u2 = rng.uniform(0.0, 9e6, 50)
    _f, jac = state_equation(constants, d, eps1, v, u2)
    assert np.all(jac[0][0] == 0) and np.all(jac[0][1] == 0) and np.all(jac[0][2] == 1)
    assert np.all(jac[1][2] == 0)
    assert np.ptp(jac[1][1]) == 0 and jac[1][1][0] < 0


@pytest.mark.parametrize("m", [5, 9, 17, 33])
def test_structured_solves_equal_dense_lu(a2, m):
    """Newton steps and the bordered (pseudo-arclength) systems: the reduction to M unknowns gives
    the dense solution to rounding, at random states and frequencies (either path: without numba
    the same code runs as Python)."""
    setup = model_setup(a2)
    sy = setup.system(m)
    rng = np.random.default_rng(m)
    for _ in range(3):
        z = rng.normal(size=3 * m) * 0.3 + np.repeat([1.0, 0.5, 0.0], m)
        u2 = (rng.uniform(500.0, 3000.0) * np.sin(np.linspace(0.0, np.pi, m, endpoint=False))) ** 2
        omega = 2 * np.pi * rng.uniform(0.1, 40.0)
        r, jac, dr = hbm_kernels.collocation_residual_jacobian(z, omega, u2, sy.constants, sy.scale, sy.rate_ref,
                                                               sy.d_theta)
        rhs = rng.normal(size=3 * m)
        x, ok = hbm_kernels.structured_solve(z, omega, u2, sy.constants, sy.scale, sy.rate_ref, sy.d_theta, rhs)
        want = np.linalg.solve(jac, rhs)
        assert ok and np.max(np.abs(x - want)) <= 1e-11 * np.max(np.abs(want))
        tz, tp, wz = rng.normal(size=3 * m), rng.normal(), 1.0 / (3 * m)
        big = np.block([[jac, dr[:, None]], [wz * tz[None, :], np.array([[tp]])]])
        t, ok = hbm_kernels.bordered_tangent(z, np.log(omega), tz, tp, wz, u2, sy.constants, sy.scale, sy.rate_ref,
                                             sy.d_theta)
        want = np.linalg.solve(big, np.eye(3 * m + 1)[-1])
        assert ok and np.max(np.abs(t - want)) <= 1e-11 * np.max(np.abs(want))


def test_bordered_system_stays_regular_at_a_fold(a2):
    """At a fold of the frequency response the collocation Jacobian is singular; the bordered
    system of the continuation is not, and the reduced solve must still give its solution."""
    grid = np.linspace(8.0, 11.0, 30)
    sweep = frequency_sweep(a2, SinePeriodic(2500.0, 8.0), grid, n_harmonics=6, stability=False)
    assert sweep.folds, "A2 at 2.5 kV has folds near resonance"
    fold = sweep.folds[0]
    near = min(sweep.points, key=lambda p: abs(p.frequency_Hz - fold.frequency_Hz))
    sy = model_setup(a2).system(near.solution.n_points)
    u2 = sy_u2(near, sy)
    omega = 2 * np.pi * fold.frequency_Hz * 2          # response frequency of the T/2 orbit
    # Newton at the fold frequency creeps onto the fold point (it cannot converge quadratically there)
    z, _it, _res, _status = hbm_kernels.newton(sy.to_z(near.solution.state), omega, u2, sy.constants, sy.scale,
                                               sy.rate_ref, sy.d_theta, 1e-12, 60)
    r, jac, dr = hbm_kernels.collocation_residual_jacobian(z, omega, u2, sy.constants, sy.scale, sy.rate_ref,
                                                           sy.d_theta)
    assert np.linalg.cond(jac) > 1e8                   # (numerically) singular: the fold
    tz = np.linalg.svd(jac)[2][-1]                     # the (near-)null direction: tangent at a fold
    wz, tp = 1.0 / z.size, 1e-6
    assert np.linalg.cond(np.block([[jac, dr[:, None]], [wz * tz[None, :], np.array([[tp]])]])) < 1e6
    big = np.block([[jac, dr[:, None]], [wz * tz[None, :], np.array([[tp]])]])
    t, ok = hbm_kernels.bordered_tangent(z, np.log(omega), tz, tp, wz, u2, sy.constants, sy.scale, sy.rate_ref,
                                         sy.d_theta)
    want = np.linalg.solve(big, np.eye(z.size + 1)[-1])
    assert ok and np.max(np.abs(t - want)) <= 1e-8 * np.max(np.abs(want))


def sy_u2(point, system):
    """u^2 at the collocation phases of a T/2 solution (what the solvers pass the kernels)."""
    m = system.m
    return point.solution.periodic_input.at_phase(np.pi * np.arange(m) / m) ** 2
