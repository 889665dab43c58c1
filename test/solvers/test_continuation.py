"""Frequency sweeps: continuation through folds, branch switching at period doubling, realised
responses and bands, the resonance peak on the branch -- against converged forward integration."""
import numpy as np
import pytest

from dea_ros.model import preset, static_equilibrium
from dea_ros.solvers.newton import solve_native
from dea_ros.solvers.inputs import SinePeriodic, SineVoltage
from dea_ros.solvers.integrate import simulate
from dea_ros.solvers.mousai_backend import mousai_available
from dea_ros.solvers.realised import realised_response
from dea_ros.solvers.steady_state import integrate_to_steady_state, shoot_periodic_orbit
from dea_ros.solvers.sweep import frequency_sweep, sweep_independent

GRID = np.linspace(0.1, 20.0, 200)


@pytest.fixture(scope="module")
def a2_sweep():
    return frequency_sweep(preset("A2"), SinePeriodic(2500.0, 1.0), GRID, n_harmonics=8)


def test_every_requested_frequency_is_on_the_branch(a2_sweep):
    f = a2_sweep.frequencies_Hz
    assert np.all(np.isin(np.round(GRID, 9), np.round(f, 9)))
    assert len(f) >= 200
    assert np.allclose(a2_sweep.response_frequencies_Hz, GRID)  # one realised response per frequency


def test_folds_and_instabilities_are_found(a2_sweep):
    assert len(a2_sweep.folds) == 2  # a hysteresis loop just above the peak
    labels = {p.stability for p in a2_sweep.points if 17.0 < p.frequency_Hz < 20.0}
    assert "unstable (period-doubling)" in labels  # parametric resonance near 2 f_n / 2
    assert all(p.stable for p in a2_sweep.points if p.frequency_Hz < 4.0)
    kinds = {(b.branch, b.kind) for b in a2_sweep.bifurcations}
    assert {("T/2", "torus"), ("T/2", "period-doubling"), ("T/2", "fold")} <= kinds


def test_bands_of_a2(a2_sweep):
    """Band edges at the located bifurcations (independently: 9.584-9.644 torus, 18.40-19.23 PD)."""
    bands = {b.kind: b for b in a2_sweep.bands if b.kind != "periodic"}
    qp, pd = bands["quasi-periodic"], bands["period-doubled"]
    assert qp.f_start_Hz == pytest.approx(9.584, abs=0.002) and qp.f_end_Hz == pytest.approx(9.644, abs=0.002)
    assert (qp.start_edge, qp.end_edge) == ("torus", "torus")
    assert pd.f_start_Hz == pytest.approx(18.40, abs=0.01) and pd.f_end_Hz == pytest.approx(19.23, abs=0.01)
    assert (pd.start_edge, pd.end_edge) == ("period-doubling", "period-doubling")
    # the bands tile the range without gaps
    edges = [(b.f_start_Hz, b.f_end_Hz) for b in a2_sweep.bands]
    assert edges[0][0] == pytest.approx(0.1) and edges[-1][1] == pytest.approx(20.0)
    assert all(a[1] == pytest.approx(b[0]) for a, b in zip(edges[:-1], edges[1:]))
    for r in a2_sweep.responses:  # every response lies in a band of its kind
        band = [b for b in a2_sweep.bands if b.f_start_Hz <= r.frequency_Hz <= b.f_end_Hz]
        assert r.kind in {b.kind for b in band}


@pytest.mark.parametrize("f_Hz", [18.6, 19.0])
def test_period_doubled_response_equals_converged_integration(a2_sweep, f_Hz):
    """The reported response in the PD band is the period-doubled orbit, within 0.1 % of the
    periodic orbit found by shooting on DOP853, and that orbit is stable (what a rig shows)."""
    r = [x for x in a2_sweep.responses if abs(x.frequency_Hz - f_Hz) < 1e-9][0]
    assert r.kind == "period-doubled" and r.branch == "T"
    pt = [p for p in a2_sweep.branch("T").points if abs(p.frequency_Hz - f_Hz) < 1e-9][0]
    ref = shoot_periodic_orbit(preset("A2"), SinePeriodic(2500.0, f_Hz), pt.solution.evaluate(0.0)[:, 0])
    assert np.max(np.abs(ref.multipliers)) < 1.0 and ref.odd_harmonic_ratio() > 0.1
    assert r.d_rms_m == pytest.approx(ref.displacement_rms(a2_sweep.d0_m), rel=1e-3)
    t2 = [p for p in a2_sweep.points if abs(p.frequency_Hz - f_Hz) < 1e-9][0]
    assert t2.stability == "unstable (period-doubling)"          # the T/2 orbit stays visible
    assert r.d_rms_m > 10 * t2.d_rms_m


