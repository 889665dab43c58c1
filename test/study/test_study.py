"""Design studies: the spec, the designs, the per-design results against independent computations,
failures with their reasons, resuming, and the Dask engine against the serial run point by point."""
import json
import sys

import numpy as np
import pytest

from dea_ros.cli import main
from dea_ros.model import preset, static_equilibrium
from dea_ros.model.parameters import MembraneParameters
from dea_ros.solvers import SinePeriodic, solve_native
from dea_ros.study import (
    Engine,
    EngineError,
    SpecError,
    StudyInterrupted,
    dask_available,
    design_parameters,
    evaluate_design,
    parquet_available,
    parse_spec,
    read_results,
    run_study,
)

#: A tiny study: 4 designs (2 thicknesses x 2 masses), 10 frequencies over the resonance, 2 per chunk.
SMALL = {
    "name": "small",
    "base": "A2",
    "parameters": {"thickness_m": {"min": 3.0e-5, "max": 4.0e-5, "points": 2}, "mass_kg": [0.002, 0.004]},
    "excitation": {"amplitude_V": 2000.0, "f_min_Hz": 4.0, "f_max_Hz": 14.0},
    "sweep": {"points": 10, "branch_switching": False},
    "static": {"voltages": 5},
    "output": {"chunk_size": 2, "format": "csv"},
}


def spec_of(**changes):
    data = json.loads(json.dumps(SMALL))
    data.update(changes)
    return parse_spec(data)


# ---------------------------------------------------------------------------------------------- spec
@pytest.mark.parametrize("changes, field", [
    ({"parameters": {"colour": {"min": 1, "max": 2, "points": 2}}}, "colour"),
    ({"parameters": {"thickness_m": {"min": 3e-5, "max": 4e-5}}}, "parameters.thickness_m"),
    ({"parameters": {"thickness_m": {"min": 4e-5, "max": 3e-5, "points": 2}}}, "parameters.thickness_m"),
    ({"sampling": {"method": "sobol", "n": 10}}, "sampling.n"),
    ({"sampling": {"method": "random"}}, "sampling.method"),
    ({"sweep": {"harmonics": 0}}, "sweep.harmonics"),
    ({"output": {"format": "xlsx"}}, "output.format"),
    ({"plots": [["thickness_m", "k1_Pa"]]}, "plots[0]"),
    ({"breakdown_margin": 1.5}, "breakdown_margin"),
    ({"extra": 1}, "unknown key"),
])
def test_a_bad_spec_is_refused_naming_the_field(changes, field):
    with pytest.raises(SpecError, match=field.replace("[", r"\[").replace("]", r"\]")):
        spec_of(**changes)


def test_the_shipped_example_spec_is_valid():
    from dea_ros.model import config_dir
    from dea_ros.study import load_spec

    spec = load_spec(config_dir() / "studies" / "a2_family.yaml")
    assert spec.n_designs == 10000 and spec.method == "lhs" and spec.names[:2] == ["prestretch", "thickness_m"]
    assert spec.plots == [["prestretch", "thickness_m"], ["mass_kg", "amplitude_V"]]


def test_grid_is_the_full_product_and_samples_are_seeded_and_space_filling():
    grid = spec_of().designs()
    assert grid.shape == (4, 2)
    assert {tuple(r) for r in grid} == {(a, b) for a in (3e-5, 4e-5) for b in (0.002, 0.004)}
    lhs = {"method": "lhs", "n": 16, "seed": 3}
    params = {"thickness_m": {"min": 3e-5, "max": 4e-5}, "prestretch": {"min": 1.1, "max": 1.3},
              "mass_kg": {"min": 1e-3, "max": 4e-3, "scale": "log"}}
    a = spec_of(sampling=lhs, parameters=params).designs()
    b = spec_of(sampling=lhs, parameters=params).designs()
    assert np.array_equal(a, b) and a.shape == (16, 3)
    # Latin hypercube: exactly one sample in each of the 16 strata of every parameter
    strata = np.floor((a[:, 0] - 3e-5) / 1e-5 * 16).astype(int)
    assert sorted(strata) == list(range(16))
    strata_log = np.floor(np.log(a[:, 2] / 1e-3) / np.log(4.0) * 16).astype(int)
    assert sorted(strata_log) == list(range(16))
    sob = spec_of(sampling={"method": "sobol", "n": 16, "seed": 1}, parameters=params).designs()
    assert sob.shape == (16, 3) and np.all((sob[:, 1] >= 1.1) & (sob[:, 1] <= 1.3))


