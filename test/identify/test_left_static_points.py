"""A joint refinement that follows a record onto another branch and leaves the static points is done again
without the records whose response the model at the two-stage parameters does not have
(``refinement.refine_jointly``), instead of reporting what it found there.

The case: F17 of the coverage family (bench/bench_coverage_family.py; creep 1.85 s, resonance 9.29 Hz),
17 frequencies, seed 2 (seed 1 until each static point was weighted by its own uncertainty, session 19).
At the resonance the record shows the upper branch (1505 um RMS) where the model at
the two-stage parameters has only a quasi-periodic response (790 um); both rounds of the refinement ended on
another branch of it, the static points' chi-square went from 7.7 to 36682 and eta1 came out x1000 while
the two-stage result was within 0.3 % (session 18, seed 1; seed 2 now: 7.9 -> 19325; with the RMS taken
about the measured rest position:
which fits land there depends on the path). Data by converged forward integration of the held voltage from
rest through the bag extraction (``synth_rig.rig_experiments``), 1 um laser noise, ILD1320 quantisation,
never the harmonic balance the fit uses."""
import pytest

from dea_ros.identify import refinement
from dea_ros.identify.pipeline import identify
from dea_ros.identify.synth import DEFAULT_STATIC_MASSES_KG
from dea_ros.identify.synth_rig import rig_experiments, rig_protocol
from dea_ros.sim.plant import LASER_QUANTISATION_M

from fakes.membranes import F17

pytestmark = pytest.mark.numeric_heavy     # 17 sine records (~10 s): the humble stack runs it

FREQUENCIES_HZ = (0.2, 2.322, 4.645, 6.503, 7.896, 8.244, 8.3, 8.593, 8.941, 9.289, 9.638, 9.986, 10.334, 10.683,
                  11.2, 13.934, 40.0)


def test_a_refinement_that_leaves_the_static_points_is_done_again_without_the_unreachable_record(monkeypatch):
    exp, _rec = rig_experiments(F17, rig_protocol(F17, FREQUENCIES_HZ), seed=2,
                                other_masses_kg=DEFAULT_STATIC_MASSES_KG, quantisation_m=LASER_QUANTISATION_M)
    # Whether the first refinement follows the record onto another branch depends on its path (it did here
    # with seed 1 until session 19, with seed 2 since on numpy 2.4 / scipy 1.17, not on Humble's numpy 1.21 /
    # scipy 1.8): the first check says it left the static points; every later one is the real check.
    real = refinement._left_the_static_points
    calls = []

    def first_left(joint, start_chi2, static):
        calls.append(joint.block_chi2.get("static", 0.0))
        return True if len(calls) == 1 else real(joint, start_chi2, static)

    monkeypatch.setattr(refinement, "_left_the_static_points", first_left)
    res = identify(exp, evaluate_fit=False)
    again = [w for w in res.warnings if "left the static points" in w]
    assert len(calls) == 2, calls                             # the first refinement and the one done again
    assert again and "refined again from the two-stage result without the record(s) at 9.289 Hz" in again[0], \
        res.warnings
    assert res.joint is not None
    assert res.joint.block_chi2["static"] < 30.0                  # 13 static points
    assert res.joint.cost / res.joint.dof < 1.5
    st = res.statistics
    for name in ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"):
        i = st.names.index(name)
        truth = F17.relative_permittivity if name == "eps_r" else getattr(F17, name)
        assert abs(st.values[i] / truth - 1) < 0.01, (name, st.values[i], truth)
        assert st.ci_low[i] <= truth <= st.ci_high[i], (name, st.ci_low[i], st.ci_high[i], truth)
