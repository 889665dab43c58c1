"""CLI entry points: synth and identify (exit codes, JSON, outputs), and argparse registration."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

import numpy as np
import pytest

from dea_ros.cli import main
from dea_ros.cli.identify import register
from dea_ros.model import MembraneParameters, preset


def test_register_adds_both_subcommands():
    parser = argparse.ArgumentParser(prog="dea-ros")
    sub = parser.add_subparsers(dest="command", required=True)
    parsers = register(sub)
    assert set(parsers) == {"synth", "identify"}
    args = parser.parse_args(["identify", "data", "--out", "o", "--json", "--quiet", "--static-method", "paper",
                              "--frequency-method", "integration"])
    assert args.func.__name__ == "cmd_identify" and args.static_method == "paper" and args.data == ["data"]
    assert args.frequency_method == "integration" and args.json and args.quiet
    args = parser.parse_args(["synth", "--membrane", "A1", "--noise", "1e-6", "--out", "d", "--seed", "3"])
    assert args.func.__name__ == "cmd_synth" and args.seed == 3
    with pytest.raises(SystemExit):
        parser.parse_args(["synth", "--membrane", "A1", "--params", "x.yaml", "--noise", "1e-6", "--out", "d"])


def test_synth_then_identify_json(tmp_path, capsys):
    data = tmp_path / "a2"
    rc = main(["synth", "--membrane", "A2", "--noise", "1e-6", "--out", str(data), "--seed", "5",
               "--frequencies", "2,8.3,9.5,11.2,40", "--quiet"])
    assert rc == 0 and (data / "manifest.yaml").is_file() and (data / "truth.yaml").is_file()
    out = tmp_path / "fit"
    rc = main(["identify", str(data), "--out", str(out), "--json", "--quiet", "--no-plots",
               "--uncertainty-samples", "8"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["membrane"] == "A2"
    band = report["uncertainty"][0]          # the frequency-response band (8 samples keep the test short)
    assert band["samples"] + band["failed_samples"] == 8 and band["amplitude_V"] == 2500.0
    lo, hi = band["peak_frequency_ci_Hz"]
    assert 0 < lo < hi < 2 * band["peak_frequency_Hz"]
    assert set(report["timings_s"]) >= {"load", "static_fit", "dynamic_fit", "evaluation", "report", "total"}
    assert report["dynamic_fit"]["fit_frequencies_Hz"] == [8.3, 11.2, 40.0]  # the paper's, those present
    assert report["metrics"]["steps"][0]["rms_error_um"] == pytest.approx(1.0, abs=0.05)
    fitted = MembraneParameters.from_yaml(out / "params.yaml")
    assert fitted.k1_Pa == pytest.approx(preset("A2").k1_Pa, rel=0.01)
    assert fitted.k1_Pa == pytest.approx(report["parameters"]["k1_Pa"], rel=1e-12)
    assert (out / "report.md").is_file() and not (out / "step.png").exists()


def test_identify_bad_data_exits_2_with_the_location(synthetic, tmp_path, capsys):
    import shutil

    folder = tmp_path / "bad"
    shutil.copytree(synthetic("A2")[0], folder)
    static = folder / "static.csv"
    lines = static.read_text().splitlines()
    cells = lines[3].split(",")
    lines[3] = ",".join([cells[0], "nan"] + cells[2:])
    static.write_text("\n".join(lines) + "\n")
    rc = main(["identify", str(folder), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "static.csv line 4, column 'voltage_V'" in err and "not finite" in err
    assert not (tmp_path / "o" / "params.yaml").exists()


def test_synth_rejects_noise_in_micrometres(tmp_path, capsys):
    rc = main(["synth", "--membrane", "A1", "--noise", "1", "--out", str(tmp_path / "x"), "--quiet"])
    assert rc == 2 and "metres expected" in capsys.readouterr().err


def test_python_dash_m_entry_point():
    proc = subprocess.run([sys.executable, "-m", "dea_ros.cli", "identify", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "--frequency-method" in proc.stdout and "--static-method" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "dea_ros.cli", "identify", "/nonexistent",
                           "--out", "/tmp/never", "--quiet"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "no manifest.yaml" in proc.stderr
    assert np.isfinite(proc.returncode)