def test_prestretch_rescales_the_ogden_coefficients_as_eqs_8_9():
    mu = (3.0e5, -2.0e4, 1.5e3)
    beta, gamma = MembraneParameters.ogden_beta_gamma_from_mu(mu, 1.2)
    base = preset("A2").replace(prestretch=1.2, beta_Pa=beta, gamma_Pa=gamma)
    spec = spec_of(parameters={"prestretch": {"min": 1.1, "max": 1.4, "points": 2}})
    params, _exc = design_parameters(base, spec, [1.35])
    beta2, gamma2 = MembraneParameters.ogden_beta_gamma_from_mu(mu, 1.35)   # same material, new prestretch
    assert np.allclose(params.beta_Pa, beta2, rtol=1e-12) and np.allclose(params.gamma_Pa, gamma2, rtol=1e-12)
    fixed = parse_spec({**SMALL, "prestretch_rule": "fixed",
                        "parameters": {"prestretch": {"min": 1.1, "max": 1.4, "points": 2}}})
    assert design_parameters(base, fixed, [1.35])[0].beta_Pa == base.beta_Pa


# ------------------------------------------------------------------------------- one design's results
def test_a_design_row_agrees_with_independent_solves():
    """Stroke: the static equilibrium at the peak voltage solves eq. 20's force balance; peak: no
    independent harmonic-balance solve on a fine grid around it is larger, and it is within the grid step."""
    spec = spec_of(sweep={"points": 12, "branch_switching": False})
    base = preset("A2")
    row = evaluate_design(base, spec, 0, [3.5e-5, 0.003])
    assert row["status"] == "ok", row["message"]
    params, _ = design_parameters(base, spec, [3.5e-5, 0.003])
    d_top = row["d0_m"] + row["stroke_m"]
    from dea_ros.model.dynamics import DEAModel

    model = DEAModel.from_parameters(params)     # the force balance of eq. 20 at both rest positions
    weight = params.mass_kg * params.gravity_m_per_s2
    assert model.static_force_N(d_top, 2000.0 ** 2) == pytest.approx(weight, rel=1e-8)
    assert model.static_force_N(row["d0_m"], 0.0) == pytest.approx(weight, rel=1e-8)
    f_peak = row["peak_frequency_Hz"]
    assert 4.0 < f_peak < 14.0
    d0 = float(static_equilibrium(params, 0.0).displacement_m)
    fine = np.linspace(f_peak - 0.3, f_peak + 0.3, 13)
    rms = [solve_native(params, SinePeriodic(2000.0, f), n_harmonics=8).displacement_rms(d0) for f in fine]
    assert row["peak_d_rms_m"] >= max(rms) * (1 - 1e-6)
    assert abs(fine[int(np.argmax(rms))] - f_peak) <= 0.05 + 1e-9
    assert row["max_truncation_ratio"] < 1e-2 and row["warning"] == ""
    assert json.loads(row["bands"])[0][0] == "periodic"


@pytest.mark.parametrize("values, reason", [
    ([1.5e-5, 0.003], "breakdown limit"),       # 15 um x 100 V/um x 0.9 = 1350 V < 2000 V
    ([3.5e-5, 0.5], "no equilibrium"),          # 500 g: more than the membrane carries up to d = l0
])
def test_failures_carry_their_reason(values, reason):
    row = evaluate_design(preset("A2"), spec_of(), 0, values)
    assert row["status"] == "failed" and row["failure"] == reason, row
    assert row["message"]


