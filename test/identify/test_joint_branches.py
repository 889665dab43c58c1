"""The joint refinement frees the curvature only after a round with it held (issue 21: intervals that hold).

F11 of the coverage family (bench/bench_coverage_family.py: hardening, creep time 0.17 s, resonance 11.1 Hz)
recorded as the rig records it (held voltage at 500 Hz from rest, converged forward integration, 1 um laser
noise and the ILD1320 quantisation, cut by the bag extraction) with 17 sine frequencies, noise seed 3.
Freed at once from the two-stage result, the curvature let the fit follow a record near the fold onto
another branch: chi-square 5272, 1845 of it on the 13 static points, k1 -1.29 % and sigma_h(1) -0.25 % at
30 standard errors. The data come from the true membrane, never from the fit's model.

These data hold every sine 12 time constants at rest (``rig_protocol(orbit_holds=False)``, the synthetic rig's
rule before session 22): the 11.086 Hz record, next to the fold, is measured ~2.3 of its orbit's time constants
(6.2 s) after it started, still settling. Held until its orbit has settled (74 s, the rule since), the joint
refinement leaves the static points on this data set again and the two-stage result is reported with the
intervals of the objective linearised there (last test): an open weakness of the refinement near a fold
(docs/benchmarks.md, issue 21 session 22), not hidden by these tests.
"""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.identify.pipeline import identify
from dea_ros.identify.static_fit import EXTENDED_COMBINATION_MATRIX
from dea_ros.identify.synth import DEFAULT_STATIC_MASSES_KG
from dea_ros.identify.synth_rig import rig_experiments, rig_protocol
from dea_ros.model import preset
from dea_ros.sim.plant import LASER_QUANTISATION_M

F11 = preset("A2").replace(
    name="F11", prestretch=1.2780999679492329, thickness_m=5.649939530490238e-05,
    plate_radius_m=0.004961323276028844, electrode_width_m=0.015547576760019412, mass_kg=0.0027288683094307113,
    relative_permittivity=2.643818723479147, k1_Pa=52770618.122001864, eta1_Pa_s=8751103.403911088,
    eta2_Pa_s=11387.16904529811, beta_Pa=(-41468.716604390764, 82481.83801665457, 207708.94510931347),
    gamma_Pa=(403207.30862072675, -288471.08388943906, -266158.8886821318))
#: the family's 17 frequencies for F11: the paper's four and 13 placed on its resonance
SEVENTEEN_HZ = (0.2, 2.771, 5.543, 7.76, 8.3, 9.423, 9.839, 10.254, 10.67, 11.086, 11.2, 11.502, 11.917, 12.333,
                12.749, 16.629, 40.0)


@pytest.fixture(scope="module")
def result():
    exp, _rec = rig_experiments(F11, rig_protocol(F11, SEVENTEEN_HZ, orbit_holds=False), seed=3,
                                other_masses_kg=DEFAULT_STATIC_MASSES_KG, quantisation_m=LASER_QUANTISATION_M)
    return identify(exp, evaluate_fit=False)


def test_the_fit_stays_on_the_records_branches_and_fits_the_static_points(result):
    joint = result.joint
    assert joint is not None and "sigma_h''(1)_Pa" in joint.names
    n_static = result.experiments.all_static().n_points
    assert joint.block_chi2["static"] < 3 * n_static                 # 1845 for 13 when freed at once
    assert joint.block_chi2["frequency"] < 3 * len(joint.frequency_points)
    assert not any("above the" in w and "held" in w for w in result.warnings)


def test_the_intervals_hold(result):
    stats = result.statistics
    truth = {"eps_r": F11.relative_permittivity, "k1_Pa": F11.k1_Pa, "eta1_Pa_s": F11.eta1_Pa_s,
             "eta2_Pa_s": F11.eta2_Pa_s,
             "sigma_h(1)_Pa": float((EXTENDED_COMBINATION_MATRIX @ np.r_[F11.beta_Pa, F11.gamma_Pa])[0])}
    for name, value in truth.items():
        k = stats.names.index(name)
        assert abs(stats.values[k] - value) < 3 * stats.std_error[k], name
        assert abs(stats.values[k] / value - 1) < 0.01, name


def test_with_the_fold_record_settled_the_refinement_is_refused_and_the_intervals_say_so():
    exp, _rec = rig_experiments(F11, rig_protocol(F11, SEVENTEEN_HZ), seed=3, other_masses_kg=DEFAULT_STATIC_MASSES_KG,
                                quantisation_m=LASER_QUANTISATION_M)
    settled = identify(exp, evaluate_fit=False)
    assert settled.joint is None
    assert any("left the static points" in w and "two-stage result is reported" in w for w in settled.warnings)
    stats = settled.statistics
    for name, value in {"eps_r": F11.relative_permittivity, "k1_Pa": F11.k1_Pa, "eta1_Pa_s": F11.eta1_Pa_s,
                        "eta2_Pa_s": F11.eta2_Pa_s}.items():
        k = stats.names.index(name)
        assert stats.ci_low[k] <= value <= stats.ci_high[k], name       # what is reported still holds
