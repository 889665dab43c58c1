"""The dynamic fit's start on membranes whose step sees the creep poorly (issue 21, item 2): two
membranes of the family benchmark (bench/bench_coverage_family.py F00, creep 7.4 s, and F03, creep
23.7 s) on which the former start (a raw scan of linearised starts over the creep time) sent the
paper's fit into the wrong basin (eta1 x0.036 on F00; eta1 -99 %, eta2 at its lower bound on
F03). Data by converged forward integration (the step from rest, DOP853; the sine records from the
converged periodic orbit), 1 um laser noise, the ILD1320 quantisation, a random start phase, several
noise seeds; never the harmonic balance the fit uses."""
from __future__ import annotations

import numpy as np
import pytest

from dea_ros.identify.dynamic_fit import fit_dynamic
from dea_ros.identify.pipeline import identify
from dea_ros.identify.static_fit import fit_static
from dea_ros.identify.synth import synthesize_experiments
from dea_ros.model import preset
from dea_ros.sim.plant import LASER_QUANTISATION_M

from .conftest import PAPER_FREQUENCIES_HZ

#: F00 of the family: creep time eta1/k1 = 7.4 s, resonance 10.4 Hz, softening-free, thin (26 um).
LONG = preset("A2").replace(
    name="F00", prestretch=1.10464, thickness_m=26.2057e-6, plate_radius_m=4.59556e-3,
    electrode_width_m=13.2475e-3, mass_kg=2.29736e-3, relative_permittivity=2.59193, k1_Pa=17.3562e6,
    eta1_Pa_s=128.207e6, eta2_Pa_s=10.7139e3, beta_Pa=(-801206.3, -427754.0, 1220336.4),
    gamma_Pa=(93358.6, -791660.2, 15445.1))
#: F03 of the family: creep time 23.7 s (six times the 4 s step), resonance 13.0 Hz.
VERY_LONG = preset("A2").replace(
    name="F03", prestretch=1.35207, thickness_m=38.0213e-6, plate_radius_m=5.23852e-3,
    electrode_width_m=14.0355e-3, mass_kg=2.42405e-3, relative_permittivity=2.54935, k1_Pa=44.2631e6,
    eta1_Pa_s=1047.89e6, eta2_Pa_s=14.3069e3, beta_Pa=(-204343.9, -120088.4, 435572.2),
    gamma_Pa=(62074.9, -601032.1, -34509.1))

_CACHE: dict = {}


def _data(params, seed):
    key = (params.name, seed)
    if key not in _CACHE:
        _CACHE[key] = synthesize_experiments(params, 1e-6, seed=seed, sine_frequencies_Hz=PAPER_FREQUENCIES_HZ,
                                             series_frequencies_Hz=(), quantisation_m=LASER_QUANTISATION_M,
                                             random_start_phase=True)
    return _CACHE[key]


@pytest.mark.parametrize("params", [LONG, VERY_LONG], ids=["creep7s", "creep24s"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_stage1_lands_in_the_true_creep_basin(params, seed):
    """The paper's fit (eqs. 22-24) from the data-derived start: the start is the minimum of the cost's
    profile over the creep time, and the fit ends in the true basin (the wrong one had eta1 -96..-99 %)."""
    exp = _data(params, seed)
    static = fit_static(exp.all_static(), exp.template_parameters(), prior_from_template=False)
    res = fit_dynamic(static.parameters, exp.steps, exp.sines, noise_m=exp.sensor_noise_m)
    p = res.parameters
    scan = res.initial["scan"]
    # the profile's best point is a long creep time, not the short-creep basin (0.1-0.3 s) the former
    # start chose; the profile is truncated (12 evaluations per tau), so its minimum may sit one grid
    # point beyond the truth (F00 seed 3: 31.6 s for 7.4 s) -- the fit from its minima decides
    assert min(scan, key=lambda s: s["cost"])["tau_s"] >= 1.0, scan
    short = [s["cost"] for s in scan if s["tau_s"] <= 0.35]
    assert min(short) > 3 * min(s["cost"] for s in scan)
    assert abs(p.eta1_Pa_s / params.eta1_Pa_s - 1) < 0.2
    assert abs(p.k1_Pa / params.k1_Pa - 1) < 0.03
    assert abs(p.eta2_Pa_s / params.eta2_Pa_s - 1) < 0.03


@pytest.mark.parametrize("params", [LONG, VERY_LONG], ids=["creep7s", "creep24s"])
def test_identification_recovers_long_creep_membranes_with_intervals_that_hold(params):
    """The whole identification (stage 1, classification, joint refinement) on seed 1: within 1.5 % or,
    for a parameter the data determine less well (eta1 of F03: 95 % half-width ~10 %), half its interval,
    and the 95 % intervals contain the truth."""
    exp = _data(params, 1)
    res = identify(exp, evaluate_fit=False)
    assert res.joint is not None, res.warnings
    st = res.statistics
    for name in ("eps_r", "k1_Pa", "eta1_Pa_s", "eta2_Pa_s"):
        i = st.names.index(name)
        truth = params.relative_permittivity if name == "eps_r" else getattr(params, name)
        assert abs(st.values[i] / truth - 1) < max(0.015, 0.5 * st.relative_ci[i]), (name, st.values[i], truth)
        assert st.ci_low[i] <= truth <= st.ci_high[i], (name, st.ci_low[i], st.ci_high[i], truth)
        assert np.isfinite(st.std_error[i])
