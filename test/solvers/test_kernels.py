"""The compiled solver kernels against the numpy reference (test/solvers/reference) and forward integration.

The product runs the compiled kernels; the numpy reference is the former numpy path, written with
whole-array operations. Both must give the same solutions, iterations, Floquet multipliers and
sweeps (to rounding), and both must match converged forward integration.
"""
import numpy as np
import pytest

from dea_ros.errors import ContinuationError
from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers import (
    branch_analysis,
    branch_tracer,
    collocation_kernels,
    floquet_kernels,
    newton_kernels,
    realised,
    sweep,
    sweep_kernels,
)
from dea_ros.solvers.branch_tracer import BranchTrace, BranchTracer, GridPoint
from dea_ros.solvers.collocation import model_setup, response_layout
from dea_ros.solvers.floquet import attach_floquet, floquet_multipliers_batch, monodromy_matrix, sorted_eigenvalues
from dea_ros.solvers.inputs import SampledPeriodic, SinePeriodic
from dea_ros.solvers.newton import solve_native, solve_native_batch
from dea_ros.solvers.realised import realised_response
from dea_ros.solvers.steady_state import integrate_to_steady_state
from dea_ros.solvers.sweep import frequency_sweep

from reference import collocation as ref_collocation, continuation as ref_continuation, floquet as ref_floquet


@pytest.fixture(scope="module")
def a2():
    return preset("A2")


def scaled_diff(a2, x, y):
    return float(np.max(np.abs(np.asarray(x) - np.asarray(y)) / model_setup(a2).scale[:, None]))


def reference_trace(self, z, p, tz, tp, p_lo, p_hi, max_steps, h0=None):
    """BranchTracer.trace by the numpy reference loop."""
    podd = self.problem.podd if self.problem.stop_on_odd_flip else None
    tr = ref_continuation.ReferenceTracer(self).trace(z, p, tz, tp, p_lo, p_hi, max_steps, odd_projector=podd, h0=h0)
    return BranchTrace(z=tr["z"], p=tr["p"], tz=tr["tz"], tp=tr["tp"], h=tr["h"], segment=tr["segment"],
                       grid=[GridPoint(*g) for g in tr["grid"]], fold_steps=tr["fold_steps"], steps=tr["steps"],
                       stopped=tr["stopped"])


@pytest.fixture
def reference_path(monkeypatch):
    """The sweep with every compiled step replaced by its numpy reference (the former numpy path)."""
    monkeypatch.setattr(BranchTracer, "trace", reference_trace)
    monkeypatch.setattr(BranchTracer, "tangent", lambda self, *a: ref_continuation.ReferenceTracer(self).tangent(*a))
    monkeypatch.setattr(BranchTracer, "correct", lambda self, *a, **k: ref_continuation.ReferenceTracer(self).correct(
        *a, **k))
    monkeypatch.setattr(BranchTracer, "solve_at", lambda self, *a: ref_continuation.ReferenceTracer(self).solve_at(*a))
    monkeypatch.setattr(branch_analysis, "floquet_multipliers_batch", ref_floquet.floquet_multipliers_batch)
    monkeypatch.setattr(branch_tracer, "floquet_multipliers", ref_floquet.floquet_multipliers)
    monkeypatch.setattr(branch_tracer, "magnus_steps", ref_floquet.magnus_steps)
    monkeypatch.setattr(realised, "rk4_periods", realised.rk4_periods.py_func)
    monkeypatch.setattr(sweep, "solve_native", ref_collocation.solve_native)


@pytest.mark.parametrize("implementation", ["kernels", "reference"])
def test_both_match_converged_forward_integration(a2, implementation):
    inp = SinePeriodic(2500.0, 3.0)      # (on the peak: test_harmonic_balance)
    d0 = static_equilibrium(a2, 0.0).displacement_m
    solve = solve_native if implementation == "kernels" else ref_collocation.solve_native
    hbm = solve(a2, inp, 8)
    fi = integrate_to_steady_state(a2, inp, tol=1e-8)
    ref = fi.displacement_rms(d0)
    assert abs(hbm.displacement_rms(d0) - ref) / ref < 1e-5
    assert hbm.stable
    if implementation == "kernels":
        batch = solve_native_batch(a2, [inp, SinePeriodic(2500.0, 4.0)], n_harmonics=8, stability=True)
        assert abs(batch[0].displacement_rms(d0) - ref) / ref < 1e-5
        assert batch[0].stable and batch[1].stable


