"""The serial backend connecting to a misbehaving or previously used ILD1320 (emulator on a pty).

A connect must put the sensor into the known state (no mastering, no additional outputs, no hold,
the rate read back), refuse a sensor that differs from the configuration with a clear error, and
survive any bad reply as an error, never a crash; a corrupted stream must not yield a value far
from the truth.
"""
from __future__ import annotations

import math
import threading
import time

import pytest

from dea_ros.hardware.laser.ild1320_protocol import LaserSensorExpectation, quantum_m
from dea_ros.hardware.laser.ild1320_serial import ILD1320Sensor, describe_ild1320
from dea_ros.hardware.laser.plausibility import DEFAULT_JUMP_TOLERANCE_M, DEFAULT_MAX_SPEED_M_PER_S
from dea_ros.hardware.laser import MeasurementError, SensorConfigurationError, SensorDisconnected, SensorError
from dea_ros.sim.ild1320_emulator import ILD1320Emulator
from fakes import load_fake


FaultyILD1320Emulator = load_fake("faulty_ild1320").FaultyILD1320Emulator

MR = 0.010
Q = quantum_m(MR)
#: Silence that counts as a disconnect in these tests: generous, a loaded machine can starve the
#: emulator thread for 0.3 s (disconnects are tested in test_laser_emulator.py).
NO_DATA_S = 3.0


def truth(t_s: float) -> float:
    """4 mm +- 0.5 mm at 2 Hz, metres from the start of the measuring range."""
    return 0.004 + 0.0005 * math.sin(2.0 * math.pi * 2.0 * t_s)


@pytest.fixture
def no_leaked_threads():
    before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        if not [t for t in threading.enumerate() if t not in before and t.is_alive()]:
            return
        time.sleep(0.01)
    pytest.fail("emulator threads left running")


def read_for(dev: ILD1320Sensor, seconds: float, at_least: int = 0, max_s: float = 10.0):
    """Readings of ``seconds`` of wall time, longer (up to ``max_s``) until there are ``at_least``:
    a loaded machine starves the emulator thread, so a count in a fixed time would test the load."""
    readings = []
    start = time.monotonic()
    while time.monotonic() < start + seconds or (len(readings) < at_least and time.monotonic() < start + max_s):
        readings += dev.read_batch(5000, wait_s=0.005)
    return readings


def slow_truth(t_s: float) -> float:
    """4 mm +- 0.5 mm at 0.2 Hz: at most 0.63 mm/s, so a 50 ms stamp error is < 32 um."""
    return 0.004 + 0.0005 * math.sin(2.0 * math.pi * 0.2 * t_s)


def test_a_previous_users_settings_are_reported_then_reset_and_readings_match_the_truth(no_leaked_threads):
    # left by a previous user: zeroed with the target at 3 mm, a counter after every value, errors held
    with ILD1320Emulator(slow_truth, mastering=(0.003, 0.0), additional_outputs=("COUNTER",), output_hold="0",
                         measuring_rate_hz=1000.0) as emu:
        report = describe_ild1320(emu.port_path, LaserSensorExpectation(MR, 2000.0))
        assert report.ok, report.lines()
        s = report.settings
        assert (s.model, s.measuring_range_m, s.measuring_rate_hz) == ("ILD1320-10", pytest.approx(MR), 1000.0)
        assert (s.additional_outputs, s.output_hold, s.mastering) == (("COUNTER",), "0", "MASTER 0.000000")
        assert len(report.to_reset) == 4  # rate, additional outputs, hold, mastering
        assert emu.mastering is not None  # describing changes nothing
        with ILD1320Sensor(emu.port_path, measuring_range_m=MR, measuring_rate_hz=2000.0,
                           min_no_data_timeout_s=NO_DATA_S) as dev:
            assert dev.connect_report is not None and len(dev.connect_report.to_reset) == 4
            assert emu.mastering is None and emu.additional_outputs == () and emu.output_hold == "NONE"
            assert emu.measuring_rate_hz == 2000.0
            additional_before = dev.decoder.additional_values_skipped
            readings = read_for(dev, 0.3, at_least=410)
            valid = [r for r in readings if r.is_valid]
            assert len(valid) > 400 and len(readings) - len(valid) <= 2  # 2 await confirmation
            # the mastered stream would read 2 mm too far (d - 3 mm + 5 mm); after the reset: the truth
            # (the tolerance covers reconstructed stamps off by up to 50 ms on a loaded machine)
            assert max(abs(r.value - slow_truth(r.acquisition_time_s)) for r in valid) < 0.5 * Q + 32e-6
            assert dev.decoder.additional_values_skipped == additional_before  # none after the reset
            assert dev.describe().to_reset == ()


