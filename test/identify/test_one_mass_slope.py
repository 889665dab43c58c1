"""A rig with one mass: the static staircase cannot see the slope sigma_h'(1), the step and the sines can.

``fit_bag`` holds sigma_h'(1) at the base value in the static fit and stage 1 (the staircase at one mass
determines it only in combination with sigma_h(1) and eps_r; stage 1 started from the static fit's free slope
failed on a demo bag) and fits it in the joint refinement (``joint_slope``). Held there as well, the base's
slope (A2's, 3.9 % from the mock membrane's) moves sigma_h(1) and k1 beyond their intervals: on the demo's
'paper' protocol on the mock membrane (250 Hz records), sigma_h(1)'s interval
misses the truth in four of six seeds (z +2.7..+4.6; seed 3 +2.76 with each static point weighted by its own
uncertainty, session 19) and k1's in two (z +2.05, +2.19; seed 3 now +1.96); fitted, |z| <= 1.6 for
both (docs/benchmarks.md, issue 21 session 17). The data here: that protocol on that membrane from converged
forward integration of the held voltage with 1 um laser noise and the laser's quantisation
(:func:`~dea_ros.identify.synth_rig.record_protocol`), never from the harmonic balance the fit uses."""
import pytest

from dea_ros.identify.bag_experiments import BagSignals, experiment_record, experiments_from_signals, pass_metadata_name
from dea_ros.identify.pipeline import identify
from dea_ros.identify.protocols import load_protocol
from dea_ros.identify.report import write_parameters
from dea_ros.identify.static_fit import stress_combinations
from dea_ros.identify.synth_rig import T0_NS, record_protocol
from dea_ros.model import load_parameters
from dea_ros.model.parameters import config_dir
from dea_ros.sim.plant import LASER_QUANTISATION_M

pytestmark = pytest.mark.numeric_heavy
RATE_HZ = 250.0


@pytest.fixture(scope="module")
def one_mass_experiments():
    truth = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")
    protocol = load_protocol("paper")
    rec = record_protocol(truth, protocol, 3, 1e-6, LASER_QUANTISATION_M, RATE_HZ, True)
    t = rec.time_s + T0_NS * 1e-9
    meta = {pass_metadata_name(1): experiment_record(protocol, rec.segments, T0_NS, len(rec.segments), False,
                                                     RATE_HZ, truth.name)}
    signals = BagSignals(t, rec.voltage_V, t.copy(), rec.displacement_measured_m, meta)
    return truth, experiments_from_signals(signals, "paper", membrane="A2")


def _z(result, name, true_value):
    st = result.statistics
    i = st.names.index(name)
    return (st.values[i] - true_value) / st.std_error[i], st.values[i] / true_value - 1


def test_the_joint_refinement_fits_the_slope_a_one_mass_staircase_cannot_see(one_mass_experiments, tmp_path):
    truth, experiments = one_mass_experiments
    assert len({float(m) for st in experiments.static for m in st.mass_kg if m > 0}) == 1
    true_slope = stress_combinations(truth.beta_Pa, truth.gamma_Pa)[1]
    held = identify(experiments, evaluate_fit=False, stress_terms=1, joint_slope=False)
    free = identify(experiments, evaluate_fit=False, stress_terms=1, joint_slope=True)
    sigma_1 = stress_combinations(truth.beta_Pa, truth.gamma_Pa)[0]
    # the premise: held at the base's slope, sigma_h(1) is moved beyond its 95 % interval and k1 by more than
    # 1.5 standard errors (+1.96 with this seed since each static point is weighted by its own uncertainty)
    assert "sigma_h'(1)_Pa" not in held.statistics.names
    assert _z(held, "sigma_h(1)_Pa", sigma_1)[0] > 1.96
    assert _z(held, "k1_Pa", truth.k1_Pa)[0] > 1.5
    # fitted in the joint refinement: the intervals of the slope, sigma_h(1), k1 and eta2 hold the truth (not
    # asserted: eps_r's, z +3.4 either way here, and eta1's bias at 250 Hz samples, issue 21's open items)
    assert "sigma_h'(1)_Pa" in free.statistics.names
    for name, value in (("sigma_h'(1)_Pa", true_slope), ("sigma_h(1)_Pa", sigma_1), ("k1_Pa", truth.k1_Pa),
                        ("eta2_Pa_s", truth.eta2_Pa_s)):
        z, rel = _z(free, name, value)
        assert abs(z) < 1.96, (name, z, rel)
    assert abs(_z(free, "k1_Pa", truth.k1_Pa)[1]) < 0.005
    # params.yaml's header says which: held, or identified with the others
    assert held.slope_fitted is False and free.slope_fitted is True
    held_header = write_parameters(held, tmp_path / "held.yaml").read_text().split("membrane:")[0]
    free_header = write_parameters(free, tmp_path / "free.yaml").read_text().split("membrane:")[0]
    assert "HELD at the base value" in held_header and "its slope and eps_r" not in held_header
    assert "its slope and eps_r" in free_header and "HELD" not in free_header