@pytest.mark.parametrize("n", [2, 4, 8])
def test_single_solves_are_the_same_as_the_reference(a2, n):
    for f in (0.1, 3.0, 9.5, 17.0):
        ref = ref_collocation.solve_native(a2, SinePeriodic(2500.0, f), n, stability=True)
        fast = solve_native(a2, SinePeriodic(2500.0, f), n, stability=True)
        assert fast.iterations == ref.iterations
        assert scaled_diff(a2, fast.state, ref.state) < 1e-10
        np.testing.assert_allclose(fast.multipliers, ref.multipliers, rtol=0, atol=1e-10)
        assert fast.stability == ref.stability


def test_batched_solves_and_stability_are_the_same_as_the_reference(a2):
    inputs = [SinePeriodic(2500.0, f) for f in np.linspace(0.1, 20.0, 17)]
    fast = solve_native_batch(a2, inputs, 4, stability=True)
    for inp, s in zip(inputs, fast):
        r = ref_collocation.solve_native(a2, inp, 4, stability=True)
        assert s.iterations == r.iterations
        assert scaled_diff(a2, s.state, r.state) < 1e-10
        np.testing.assert_allclose(s.multipliers, r.multipliers, rtol=0, atol=1e-10)
    # without the symmetry (full period: the half-period multipliers too)
    for s in solve_native_batch(a2, inputs[3:6], 6, use_symmetry=False, stability=True):
        r = ref_collocation.solve_native(a2, s.periodic_input, 6, use_symmetry=False, stability=True)
        np.testing.assert_allclose(s.multipliers, r.multipliers, rtol=0, atol=1e-10)
        assert (s.half_period_multipliers is None) == (r.half_period_multipliers is None)
        if r.half_period_multipliers is not None:
            np.testing.assert_allclose(s.half_period_multipliers, r.half_period_multipliers, rtol=0, atol=1e-10)


def test_one_batch_of_mixed_waveforms_has_each_items_own_multipliers(a2):
    """The batched Floquet step evaluates a waveform once for all items that share it
    (``waveform_key``): items with other amplitudes, offsets or sampled waveforms must still get
    their own input, i.e. the multipliers each item gets alone."""
    assert SinePeriodic(2500.0, 3.0).waveform_key() == SinePeriodic(2500.0, 7.0).waveform_key()
    assert SinePeriodic(2500.0, 3.0).waveform_key() != SinePeriodic(2000.0, 3.0).waveform_key()
    assert SinePeriodic(2500.0, 3.0).waveform_key() != SinePeriodic(2500.0, 3.0, 300.0).waveform_key()
    theta = 2 * np.pi * np.arange(16) / 16
    inputs = [SinePeriodic(2500.0, 3.0, 400.0), SinePeriodic(1500.0, 3.0, 400.0), SinePeriodic(2500.0, 9.0, 400.0),
              SampledPeriodic(1800.0 + 500.0 * np.sin(theta) + 200.0 * np.cos(2 * theta), 3.0),
              SampledPeriodic(1800.0 + 500.0 * np.sin(theta), 3.0), SinePeriodic(2500.0, 0.2, 400.0)]
    batch = solve_native_batch(a2, inputs, 6, stability=True)
    setup = model_setup(a2)
    for sol in batch:
        alone = attach_floquet(setup.model, solve_native_batch(a2, [sol.periodic_input], 6)[0], scale=setup.scale)
        np.testing.assert_allclose(sol.multipliers, alone.multipliers, rtol=0, atol=1e-12)
        ref = ref_floquet.floquet_multipliers(setup.model, sol, scale=setup.scale)   # and the numpy reference
        np.testing.assert_allclose(sol.multipliers, ref, rtol=0, atol=1e-10)


def test_coarse_batch_multipliers_are_the_same_as_the_reference(a2):
    sols = solve_native_batch(a2, [SinePeriodic(2500.0, f) for f in (0.3, 2.0, 9.4, 14.0)], 6)
    states = np.stack([s.state for s in sols])
    periods = np.array([s.response_period_s for s in sols])
    setup = model_setup(a2)
    args = (setup.model, states, periods, SinePeriodic(2500.0, 1.0), 2)
    np.testing.assert_allclose(floquet_multipliers_batch(*args, scale=setup.scale),
                               ref_floquet.floquet_multipliers_batch(*args, scale=setup.scale), rtol=0, atol=1e-10)


@pytest.fixture(scope="module")
def kernel_sweep(a2):
    return frequency_sweep(a2, SinePeriodic(2500.0, 0.1), np.linspace(0.1, 20.0, 60), n_harmonics=8)