def test_period_doubled_response_from_rest_by_brute_force_integration(a2_sweep):
    """What a rig starting at rest sees at 18.8 Hz: forward integration to the steady state."""
    p = preset("A2")
    fi = integrate_to_steady_state(p, SinePeriodic(2500.0, 18.8), tol=1e-7, max_time_s=300.0)
    d0 = static_equilibrium(p, 0.0).displacement_m
    r = [x for x in a2_sweep.responses if abs(x.frequency_Hz - 18.8) < 1e-9][0]
    assert r.d_rms_m == pytest.approx(fi.displacement_rms(d0), rel=1e-3)  # ~1246 um


def test_full_period_solve_of_the_symmetric_orbit_is_named_period_doubling():
    sol = solve_native(preset("A2"), SinePeriodic(2500.0, 18.8), n_harmonics=16, use_symmetry=False)
    assert sol.odd_harmonic_ratio() < 1e-6          # the default guess converges to the T/2 orbit
    assert sol.stability == "unstable (period-doubling)"   # not "saddle" (its multiplier squared is > 1)
    assert not sol.stable


def test_torus_band_realised_by_integration(a2_sweep):
    r = [x for x in a2_sweep.responses if abs(x.frequency_Hz - 9.6) < 1e-9][0]
    assert r.kind == "quasi-periodic" and r.branch == "integration"
    assert r.d_rms_min_m < r.d_rms_m < r.d_rms_max_m
    assert r.d_rms_max_m - r.d_rms_min_m > 0.2 * r.d_rms_m       # strongly modulated
    assert r.integration["window_periods"] > 0 and r.integration["window_s"][1] > r.integration["window_s"][0]
    t2 = [p for p in a2_sweep.points if abs(p.frequency_Hz - 9.6) < 1e-9][0]
    assert not t2.stable and abs(r.d_rms_m / t2.d_rms_m - 1) > 0.05


def test_realised_response_integrator_matches_dop853():
    """The fixed-step integrator behind quasi-periodic responses against the adaptive one."""
    p = preset("A2")
    f = 9.6
    start = solve_native(p, SinePeriodic(2500.0, f), 8).evaluate(0.0)[:, 0] + np.array([1e-5, 0, 0])
    d0 = static_equilibrium(p, 0.0).displacement_m
    rr = realised_response(p, SinePeriodic(2500.0, f), start, d0, settle_periods=0, window_periods=10,
                           steps_per_period=128)
    t = np.arange(10 * 128) / (128 * f)
    ref = simulate(p, SineVoltage(2500.0, f), t[-1] + 1 / (128 * f), t_eval=t, x0=start, rtol=1e-10,
                   atol_scale=1e-10).displacement_m
    ref_rms = np.sqrt(np.mean((ref - d0) ** 2))
    assert rr.d_rms_m == pytest.approx(ref_rms, rel=3e-4)


def test_coexisting_branches_in_a_hysteresis_band():
    r = frequency_sweep(preset("A1"), SinePeriodic(2500.0, 1.0), np.linspace(9.0, 11.0, 41), n_harmonics=8)
    co = [b for b in r.bands if b.kind == "coexisting"]
    assert len(co) == 1 and co[0].branches == ["T/2", "T/2"]
    assert co[0].f_start_Hz == pytest.approx(10.1955, abs=1e-3) and co[0].f_end_Hz == pytest.approx(10.2547, abs=1e-3)
    at = [x for x in r.responses if abs(x.frequency_Hz - 10.2) < 1e-9][0]
    assert at.kind == "coexisting" and len(at.alternatives) == 1
    assert at.d_rms_m == at.d_rms_max_m  # a slow upward sweep stays on the upper branch


@pytest.fixture(scope="module")
def fine_peak():
    """The peak of a 0.0001 Hz sweep across the top of the A2 resonance (largest stable point)."""
    fine = frequency_sweep(preset("A2"), SinePeriodic(2500.0, 1.0), np.linspace(9.55, 9.59, 401),
                           n_harmonics=8, branch_switching=False, realised=False)
    k = int(np.argmax(np.where(fine.stable, fine.d_rms_m, -1)))
    return fine.frequencies_Hz[k], fine.d_rms_m[k]


