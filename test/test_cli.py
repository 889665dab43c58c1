"""The dea-ros command line: readable and JSON output, plots, clear errors with exit code 2."""
import json
import subprocess
import sys

import pytest

from dea_ros.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_equilibrium_text_and_json(capsys):
    code, out, _ = run(capsys, "equilibrium", "--membrane", "LP1", "--voltage", "0", "2500")
    assert code == 0 and "824.476" in out  # LP1 at rest, um
    code, out, _ = run(capsys, "equilibrium", "--membrane", "A2", "--json")
    data = json.loads(out)
    assert data["membrane"] == "A2" and len(data["equilibria"]) == 4


def test_simulate_writes_csv_and_plot(capsys, tmp_path):
    csv, png = tmp_path / "s.csv", tmp_path / "s.png"
    code, out, _ = run(capsys, "simulate", "--membrane", "A1", "--step", "2200", "--duration", "0.5",
                       "--out", str(csv), "--plot", str(png), "--json")
    assert code == 0
    data = json.loads(out)
    assert data["final_displacement_m"] > data["initial_displacement_m"]
    assert csv.read_text().startswith("time_s,voltage_V,displacement_m")
    assert png.stat().st_size > 10_000
    # the CSV can be fed back as an input
    code, out, _ = run(capsys, "simulate", "--membrane", "A1", "--input-csv", str(csv), "--duration", "0.5")
    assert code == 0 and "Simulated membrane A1" in out


def test_sweep_json_fields(capsys, tmp_path):
    png = tmp_path / "f.png"
    code, out, _ = run(capsys, "sweep", "--membrane", "A2", "--amplitude", "2500", "--fmin", "0.1",
                       "--fmax", "20", "--points", "200", "--harmonics", "6", "--method", "native",
                       "--json", "--plot", str(png))
    assert code == 0
    data = json.loads(out)
    p = data["points"][0]
    for key in ("frequency_Hz", "d_rms_m", "mean_displacement_m", "stable", "stability",
                "iterations", "wall_time_s"):
        assert key in p
    assert 9.0 < data["resonance_peak"]["frequency_Hz"] < 10.0
    assert png.stat().st_size > 10_000


def test_sweep_text_output_mentions_peak(capsys):
    code, out, _ = run(capsys, "sweep", "--membrane", "A1", "--fmin", "5", "--fmax", "15", "--points", "21")
    assert code == 0 and "resonance peak" in out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["equilibrium", "--params", "/no/such.yaml"], "no such parameters file"),
        (["equilibrium", "--membrane", "Z9"], "unknown membrane preset"),
        (["sweep", "--fmin", "5", "--fmax", "1"], "--fmax"),
        (["sweep", "--harmonics", "0"], "--harmonics"),
        (["simulate", "--duration", "nan"], "--duration"),
        (["equilibrium", "--mass", "-1"], "mass_kg"),
    ],
)
def test_bad_input_exits_2_with_a_message(capsys, argv, message):
    code, _, err = run(capsys, *argv)
    assert code == 2
    assert message in err


def test_console_script_entry_point():
    out = subprocess.run([sys.executable, "-m", "dea_ros.cli", "equilibrium", "--json"],
                         capture_output=True, text=True, check=True)
    assert json.loads(out.stdout)["membrane"] == "A2"
