"""Each static point weighted by its own uncertainty in the joint fit (issue 21, session 19).

A static point is the mean of the laser's samples over its measurement window: its standard uncertainty is
the laser noise over the square root of the samples it averages, and the points of one run differ (the coverage
family: the 0 V points at the other masses scatter by 0.02-0.04 um, the rig's static segments by 0.05-0.12 um).
One pooled sigma trusted the latter too much and made the intervals of the parameters they determine (k1,
eps_r) too narrow. The data state each point's uncertainty (``StaticData.std_error_m``: the bag extraction, the
synthesis); ``refinement.static_sigma`` weights each point with its own, scaled up where the static fit's
residuals scatter more than they say (a model error; by sqrt(chi^2/dof) times t/z)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from dea_ros.identify.bag_experiments import BagSignals, experiment_record, experiments_from_signals, pass_metadata_name
from dea_ros.errors import ExperimentError
from dea_ros.identify.experiments import StaticData, load_experiment_set, write_experiment_set
from dea_ros.identify.protocols import Protocol
from dea_ros.identify.refinement import static_sigma
from dea_ros.identify.static_fit import fit_static
from dea_ros.identify.synth import LaserReadings, static_points
from dea_ros.identify.synth_rig import T0_NS, record_protocol
from dea_ros.model import config_dir, load_parameters, preset
from dea_ros.sim.plant import LASER_QUANTISATION_M

from fakes.membranes import F05

MOCK = load_parameters(config_dir() / "rig" / "mock_membrane.yaml")


def _points(samples_per_point, seed=3, scale=1.0):
    """F05's points at 0 V (three masses) and at four voltages (its mass), each the mean of its own number of
    samples with 1 um noise; their stated uncertainties ``scale`` x the true ones."""
    rng = np.random.default_rng(seed)
    laser = LaserReadings(1e-6, 0.0, rng)
    parts = [static_points(F05, laser, [m], (), n) for m, n in zip((0.002, 0.004, 0.006), samples_per_point[:3])]
    voltages_V = (1000.0, 1500.0, 2000.0, 2500.0)
    parts += [static_points(F05, laser, (), [u], n) for u, n in zip(voltages_V, samples_per_point[3:])]
    data = StaticData(np.concatenate([p.mass_kg for p in parts]), np.concatenate([p.voltage_V for p in parts]),
                      np.concatenate([p.displacement_m for p in parts]), "test static",
                      std_error_m=scale * np.concatenate([p.std_error_m for p in parts]))
    return data, fit_static(data, preset("A2").replace(**{k: getattr(F05, k) for k in (
        "prestretch", "thickness_m", "plate_radius_m", "electrode_width_m", "mass_kg")}))


def _recorded_staircase():
    """The mock membrane's staircase as the rig records it, cut by the bag extraction (1 s windows at 500 Hz)."""
    protocol = Protocol.from_dict({"name": "staircase", "membrane": "A2", "mass_kg": 0.003, "segments": [
        {"kind": "static", "voltages_V": [0, 2000, 2500, 0], "hold_s": 10.0, "measure_s": 1.0}]})
    rec = record_protocol(MOCK, protocol, 2, 1e-6, LASER_QUANTISATION_M, 500.0, True)
    t = rec.time_s + T0_NS * 1e-9
    meta = {pass_metadata_name(1): experiment_record(protocol, rec.segments, T0_NS, len(rec.segments), False,
                                                     500.0, MOCK.name)}
    return experiments_from_signals(BagSignals(t, rec.voltage_V, t.copy(), rec.displacement_measured_m, meta),
                                    "staircase", membrane="A2")


def test_synthetic_and_recorded_points_state_the_noise_over_the_root_of_their_samples():
    laser = LaserReadings(1e-6, 0.0, np.random.default_rng(1))
    pts = static_points(F05, laser, (0.002, 0.004), (2000.0,), 400)
    assert np.allclose(pts.std_error_m, 1e-6 / 20.0)
    # the bag extraction: the run's laser noise over the square root of each window's samples
    std = _recorded_staircase().all_static().std_error_m
    per_sample = math.hypot(1e-6, LASER_QUANTISATION_M / math.sqrt(12.0))
    assert std.shape == (4,)
    assert np.all(np.abs(std * math.sqrt(500.0) / per_sample - 1.0) < 0.15), std   # the noise estimate's spread


def test_an_experiment_folder_keeps_the_points_uncertainties(tmp_path):
    exp = _recorded_staircase()
    folder = tmp_path / "exp"
    write_experiment_set(exp, folder)
    static_csv = next(folder.glob("static*.csv"))
    assert "displacement_std_m" in static_csv.read_text()
    back = load_experiment_set(folder)
    assert np.allclose(back.all_static().std_error_m, exp.all_static().std_error_m, rtol=1e-9)
    # a zero uncertainty is refused, naming the column and the fix
    lines = static_csv.read_text().splitlines()
    last = lines[-1].split(",")
    static_csv.write_text("\n".join(lines[:-1] + [",".join(last[:-1] + ["0"])]) + "\n")
    with pytest.raises(ExperimentError, match="displacement_std_m.*> 0 m"):
        load_experiment_set(folder)


def test_each_point_is_weighted_with_its_own_uncertainty_when_the_residuals_agree_with_them():
    samples = (4000, 4000, 4000, 250, 250, 250, 250)         # long 0 V means, short staircase levels: 4x apart
    data, fit = _points(samples, seed=1)
    sig = static_sigma(fit, data)
    chi2 = float(np.sum((fit.residuals_m / data.std_error_m) ** 2))
    assert chi2 <= fit.statistics.dof                        # the premise: the residuals agree with the stated
    assert np.ndim(sig) == 1 and sig.size == data.n_points
    assert np.allclose(sig, data.std_error_m)
    assert sig[3] / sig[0] == pytest.approx(4.0)
    # without stated uncertainties: one pooled value, as before
    pooled = StaticData(data.mass_kg, data.voltage_V, data.displacement_m, "no stated uncertainty")
    assert np.ndim(static_sigma(fit, pooled)) == 0


def test_stated_uncertainties_smaller_than_the_scatter_are_scaled_up_to_it():
    samples = (4000, 4000, 4000, 250, 250, 250, 250)
    data, fit = _points(samples, seed=1, scale=0.1)          # the data understate their errors 10x
    sig = static_sigma(fit, data)
    dof = fit.statistics.dof
    t_over_z = scipy_stats.t.ppf(0.975, dof) / scipy_stats.norm.ppf(0.975)
    ratio = float(np.sum((fit.residuals_m / sig) ** 2)) / dof
    assert ratio == pytest.approx(1.0 / t_over_z ** 2)        # scaled to the residuals' scatter, times t/z
    assert sig[3] / sig[0] == pytest.approx(4.0)