def test_an_impossible_frequency_range_is_an_invalid_design():
    spec = spec_of(parameters={"f_min_Hz": [5.0, 30.0]}, excitation={"amplitude_V": 2000.0, "f_max_Hz": 14.0})
    assert evaluate_design(preset("A2"), spec, 1, [30.0])["failure"] == "invalid parameters"


def test_a_large_study_is_drawn_as_a_binned_map_with_the_band_regions(tmp_path):
    """Beyond SCATTER_MAX designs, markers would hide each other: bins coloured by their median and
    hatched regions where >= 50 % of the designs have a band. Synthetic rows with known regions."""
    from matplotlib.image import imread

    from dea_ros.study.plots import SCATTER_MAX, binned_panel, plot_maps

    rng = np.random.default_rng(3)
    n = SCATTER_MAX * 5
    x, y = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n)
    rows = [{"status": "ok" if i % 97 else "failed", "failure": "" if i % 97 else "no convergence",
             "thickness_m": 3e-5 + 1e-5 * x[i], "mass_kg": 0.002 + 0.002 * y[i],
             "peak_frequency_Hz": 8.0 + 4.0 * x[i], "stroke_m": 1e-4 * y[i],
             "quasi_periodic_width_Hz": 0.01 if x[i] < 0.5 else 0.0, "period_doubled_width_Hz": 0.0,
             "n_folds": 2 if y[i] > 0.7 else 0} for i in range(n)]
    spec = spec_of()
    (path,) = plot_maps(spec, rows, tmp_path)
    assert imread(path).shape[0] > 400
    # the regions: torus where x < 0.5, folds where y > 0.7, no period-doubling region
    from matplotlib.figure import Figure
    ax = Figure().subplots()
    ok = np.array([r["status"] == "ok" for r in rows])
    flags = [(x[ok] < 0.5, "r", "-", "//", "torus"), (np.zeros(ok.sum(), bool), "o", "-", "..", "pd"),
             (y[ok] > 0.7, "k", "--", "..", "folds")]
    handles = binned_panel(ax.figure, ax, x[ok], y[ok], (8.0 + 4.0 * x)[ok], flags, "f")
    assert [h.get_label() for h in handles] == ["torus in >= 50 % of designs", "folds in >= 50 % of designs"]
    mesh = ax.collections[0].get_array().reshape(-1)
    assert np.nanmin(mesh) > 8.0 and np.nanmax(mesh) < 12.0     # medians of 8 + 4 x


# ----------------------------------------------------------------------------------- runs and resume
@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    summary = run_study(spec_of(), out, progress=False, plots=True)
    return out, summary, read_results(summary["results"])


def test_serial_run_writes_results_and_maps(serial_run):
    out, summary, table = serial_run
    assert summary["designs"] == 4 and summary["ok"] == 4 and summary["chunks_computed"] == 2
    assert list(table["design"]) == [0, 1, 2, 3]
    assert (out / "map_thickness_m_mass_kg.png").stat().st_size > 1000
    # a heavier mass on the same membrane: lower resonance, larger rest displacement
    for t in (3e-5, 4e-5):
        light = (table["thickness_m"] == t) & (table["mass_kg"] == 0.002)
        heavy = (table["thickness_m"] == t) & (table["mass_kg"] == 0.004)
        assert table["peak_frequency_Hz"][heavy][0] < table["peak_frequency_Hz"][light][0]
        assert table["d0_m"][heavy][0] > table["d0_m"][light][0]


def test_an_interrupted_study_resumes_to_the_same_file(serial_run, tmp_path):
    _out, _summary, _table = serial_run
    full = serial_run[1]["results"]

    def stop(k, rows):
        raise KeyboardInterrupt

    with pytest.raises(StudyInterrupted, match="resume"):
        run_study(spec_of(), tmp_path, progress=False, plots=False, on_chunk=stop)
    assert len(list((tmp_path / "chunks").glob("chunk_*.json"))) == 1
    computed = []
    summary = run_study(spec_of(), tmp_path, progress=False, plots=False, on_chunk=lambda k, r: computed.append(k))
    assert summary["chunks_resumed"] == 1 and summary["chunks_computed"] == 1 and len(computed) == 1
    with open(full, "rb") as a, open(summary["results"], "rb") as b:
        assert a.read() == b.read()
    again = run_study(spec_of(), tmp_path, progress=False, plots=False)
    assert again["chunks_computed"] == 0
    with pytest.raises(SpecError, match="another spec"):
        run_study(spec_of(excitation={"amplitude_V": 1500.0, "f_min_Hz": 4.0, "f_max_Hz": 14.0}), tmp_path,
                  progress=False, plots=False)


