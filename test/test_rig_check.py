"""`dea-ros rig check`: what is connected vs what the configuration expects, before any voltage.

The DAQ is the fake uldaq with the real boards' ranges (test/fakes/fake_uldaq.py); the laser is
the ILD1320 emulator on a pseudo-terminal, left in a previous user's state.
"""
import json
import sys

import pytest

from dea_ros.cli import main
from dea_ros.sim.ild1320_emulator import ILD1320Emulator
from fakes import load_fake


fake = load_fake("fake_uldaq")


@pytest.fixture
def board(monkeypatch):
    def install(product):
        ul, rig = fake.make(product)
        monkeypatch.setitem(sys.modules, "uldaq", ul)
        return rig
    return install


def run(capsys, *argv):
    code = main(["rig", "check", "--json", *argv])
    out = capsys.readouterr()
    return code, (json.loads(out.out) if code in (0, 1) else None), out.err


def test_mock_configuration_is_consistent_and_needs_no_hardware(capsys):
    code, report, _ = run(capsys, "--laser", "backend:=mock")
    assert code == 0 and report["ok"], report
    assert "ceiling 3150.0 V" in " ".join(report["sections"]["amplifier_node"])


def test_real_rig_reports_board_sensor_and_what_the_node_will_reset(capsys, board):
    rig = board("USB-1208FS-Plus")  # only UNI5VOLTS: 3.15 V at the amplifier input is covered
    with ILD1320Emulator(lambda t: 0.004, mastering=(0.003, 0.0), additional_outputs=("COUNTER",)) as emu:
        code, report, _ = run(capsys, "--amplifier", "backend:=uldaq", "--laser", f"port:={emu.port_path}")
        assert emu.mastering is not None  # a check changes nothing on the sensor
    assert code == 0, report["mismatches"]
    amp = " ".join(report["sections"]["amplifier_node"])
    assert "USB-1208FS-Plus" in amp and "UNI5VOLTS" in amp
    laser = " ".join(report["sections"]["laser_sensor_node"])
    assert "ILD1320-10" in laser and "MASTER" in laser.upper()
    assert not any(call[0] in ("a_out", "d_bit_out") for call in rig.calls)  # nothing written to the DAQ


def test_every_mismatch_is_named_and_exits_1(capsys, board):
    board("USB-1208HS-4AO")  # offers only BIP10VOLTS
    with ILD1320Emulator(lambda t: 0.004) as emu:
        code, report, _ = run(capsys, "--amplifier", "backend:=uldaq", "--amplifier", "uldaq_range:=UNI10VOLTS",
                              "--laser", f"port:={emu.port_path}", "--laser", "measuring_range_m:=0.025")
    assert code == 1
    text = "\n".join(report["mismatches"])
    assert "UNI10VOLTS" in text and "BIP10VOLTS" in text and "USB-1208HS-4AO" in text
    assert "laser_sensor_node" in text and "25" in text  # the range the configuration expects


def test_unreachable_devices_are_mismatches_not_tracebacks(capsys, tmp_path):
    code, report, err = run(capsys, "--amplifier", "backend:=uldaq", "--laser", f"port:={tmp_path / 'no_such_tty'}")
    assert code == 1 and "Traceback" not in err
    assert any("laser not reachable" in m for m in report["mismatches"])
    assert any("DAQ not reachable" in m for m in report["mismatches"])


@pytest.mark.parametrize("argv, field", [
    (["--amplifier", "margin:=1.0"], "margin"),
    (["--amplifier", "amplifier_gain_V_per_V:=100"], "amplifier_gain_V_per_V"),
    (["--amplifier", "nonsense"], "--amplifier"),
])
def test_an_invalid_configuration_exits_2_naming_the_field(capsys, argv, field):
    code, _, err = run(capsys, "--no-laser", *argv)
    assert code == 2 and field in err and "Traceback" not in err


def test_a_params_file_without_the_node_is_refused(capsys, tmp_path):
    f = tmp_path / "other.yaml"
    f.write_text("/**/model_node:\n  ros__parameters:\n    params_file: A2\n")
    code, _, err = run(capsys, "--no-laser", "--amplifier-params-file", str(f))
    assert code == 2 and "no section for amplifier_node" in err
