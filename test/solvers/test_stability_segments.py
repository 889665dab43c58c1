"""Branch curves drawn by stability: split at the located bifurcations, nothing lost when the
continuation took long steps (a lone stable or unstable curve point between the others)."""
from types import SimpleNamespace

import numpy as np
import pytest

from dea_ros.model import preset
from dea_ros.solvers.sweep import frequency_sweep
from dea_ros.solvers.sweep_results import Bifurcation, stability_segments
from dea_ros.solvers.inputs import SinePeriodic


def pieces(f, d):
    """Finite runs of a NaN-separated polyline, as lists of (f, d)."""
    out, cur = [], []
    for x, y in zip(f, d):
        if np.isnan(x):
            out.append(cur)
            cur = []
        else:
            cur.append((x, y))
    return out + ([cur] if cur else [])


def test_a_lone_point_is_drawn_and_the_split_is_at_the_bifurcation():
    branch = SimpleNamespace(name="T/2", curve_frequency_Hz=np.array([17.0, 18.0, 19.0, 20.0, 21.0]),
                             curve_d_rms_m=np.array([1.0, 2.0, 3.0, 4.0, 5.0]),
                             curve_stable=np.array([True, True, False, True, True]))
    bif = [Bifurcation("period-doubling", 18.4, 2.4, "T/2", -1.0, True),
           Bifurcation("period-doubling", 19.2, 3.2, "T/2", -1.0, False),
           Bifurcation("period-doubling", 18.5, 9.9, "T", -1.0, True)]   # another branch's: ignored
    (fs, ds), (fu, du) = stability_segments(branch, bif)
    assert [len(p) for p in pieces(fs, ds)] == [3, 3]
    assert pieces(fs, ds)[0] == [(17.0, 1.0), (18.0, 2.0), (18.4, 2.4)]
    assert pieces(fs, ds)[1] == [(19.2, 3.2), (20.0, 4.0), (21.0, 5.0)]
    assert pieces(fu, du) == [[(18.4, 2.4), (19.0, 3.0), (19.2, 3.2)]]   # masking would draw nothing here


def test_without_a_located_bifurcation_the_split_is_half_way():
    branch = SimpleNamespace(name="T/2", curve_frequency_Hz=np.array([1.0, 2.0]), curve_d_rms_m=np.array([1.0, 3.0]),
                             curve_stable=np.array([True, False]))
    (fs, ds), (fu, du) = stability_segments(branch, [])
    assert pieces(fs, ds) == [[(1.0, 1.0), (1.5, 2.0)]] and pieces(fu, du) == [[(1.5, 2.0), (2.0, 3.0)]]


def test_a2_period_doubling_band_and_the_stable_orbit_beyond_it_are_drawn():
    """A2 at 2.5 kV: the T/2 orbit is unstable in the period-doubling band (18.40-19.23 Hz) and stable
    again above it (coexisting with the period-doubled orbit): the continuation steps ~1 Hz there,
    so both pieces rest on one or two curve points."""
    sweep = frequency_sweep(preset("A2"), SinePeriodic(2500.0, 1.0), np.linspace(12.0, 21.0, 40),
                            n_harmonics=6, realised=False)
    half = next(b for b in sweep.branches if b.name == "T/2")
    pd = sorted(b.frequency_Hz for b in sweep.bifurcations if b.branch == "T/2" and b.kind == "period-doubling")
    assert pd == [pytest.approx(18.40, abs=0.02), pytest.approx(19.23, abs=0.02)]
    (fs, ds), (fu, du) = stability_segments(half, sweep.bifurcations)
    unstable = pieces(fu, du)
    assert len(unstable) == 1 and unstable[0][0][0] == pd[0] and unstable[0][-1][0] == pd[1]
    stable = pieces(fs, ds)
    assert stable[-1][0][0] == pd[1] and stable[-1][-1][0] >= 21.0   # the coexisting and periodic stretch
    assert stable[-2][-1][0] == pd[0]
