"""Report outputs: parameters YAML, figures, report.md, result.json."""
from __future__ import annotations

import json

from dea_ros.identify.report import write_report
from dea_ros.model import MembraneParameters


def test_report_folder(identified, tmp_path):
    res = identified("A2", "paper")
    paths = write_report(res, tmp_path)
    fitted = MembraneParameters.from_yaml(tmp_path / "params.yaml")
    assert fitted == res.parameters
    text = (tmp_path / "params.yaml").read_text()
    assert "not individually identifiable" in text  # the header says what beta/gamma are
    for name in ("static.png", "step.png", "frequency.png", "sine_series.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    md = (tmp_path / "report.md").read_text()
    for needle in ("## Warnings", "## Parameters (Table II)", "| Viscoelastic model | k1 |", "IAE [mm s]",
                   "Resonance peak, model [Hz]", "## Timings", "Correlation matrix", "![Step response"):
        assert needle in md
    for w in res.warnings:
        assert w in md
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["parameters"]["eta2_Pa_s"] == res.parameters.eta2_Pa_s
    assert data["dynamic_fit"]["statistics"]["parameters"]["k1_Pa"]["relative_ci"] < 0.01
    assert paths["report_s"] > 0
