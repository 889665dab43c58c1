"""Connecting to an ILD1320 that has been streaming (issue 20, item 1).

A real ILD1320 streams from power-on; the emulator streams too, and when nobody reads it for ~8 s
its bounded output buffer drops the oldest bytes mid-frame. After a node restart the port holds a
partial frame. The connect must resynchronise on any of it, every time: these tests connect after
0, 8, 30 and 60 s of unread streaming (on the emulator's clock, no sleep) and with a partial frame
before the port is opened and before every reply (the exact failure of the issue:
``GETINFO reply has no 'Name:' line: ['\\ufffdName: ILD1320-10', ...]``).
"""
from __future__ import annotations

import math
import time

import pytest

from dea_ros.hardware.laser.ild1320_protocol import quantum_m
from dea_ros.hardware.laser.ild1320_protocol.commands import parse_getinfo_reply, parse_reply, resync_first_line
from dea_ros.hardware.laser.ild1320_serial import ILD1320Sensor, describe_ild1320
from dea_ros.errors import CommandError
from fakes import load_fake

FaultyILD1320Emulator = load_fake("faulty_ild1320").FaultyILD1320Emulator

MR = 0.010
Q = quantum_m(MR)
NO_DATA_S = 3.0


def slow_truth(t_s: float) -> float:
    """4 mm +- 0.5 mm at 0.2 Hz (at most 0.63 mm/s: a 50 ms stamp error is < 32 um)."""
    return 0.004 + 0.0005 * math.sin(2.0 * math.pi * 0.2 * t_s)


def valid_readings(dev: ILD1320Sensor, at_least: int, max_s: float = 10.0):
    readings = []
    deadline = time.monotonic() + max_s
    while len([r for r in readings if r.is_valid]) < at_least and time.monotonic() < deadline:
        readings += dev.read_batch(5000, wait_s=0.005)
    return [r for r in readings if r.is_valid]


def wait_until(predicate, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


# ---------------------------------------------------------------------------------------- the parser
@pytest.mark.parametrize("garbage", ["\ufffd", "\x05E", "\x05\x45\ufffd", "5M", "\x00\x00\x3f", "\ufffd\ufffdx"])
def test_the_first_reply_line_resynchronises_on_the_reply_start(garbage):
    assert resync_first_line(garbage + "Name: ILD1320-10", "GETINFO") == "Name: ILD1320-10"
    assert resync_first_line(garbage + "MEASRATE 2", "MEASRATE") == "MEASRATE 2"
    assert resync_first_line(garbage + "OUTPUT RS422", "OUTPUT") == "OUTPUT RS422"
    assert resync_first_line(garbage + "E232 Invalid parameter value", "MEASRATE 7") == \
        "E232 Invalid parameter value"


def test_the_issues_reply_parses_and_an_error_behind_garbage_stays_an_error():
    raw = "\ufffdName: ILD1320-10\r\nSerial: 00000000\r\nMeasuring range: 10 mm\r\n->".encode("utf-8")
    info = parse_getinfo_reply(parse_reply(raw, "GETINFO"))
    assert (info.name, info.measuring_range_m) == ("ILD1320-10", pytest.approx(MR))
    with pytest.raises(CommandError):
        parse_reply(b"\xbf\x05E232 Invalid parameter value\r\n->", "MEASRATE 7")
    # text that is no reply at all is kept: its parser refuses it and the command is repeated
    assert parse_reply(b"\xbfxyz\r\n->", "GETINFO").lines == ("xyz",)


# ------------------------------------------------------------------------------ against the emulator
@pytest.mark.parametrize("unread_s", [0.0, 8.0, 30.0, 60.0])
def test_connect_after_the_sensor_streamed_unread(unread_s):
    with FaultyILD1320Emulator(slow_truth, measuring_rate_hz=2000.0) as emu:
        emu.stream_unread_for(unread_s)
        # the streaming happened before the connect (the emulator makes those frames in a burst,
        # seconds of CPU on a loaded machine; a sensor makes them in real time)
        assert wait_until(lambda: emu.frames_emitted >= unread_s * 2000.0, 60.0)
        if unread_s >= 30.0:  # 48 kB in 8 s fit the pty and the 64 kB buffer; 180 kB do not: trimmed
            assert wait_until(lambda: emu.bytes_dropped_overflow > 0)
        with ILD1320Sensor(emu.port_path, measuring_range_m=MR, measuring_rate_hz=2000.0,
                           min_no_data_timeout_s=NO_DATA_S) as dev:
            assert dev.connect_report is not None and dev.connect_report.ok
            assert dev.connect_report.settings.output == "RS422"  # what it was, not the stopped stream
            valid = valid_readings(dev, 200)
            assert len(valid) >= 200
            assert max(abs(r.value - slow_truth(r.acquisition_time_s)) for r in valid) < 0.5 * Q + 32e-6
        assert emu.output_channel == "RS422"


@pytest.mark.parametrize("tail", [b"\xbf", b"\x05", b"\x05\x45", b"\x05\x45\x45\xbf\xbf"])
def test_connect_after_a_partial_frame_and_with_one_before_every_reply(tail):
    with FaultyILD1320Emulator(slow_truth, measuring_rate_hz=1000.0) as emu:
        emu.partial_frame_before_replies(tail)
        emu.inject_garbage(2, raw=True)
        for attempt in range(3):  # every time, also on a reconnect
            with ILD1320Sensor(emu.port_path, measuring_range_m=MR, measuring_rate_hz=2000.0,
                               min_no_data_timeout_s=NO_DATA_S) as dev:
                assert dev.connect_report.settings.model == "ILD1320-10", attempt
                assert len(valid_readings(dev, 100)) >= 100
        assert emu.measuring_rate_hz == 2000.0


def test_describing_a_streaming_sensor_leaves_it_streaming():
    with FaultyILD1320Emulator(slow_truth) as emu:
        emu.stream_unread_for(8.0)
        emu.partial_frame_before_replies()
        report = describe_ild1320(emu.port_path)
        assert report.settings.model == "ILD1320-10" and report.settings.output == "RS422"
        assert emu.output_channel == "RS422"