def test_sweep_with_bands_is_the_same_as_the_reference(a2, kernel_sweep, reference_path):
    """Folds, bifurcations, bands and the realised (integrated) responses in the torus band."""
    fast = kernel_sweep
    ref = frequency_sweep(a2, SinePeriodic(2500.0, 0.1), np.linspace(0.1, 20.0, 60), n_harmonics=8)
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


@pytest.mark.parametrize("implementation", ["kernels", "reference"])
def test_a_branch_longer_than_max_branch_steps_is_an_error(a2, implementation, request):
    if implementation == "reference":
        request.getfixturevalue("reference_path")
    with pytest.raises(ContinuationError, match="more than 5 branch steps"):
        frequency_sweep(a2, SinePeriodic(2500.0, 0.1), np.linspace(0.1, 20.0, 20), n_harmonics=4,
                        max_branch_steps=5)


def test_compiled_branch_trace_takes_the_same_steps_as_the_reference(a2):
    """The compiled continuation engine against the reference loop: same steps, grid points, folds, tangents."""
    setup = model_setup(a2)
    inp = SinePeriodic(2500.0, 8.0)
    divisor, m = response_layout(inp, 6, True)
    p_grid = np.log(2 * np.pi * np.linspace(8.0, 12.0, 30) * divisor)
    start = solve_native(a2, inp, 6)
    tracer = BranchTracer(setup, inp, divisor, m, 1e-10, 0.05, p_grid)
    reference = ref_continuation.ReferenceTracer(tracer)
    z0 = tracer.system.to_z(start.state)
    tz, tp = tracer.tangent(z0, p_grid[0], np.zeros(tracer.n), 1.0)
    tz_r, tp_r = reference.tangent(z0, p_grid[0], np.zeros(tracer.n), 1.0)
    np.testing.assert_allclose(tz, tz_r, rtol=0, atol=1e-10)
    fast = tracer.trace(z0, p_grid[0], tz, tp, p_grid[0] - 1.0, p_grid[-1], 2000)
    ref = reference.trace(z0, p_grid[0], tz, tp, p_grid[0] - 1.0, p_grid[-1], 2000)
    assert fast.steps == ref["steps"] and fast.fold_steps == ref["fold_steps"] and len(ref["fold_steps"]) == 2
    np.testing.assert_allclose(fast.p, ref["p"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(fast.z, ref["z"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast.tp, ref["tp"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast.h, ref["h"], rtol=1e-8)
    assert [g[0] for g in fast.grid] == [g[0] for g in ref["grid"]]
    assert [g[4] for g in fast.grid] == [g[4] for g in ref["grid"]]
    np.testing.assert_allclose([g[1] for g in fast.grid], [g[1] for g in ref["grid"]], rtol=0, atol=1e-9)


def test_realised_integration_is_the_same_as_python(a2, monkeypatch):
    d0 = static_equilibrium(a2, 0.0).displacement_m
    args = (a2, SinePeriodic(2500.0, 9.5), [1.2 * d0, 0.0, 0.0], d0)
    fast = realised_response(*args, settle_periods=20, window_periods=10)
    monkeypatch.setattr(realised, "rk4_periods", realised.rk4_periods.py_func)
    ref = realised_response(*args, settle_periods=20, window_periods=10)
    assert fast.d_rms_m == pytest.approx(ref.d_rms_m, rel=1e-12)
    assert fast.kind == ref.kind
    np.testing.assert_allclose(fast.final_state, ref.final_state, rtol=1e-10)


def test_multipliers_of_monodromies_are_the_same_as_numpy(a2):
    """sorted_eigenvalues: the compiled cubic and numpy's eigvals on the monodromies of a resonance sweep
    (where the multipliers cluster and cross the unit circle) within 1e-10; the monodromies too."""
    setup = model_setup(a2)
    sols = solve_native_batch(a2, [SinePeriodic(2500.0, f) for f in np.linspace(8.0, 12.0, 41)], 8)
    mats = np.stack([monodromy_matrix(setup.model, sol, scale=setup.scale) for sol in sols])
    ref_mats = np.stack([ref_floquet.monodromy_matrix(setup.model, sol, scale=setup.scale) for sol in sols])
    np.testing.assert_allclose(mats, ref_mats, rtol=0, atol=1e-10)
    np.testing.assert_allclose(sorted_eigenvalues(mats), ref_floquet.sorted_eigenvalues(mats), rtol=0, atol=1e-10)


@pytest.mark.parametrize("eigenvalues", [sorted_eigenvalues, ref_floquet.sorted_eigenvalues])
def test_a_monodromy_with_nan_is_a_linalg_error(eigenvalues):
    with pytest.raises(np.linalg.LinAlgError):
        eigenvalues(np.full((1, 3, 3), np.nan))


def test_spectral_radius_of_3x3_matrices_matches_eigenvalues():
    rng = np.random.default_rng(7)
    for _ in range(300):
        a = rng.normal(size=(3, 3)) * rng.choice([1e-2, 1.0, 1e2])
        want = np.max(np.abs(np.linalg.eigvals(a)))
        assert floquet_kernels.spectral_radius3(a) == pytest.approx(want, rel=1e-7)
    assert floquet_kernels.spectral_radius3(np.diag([3.0, -5.0, 1.0])) == pytest.approx(5.0)
    assert floquet_kernels.spectral_radius3(np.array([[0.0, -2.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 1.0]])) == \
        pytest.approx(2.0)


def test_eigenvalues_of_3x3_matrices_match_lapack_and_its_conventions():
    """floquet_kernels.eigenvalues3 (characteristic cubic) against numpy's eigvals (LAPACK dgeev): matrices with
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
        got = floquet_kernels.eigenvalues3(a[None])[0]
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
    assert np.all(floquet_kernels.eigenvalues3(np.zeros((1, 3, 3))) == 0.0)


def test_model_jacobian_has_the_pattern_the_structured_solve_uses(a2):
    """The reduction of the collocation systems (collocation_kernels.structured_solve_into) needs eq. 18's pattern:
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
    the dense solution to rounding, at random states and frequencies."""
    setup = model_setup(a2)
    sy = setup.system(m)
    rng = np.random.default_rng(m)
    for _ in range(3):
        z = rng.normal(size=3 * m) * 0.3 + np.repeat([1.0, 0.5, 0.0], m)
        u2 = (rng.uniform(500.0, 3000.0) * np.sin(np.linspace(0.0, np.pi, m, endpoint=False))) ** 2
        omega = 2 * np.pi * rng.uniform(0.1, 40.0)
        r, jac, dr = collocation_kernels.collocation_residual_jacobian(z, omega, u2, sy.constants, sy.scale,
                                                                       sy.rate_ref, sy.d_theta)
        rhs = rng.normal(size=3 * m)
        x, ok = collocation_kernels.structured_solve(z, omega, u2, sy.constants, sy.scale, sy.rate_ref, sy.d_theta, rhs)
        want = np.linalg.solve(jac, rhs)
        assert ok and np.max(np.abs(x - want)) <= 1e-11 * np.max(np.abs(want))
        tz, tp, wz = rng.normal(size=3 * m), rng.normal(), 1.0 / (3 * m)
        big = np.block([[jac, dr[:, None]], [wz * tz[None, :], np.array([[tp]])]])
        t, ok = sweep_kernels.bordered_tangent(z, np.log(omega), tz, tp, wz, u2, sy.constants, sy.scale,
                                               sy.rate_ref, sy.d_theta)
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
    z, _it, _res, _status = newton_kernels.newton(sy.to_z(near.solution.state), omega, u2, sy.constants,
                                                  sy.scale, sy.rate_ref, sy.d_theta, 1e-12, 60)
    r, jac, dr = collocation_kernels.collocation_residual_jacobian(z, omega, u2, sy.constants, sy.scale,
                                                                   sy.rate_ref, sy.d_theta)
    assert np.linalg.cond(jac) > 1e8                   # (numerically) singular: the fold
    tz = np.linalg.svd(jac)[2][-1]                     # the (near-)null direction: tangent at a fold
    wz, tp = 1.0 / z.size, 1e-6
    assert np.linalg.cond(np.block([[jac, dr[:, None]], [wz * tz[None, :], np.array([[tp]])]])) < 1e6
    big = np.block([[jac, dr[:, None]], [wz * tz[None, :], np.array([[tp]])]])
    t, ok = sweep_kernels.bordered_tangent(z, np.log(omega), tz, tp, wz, u2, sy.constants, sy.scale,
                                           sy.rate_ref, sy.d_theta)
    want = np.linalg.solve(big, np.eye(z.size + 1)[-1])
    assert ok and np.max(np.abs(t - want)) <= 1e-8 * np.max(np.abs(want))


def sy_u2(point, system):
    """u^2 at the collocation phases of a T/2 solution (what the solvers pass the kernels)."""
    m = system.m
    return point.solution.periodic_input.at_phase(np.pi * np.arange(m) / m) ** 2
