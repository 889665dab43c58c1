"""Report outputs: parameters YAML, figures, report.md, result.json; records aligned on the phase of u^2."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from dea_ros.identify.experiments import SineSeries
from dea_ros.identify.evaluation import series_model
from dea_ros.identify.report import write_report
from dea_ros.model import MembraneParameters, preset
from dea_ros.solvers.sweep import frequency_sweep
from dea_ros.solvers.inputs import SinePeriodic, SineVoltage
from dea_ros.solvers.steady_state import shoot_periodic_orbit


def test_report_folder(identified, tmp_path):
    res = identified("A2", "paper")
    paths = write_report(res, tmp_path)
    fitted = MembraneParameters.from_yaml(tmp_path / "params.yaml")
    assert fitted == res.parameters
    text = (tmp_path / "params.yaml").read_text()
    assert "not individually identifiable" in text  # the header says what beta/gamma are
    meta = yaml.safe_load(text)["identification"]
    assert meta["stress_derivatives"].startswith("w.r.t. lambda_r")
    assert meta["dsigma_h_dlambda(1)_Pa"] > 0
    for name in ("static.png", "step.png", "frequency.png", "sine_series.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    md = (tmp_path / "report.md").read_text()
    for needle in ("## Warnings", "## Parameters (Table II)", "| Viscoelastic model | k1 |", "IAE [mm s]",
                   "Resonance peak, model [Hz]", "## Timings", "Correlation matrix", "![Step response",
                   "d sigma_h / d lambda_r at 1", "u = U sin(2 pi f t)", "## Sine records",
                   "## Joint refinement"):
        assert needle in md
    for w in res.warnings:
        assert w in md
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["parameters"]["eta2_Pa_s"] == res.parameters.eta2_Pa_s
    assert data["joint_fit"]["statistics"]["parameters"]["k1_Pa"]["relative_ci"] < 0.01
    assert paths["report_s"] > 0


def _record(orbit, f, phase0, waveform, periods=4, fs=1000.0):
    """A record starting at an arbitrary phase of the sine (t = 0 is not a zero crossing)."""
    t = np.arange(int(periods * fs / f)) / fs
    u = SineVoltage(2500.0, f, phase_rad=phase0)(t)
    if waveform == "abs_sine":
        u = np.abs(u)
    d = orbit.evaluate(t + phase0 / (2 * np.pi * f))[0]
    return SineSeries(f, t, u, d)


@pytest.mark.parametrize("waveform", ["sine", "abs_sine"])
@pytest.mark.parametrize("f_Hz, kind", [(9.3, "T/2"), (18.8, "T")])
def test_records_and_model_are_aligned(waveform, f_Hz, kind):
    """On a record the model reproduces exactly (integrated orbit of the same parameters), the report's
    model curve lies on the data for U sin and |U sin|, T/2 and period-doubled responses alike; a
    model aligned on the voltage's own f component would be off by up to the whole swing."""
    p = preset("A2")
    sweep = frequency_sweep(p, SinePeriodic(2500.0, 1.0), [f_Hz - 2.0, f_Hz], n_harmonics=8, realised=False)
    branch = sweep.branch("T/2" if kind == "T/2" else "T")
    hb = [pt for pt in branch.points if abs(pt.frequency_Hz - f_Hz) < 1e-9][0].solution
    orbit = shoot_periodic_orbit(p, SinePeriodic(2500.0, f_Hz), hb.evaluate(0.0)[:, 0])
    for phase0 in (0.7, 2.9):
        rec = _record(orbit, f_Hz, phase0, waveform)
        model, _phase = series_model(p, rec, 2500.0, solution=hb)
        swing = np.ptp(rec.displacement_m)
        assert np.sqrt(np.mean((model - rec.displacement_m) ** 2)) < 1e-5 * swing
        shifted = hb.evaluate(rec.time_s + (phase0 + 0.5) / (2 * np.pi * f_Hz))[0]   # 30 deg of the sine off
        assert np.sqrt(np.mean((shifted - rec.displacement_m) ** 2)) > 0.05 * swing
