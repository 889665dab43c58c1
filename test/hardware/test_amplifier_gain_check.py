"""Issue 20: the gain loop check (no ROS): the fake board's amplifier with a real gain x0.1 / x1 / x10 of the
configured one, driven through the safety controller and the uldaq backend as amplifier_node drives it."""
import math
import sys
import warnings

import pytest

from dea_ros.hardware.amplifier import (
    AmplifierRangeWarning,
    GainLoopCheck,
    SafetyLimits,
    SafeVoltageController,
    UldaqAmplifierBackend,
    amplifier_config_from_parameters,
)
from fakes import load_fake


@pytest.fixture
def board(monkeypatch):
    ul, rig = load_fake("fake_uldaq").make("USB-1208HS-4AO")
    monkeypatch.setitem(sys.modules, "uldaq", ul)
    rig.monitor_wiring = (ul.AiInputMode.SINGLE_ENDED, 1)
    return rig


def run_check(board, real_gain, period_s=1e-3):
    board.real_gain_V_per_V = real_gain
    limits = SafetyLimits(max_voltage_V=2430.0, slew_rate_V_per_s=2e4, watchdog_timeout_s=0.5,
                          ramp_down_rate_V_per_s=1e4)
    ctl = SafeVoltageController(limits)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AmplifierRangeWarning)
        backend = UldaqAmplifierBackend(max_voltage_V=2430.0, monitor_channel=1, monitor_gain_V_per_V=1000.0)
    backend.open()
    check = GainLoopCheck(40.0, 0.2, 0.05, 2.0, 1000.0, 1000.0)
    ctl.activate(0.0)
    highest, t, result = 0.0, 0.0, None
    while result is None:
        t += period_s
        ctl.command(check.command_at(t), t)
        u = ctl.update(t)
        backend.write_voltage(u)
        highest = max(highest, board.amplifier_output_V)
        result = check.observe(t, u, backend.read_monitor_V())
    backend.close()
    return result, highest, t


@pytest.mark.parametrize("real_gain, ok", [(100.0, False), (1000.0, True), (10000.0, False)])
def test_loop_check_judges_the_real_gain(board, real_gain, ok):
    result, highest, t = run_check(board, real_gain)
    assert result.ok is ok
    assert result.ratio == pytest.approx(real_gain / 1000.0, rel=1e-3)
    assert result.commanded_V == 40.0 and result.output_V == pytest.approx(40.0)
    assert highest <= 40.0 * real_gain / 1000.0 + 1e-9
    assert 0.09 <= t <= 0.2                  # ramp 40 ms + hold 50 ms
    if not ok:
        assert f"{result.monitor_V:.1f} V" in result.message and "ratio" in result.message


def test_loop_check_times_out_when_the_output_does_not_reach_the_check_voltage():
    check = GainLoopCheck(40.0, 0.2, 0.05, 0.5, 1000.0, 1000.0)
    result = None
    t = 0.0
    while result is None:
        t += 1e-3
        result = check.observe(t, 10.0, 10.0)      # stuck at 10 V
    assert not result.ok and "did not reach" in result.message and t == pytest.approx(0.501, abs=2e-3)
    assert math.isnan(GainLoopCheck(40.0, 0.2, 0.01, 1.0, 1e3, 1e3).judge(0.0, None).ratio)


def test_monitor_needs_its_own_gain():
    with pytest.raises(ValueError, match="monitor_gain_V_per_V.*required"):
        amplifier_config_from_parameters({"backend": "uldaq", "params_file": "A1", "monitor_channel": 1})