@pytest.mark.skipif(not dask_available(), reason="dask.distributed not installed (extra [study])")
def test_dask_local_cluster_with_two_workers_matches_the_serial_run_point_by_point(serial_run, tmp_path):
    _out, _summary, serial = serial_run
    # Parquet where pyarrow works (a NumPy-2 pyarrow under Jazzy's numpy 1.26 imports but cannot: CSV)
    spec = spec_of(output={"chunk_size": 1, "format": "parquet" if parquet_available() else "csv"})
    with Engine("dask", workers=2) as engine:
        assert engine.worker_count() == 2
        summary = run_study(spec, tmp_path, engine=engine, progress=False, plots=False)
    assert summary["engine"].startswith("dask") and summary["chunks_computed"] == 4
    table = read_results(summary["results"])
    assert set(table) == set(serial)
    for name, col in serial.items():
        if isinstance(col, list):
            if name == "bands":   # edges located by bisection to ~1e-6 of the frequency
                for a, b in zip(col, table[name]):
                    ba, bb = json.loads(a), json.loads(b)
                    assert [x[0] for x in ba] == [x[0] for x in bb]
                    assert np.allclose([x[1:] for x in ba], [x[1:] for x in bb], rtol=1e-6)
            elif name == "folds_Hz":   # JSON lists of floats: the last bits follow the BLAS build of each process
                for a, b in zip(col, table[name]):
                    ja, jb = json.loads(a), json.loads(b)
                    assert len(ja) == len(jb) and np.allclose(ja, jb, rtol=1e-9), (name, a, b)
            else:
                assert col == table[name], name
        else:
            assert np.allclose(col.astype(float), table[name].astype(float), rtol=1e-6, equal_nan=True), name


def test_processes_engine_matches_the_serial_run(serial_run, tmp_path):
    _out, _summary, serial = serial_run
    with Engine("processes", workers=2) as engine:
        summary = run_study(spec_of(), tmp_path, engine=engine, progress=False, plots=False)
    table = read_results(summary["results"])
    assert np.allclose(serial["peak_frequency_Hz"], table["peak_frequency_Hz"], rtol=1e-6)
    assert np.allclose(serial["stroke_m"], table["stroke_m"], rtol=1e-9)


# ------------------------------------------------------------------------------------------ the CLI
def test_cli_scheduler_without_dask_names_the_fix(tmp_path, monkeypatch, capsys):
    spec = tmp_path / "s.yaml"
    spec.write_text(json.dumps(SMALL))
    monkeypatch.setitem(sys.modules, "distributed", None)     # import distributed -> ImportError
    with pytest.raises(EngineError, match="pip install"):
        Engine(scheduler="tcp://127.0.0.1:8786")
    code = main(["study", str(spec), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:8786"])
    assert code == 2 and "needs Dask" in capsys.readouterr().err
    # the serial path needs nothing optional
    code = main(["study", str(spec), "--out", str(tmp_path / "o"), "--engine", "serial", "--quiet", "--no-plots"])
    assert code == 0 and (tmp_path / "o" / "results.csv").is_file()


def test_cli_bad_spec_exits_2_naming_the_field(tmp_path, capsys):
    spec = tmp_path / "s.yaml"
    spec.write_text("parameters:\n  thickness_m: {min: 3.0e-5}\n")
    assert main(["study", str(spec), "--out", str(tmp_path / "o")]) == 2
    assert "parameters.thickness_m" in capsys.readouterr().err
