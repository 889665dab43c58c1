"""Frequency sweeps: continuation through folds, stability along the branch, resonance peak."""
import numpy as np
import pytest

from dea_ros.model import preset
from dea_ros.solvers.continuation import frequency_sweep, sweep_independent
from dea_ros.solvers.harmonic_balance import solve_native
from dea_ros.solvers.inputs import SinePeriodic
from dea_ros.solvers.mousai_backend import mousai_available


@pytest.fixture(scope="module")
def a2_sweep():
    return frequency_sweep(preset("A2"), SinePeriodic(2500.0, 1.0), np.linspace(0.1, 20.0, 200),
                           n_harmonics=8)


def test_every_requested_frequency_is_on_the_branch(a2_sweep):
    f = a2_sweep.frequencies_Hz
    assert np.all(np.isin(np.round(np.linspace(0.1, 20, 200), 9), np.round(f, 9)))
    assert len(f) >= 200


def test_resonance_peak_matches_the_paper(a2_sweep):
    peak = a2_sweep.resonance_peak()
    assert peak["frequency_Hz"] == pytest.approx(9.5, abs=0.15)  # Table IV: simulated 9.5 Hz for A2
    assert a2_sweep.resonance_peak(stable_only=False)["d_rms_m"] >= peak["d_rms_m"]


def test_folds_and_instabilities_are_found(a2_sweep):
    assert len(a2_sweep.folds) == 2  # a hysteresis loop just above the peak
    segments = {p.segment for p in a2_sweep.points}
    assert segments == {0, 2} or len(segments) >= 2
    labels = {p.stability for p in a2_sweep.points if 17.0 < p.frequency_Hz < 20.0}
    assert "unstable (period-doubling)" in labels  # parametric resonance near 2 f_n / 2
    assert all(p.stable for p in a2_sweep.points if p.frequency_Hz < 4.0)


def test_branch_points_equal_independent_solves(a2_sweep):
    for p in a2_sweep.points[::40]:
        if p.segment != 0:
            continue
        ref = solve_native(preset("A2"), SinePeriodic(2500.0, p.frequency_Hz), n_harmonics=8,
                           x_guess=p.solution.state)
        assert ref.displacement_rms(a2_sweep.d0_m) == pytest.approx(p.d_rms_m, rel=1e-9)


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