@pytest.mark.parametrize("grid", [np.linspace(0.1, 20.0, 40), np.linspace(0.137, 19.93, 67),
                                  np.geomspace(0.2, 20.0, 25)])
def test_resonance_peak_is_located_on_the_branch_whatever_the_grid(grid, fine_peak):
    f_ref, d_ref = fine_peak
    peak = frequency_sweep(preset("A2"), SinePeriodic(2500.0, 1.0), grid, n_harmonics=8,
                           branch_switching=False, realised=False).resonance_peak()
    assert peak["frequency_Hz"] == pytest.approx(f_ref, abs=0.01)
    assert peak["d_rms_m"] == pytest.approx(d_ref, rel=1e-3)
    assert peak["d_rms_m"] >= d_ref * (1 - 1e-6)  # the branch maximum, not a grid point below it


def test_branch_points_equal_independent_solves(a2_sweep):
    for p in a2_sweep.points[::40]:
        if p.segment != 0:
            continue
        ref = solve_native(preset("A2"), SinePeriodic(2500.0, p.frequency_Hz), n_harmonics=8,
                           x_guess=p.solution.state)
        assert ref.displacement_rms(a2_sweep.d0_m) == pytest.approx(p.d_rms_m, rel=1e-9)


def test_bifurcations_are_where_shooting_multipliers_cross_the_unit_circle(a2_sweep):
    """Each torus and period-doubling point of the T/2 branch is located where the largest Floquet
    multiplier of single shooting (DOP853 and its variational equations: no harmonic balance, no
    Magnus) crosses the unit circle: 1e-6 Hz before and after it, |mu| - 1 has opposite signs (the
    located |mu| must be accurate to ~1e-6 for that: bisection with the default Magnus steps was
    wrong by up to 5e-6 Hz at all four)."""
    p = preset("A2")
    bifs = [b for b in a2_sweep.bifurcations if b.branch == "T/2" and b.kind in ("torus", "period-doubling")]
    assert len(bifs) == 4
    for b in bifs:
        # the branch's solution nearest to the bifurcation (frequency and amplitude) seeds the shooting
        near = min((q for q in a2_sweep.points if q.branch == "T/2"),
                   key=lambda q: abs(q.frequency_Hz - b.frequency_Hz) / 0.05 + abs(q.d_rms_m - b.d_rms_m) / b.d_rms_m)
        margin = []
        for f in (b.frequency_Hz - 1e-6, b.frequency_Hz + 1e-6):
            inp = SinePeriodic(2500.0, f)
            start = solve_native(p, inp, n_harmonics=8, x_guess=near.solution.state)   # on the same branch
            orbit = shoot_periodic_orbit(p, inp, start.evaluate(0.0)[:, 0], max_iter=20)
            assert orbit.odd_harmonic_ratio() < 1e-6      # still the T/2 orbit
            margin.append(float(np.max(np.abs(orbit.multipliers))) - 1.0)
        assert margin[0] * margin[1] < 0, (b.kind, b.frequency_Hz, margin)


def test_d0_choice_changes_only_the_reference():
    inp = SinePeriodic(2500.0, 1.0)
    a = frequency_sweep(preset("A1"), inp, [1.0, 2.0], d0="static", stability=False)
    b = frequency_sweep(preset("A1"), inp, [1.0, 2.0], d0="mean", stability=False)
    assert np.all(a.d_rms_m > b.d_rms_m)  # static d0 adds the DC shift by the Maxwell pressure
    with pytest.raises(ValueError, match="d0"):
        frequency_sweep(preset("A1"), inp, [1.0, 2.0], d0="zero")


@pytest.mark.skipif(not mousai_available(), reason="mousai not installed (optional extra [mousai])")
def test_mousai_sweep_agrees_with_native():
    r = sweep_independent(preset("A2"), SinePeriodic(2500.0, 1.0), [2.0, 3.0], method="mousai",
                          n_harmonics=6)
    assert [p.stability for p in r.points] == ["stable", "stable"]
    ref = frequency_sweep(preset("A2"), SinePeriodic(2500.0, 1.0), [2.0, 3.0], n_harmonics=8)
    for p, q in zip(r.points, ref.points):
        assert p.frequency_Hz == pytest.approx(q.frequency_Hz)
        assert p.d_rms_m == pytest.approx(q.d_rms_m, rel=1e-4)