@pytest.mark.parametrize("rate_text", ["0", "7", "4", "-2", "nan", "x"])
def test_a_bad_measrate_reply_is_a_clear_error_not_a_crash(no_leaked_threads, rate_text):
    with FaultyILD1320Emulator(truth) as emu:
        emu.misbehave(reported_rate_khz=rate_text)
        # replies within 2 s: what is tested is the reply, not the timing (ci24 on a machine loaded by two
        # benchmark processes once missed the default 0.5 s in describe_ild1320 below)
        dev = ILD1320Sensor(emu.port_path, measuring_range_m=MR, measuring_rate_hz=2000.0, timeout_s=2.0)
        with pytest.raises(SensorError) as err:
            dev.open()
        assert "rate" in str(err.value)
        assert not isinstance(err.value, ZeroDivisionError)
        with pytest.raises(SensorError, match="not open"):
            dev.read_batch()  # closed again
        report = describe_ild1320(emu.port_path, LaserSensorExpectation(MR, 2000.0), timeout_s=2.0)
        assert not report.ok or report.settings.measuring_rate_hz is None
        # the sensor behaves again: the same object connects
        emu.misbehave(reported_rate_khz=None)
        dev.open()
        assert dev.measuring_rate() == 2000.0
        dev.close()


def test_a_wrong_measuring_range_or_model_is_refused_with_the_mismatch(no_leaked_threads):
    with FaultyILD1320Emulator(truth) as emu:
        emu.misbehave(reported_range_mm=1000.0)
        dev = ILD1320Sensor(emu.port_path, measuring_range_m=MR)
        with pytest.raises(SensorConfigurationError) as err:
            dev.open()
        assert "1000 mm" in str(err.value) and "measuring_range_m" in str(err.value)
        assert err.value.mismatches and not dev.connect_report.ok
        # a 25 mm head where a 10 mm head is configured: consistent GETINFO, still refused
        emu.misbehave(reported_range_mm=25.0, reported_model="ILD1320-25")
        with pytest.raises(SensorConfigurationError, match="25 mm"):
            dev.open()
        emu.misbehave(reported_range_mm=None, reported_model="ILD1420-10")
        with pytest.raises(SensorConfigurationError, match="ILD1420"):
            dev.open()
        emu.misbehave(reported_model=None)
        dev.open()
        assert dev.measuring_range_m == pytest.approx(MR)
        dev.close()


def test_settings_that_do_not_read_back_and_garbage_replies_are_errors(no_leaked_threads):
    with FaultyILD1320Emulator(truth, mastering=(0.003, 0.001)) as emu:
        dev = ILD1320Sensor(emu.port_path, measuring_range_m=MR, timeout_s=0.2)
        emu.misbehave(ignored_commands=["MASTERMV"])  # acknowledged, not applied
        with pytest.raises(SensorError, match="MASTERMV reads back"):
            dev.open()
        emu.misbehave(ignored_commands=["MEASRATE"])
        emu.misbehave(ignored_commands=[], reply_overrides={"MEASRATE": b"MEASRATE 1\r\n->"})
        with pytest.raises(SensorError, match="1000 Hz after MEASRATE 2"):
            ILD1320Sensor(emu.port_path, measuring_range_m=MR, measuring_rate_hz=2000.0).open()
        for junk in (b"\xff\xfe\x80garbage\r\n->", b"Name ILD1320-10\r\n->", b"E999 broken\r\n->", b"no prompt"):
            emu.misbehave(reply_overrides={"GETINFO": junk})
            with pytest.raises(SensorError):
                dev.open()
        emu.misbehave(reply_overrides=None)
        dev.open()
        assert emu.mastering is None
        dev.close()


def test_a_corrupted_stream_never_yields_a_value_far_from_the_truth(no_leaked_threads):
    with FaultyILD1320Emulator(truth, seed=3) as emu, ILD1320Sensor(
            emu.port_path, measuring_range_m=MR, min_no_data_timeout_s=NO_DATA_S) as dev:
        read_for(dev, 0.05)
        emu.misbehave(drop_byte_probability=0.01, random_byte_probability=0.01)
        for _ in range(5):
            emu.inject_garbage(300, raw=True)  # uniformly random: frames with valid flags among them
            emu.corrupt_next(5)
            time.sleep(0.03)
        readings = read_for(dev, 0.6)
        emu.misbehave(drop_byte_probability=None, random_byte_probability=None)
        valid = [r for r in readings if r.is_valid]
        assert len(valid) > 500
        # stamps are reconstructed (lost frames shift them by up to a few periods): judge each accepted
        # value against the truth over +-10 ms around its stamp, with the speed-limit allowance
        allowance = DEFAULT_MAX_SPEED_M_PER_S * 4 * 0.5e-3 + DEFAULT_JUMP_TOLERANCE_M
        for r in valid:
            nearby = [truth(r.acquisition_time_s + k * 1e-3) for k in range(-10, 11)]
            assert min(nearby) - allowance <= r.value <= max(nearby) + allowance
        reasons = {r.value for r in readings if not r.is_valid}
        assert MeasurementError.AFTER_FRAMING_ERROR in reasons
        counters = dev.diagnostic_counters()
        assert counters["bytes_discarded"] > 1500 and counters["partial_frames_dropped"] > 0
        assert emu.bytes_dropped_fault > 0 and emu.random_bytes_inserted > 0
        assert dev.plausibility_filter.discarded[MeasurementError.AFTER_FRAMING_ERROR] > 20


def test_describe_without_a_sensor_is_a_disconnect_error():
    with pytest.raises(SensorDisconnected, match="cannot open"):
        describe_ild1320("/dev/nonexistent_dea_ros_laser")
