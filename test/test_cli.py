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


@pytest.fixture
def bad_files(tmp_path):
    """Slips a user can make with input files."""
    files = {
        "deep": ("a: " + "[" * 600 + "]" * 600 + "\n").encode(),
        "binary": bytes(range(256)) * 20,
        "text_values": b"time_s,voltage_V\n0,0\n0.5,abc\n1,2500\n",
        "kilovolts": b"time_s,voltage_V\n0,0\n0.5,2.5\n1,2.2\n",
        "negative": b"time_s,voltage_V\n0,0\n0.5,-2500\n1,2500\n",
        "time_backwards": b"time_s,voltage_V\n0,0\n0.5,2500\n0.2,2500\n",
        "one_row": b"time_s,voltage_V\n0,2500\n",
        "header_only": b"time_s,voltage_V\n",
        "existing": b"x",
    }
    paths = {}
    for name, content in files.items():
        paths[name] = tmp_path / (f"{name}.yaml" if name == "deep" else f"{name}.csv")
        paths[name].write_bytes(content)
    return paths


@pytest.mark.parametrize(
    "argv, message",
    [
        (["equilibrium", "--params", "{deep}"], "--params {deep}: nested too deeply"),
        (["equilibrium", "--params", "{binary}"], "--params {binary}: not a text file"),
        (["simulate", "--input-csv", "{binary}"], "--input-csv {binary}: not a CSV"),
        (["simulate", "--input-csv", "{text_values}"], "--input-csv {text_values}: line 3"),
        (["simulate", "--input-csv", "{kilovolts}"], "this looks like kV"),
        (["simulate", "--input-csv", "{negative}"], "negative voltage -2500 V"),
        (["simulate", "--input-csv", "{time_backwards}"], "--input-csv {time_backwards}: time_s"),
        (["simulate", "--input-csv", "{one_row}"], "--input-csv {one_row}: 1 data row(s); a voltage record needs"),
        (["simulate", "--input-csv", "{header_only}"], "--input-csv {header_only}"),
        (["simulate", "--duration", "1e9"], "--duration: 1e+09 s is beyond the 1000 s limit"),
        (["simulate", "--duration", "900", "--rate", "1e5"], "output samples exceed the limit"),
        (["simulate", "--out", "{existing}/x.csv"], "--out {existing}/x.csv: folder"),
        (["sweep", "--harmonics", "100000"], "--harmonics: must be an integer from 1 to 32"),
        (["sweep", "--points", "10000000"], "--points: must be from 1 to"),
        (["identify", "{existing}", "--out", "{existing}"], "--out {existing}: exists and is not a folder"),
        (["identify", "{existing}", "--out", "{existing}.d", "--harmonics", "0"], "--harmonics"),
        (["identify", "{existing}", "--out", "{existing}.d", "--harmonics", "100000"], "--harmonics"),
        (["identify", "{deep}", "--out", "{existing}.d"], "nested too deeply"),
        (["synth", "--membrane", "A1", "--noise", "1e-6", "--out", "{existing}"], "--out {existing}"),
        (["synth", "--params", "{deep}", "--noise", "1e-6", "--out", "{existing}.d"], "nested too deeply"),
        (["synth", "--membrane", "A1", "--noise", "1e-6", "--out", "{existing}.d", "--frequencies", "a,b"],
         "--frequencies"),
    ],
)
def test_every_error_exits_2_naming_the_file_or_option(capsys, bad_files, argv, message):
    names = {k: str(v) for k, v in bad_files.items()}
    code, _, err = run(capsys, *[a.format(**names) for a in argv])
    assert code == 2, err
    assert message.format(**names) in err
    assert "Traceback" not in err and "internal error" not in err


def test_experiment_folder_with_a_binary_csv_exits_2_naming_it(capsys, tmp_path):
    folder = tmp_path / "exp"
    folder.mkdir()
    (folder / "manifest.yaml").write_text(
        "format: dea_ros.experiments/1\nmembrane: A1\nmass_kg: 0.003\nexperiments:\n"
        "- kind: static\n  file: static.csv\n")
    (folder / "static.csv").write_bytes(bytes(range(256)) * 10)
    code, _, err = run(capsys, "identify", str(folder), "--out", str(tmp_path / "fit"), "--quiet")
    assert code == 2 and str(folder / "static.csv") in err and "not text" in err


def test_console_script_entry_point():
    out = subprocess.run([sys.executable, "-m", "dea_ros.cli", "equilibrium", "--json"],
                         capture_output=True, text=True, check=True)
    assert json.loads(out.stdout)["membrane"] == "A2"
