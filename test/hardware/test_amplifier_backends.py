"""Tests of dea_ros.hardware.amplifier_backends: in-process, UDP mock pair, uldaq (faked)."""
from __future__ import annotations

import enum
import importlib.abc
import importlib.machinery
import math
import socket
import struct
import sys
import time
import types
import warnings

import pytest

from dea_ros.hardware.amplifier_backends import (
    DATAGRAM_SIZE,
    AmplifierBackend,
    AmplifierBackendError,
    AmplifierRangeWarning,
    InProcessAmplifierBackend,
    MockAmplifierBackend,
    MockAmplifierReceiver,
    UldaqAmplifierBackend,
    decode_voltage_datagram,
    encode_voltage_datagram,
    parse_daq_range,
)


# =========================================================================== interface + in-process
def test_backend_interface_is_abstract():
    with pytest.raises(TypeError):
        AmplifierBackend()  # type: ignore[abstract]


class TestInProcessBackend:
    def test_open_write_close_cycle(self):
        backend = InProcessAmplifierBackend(max_voltage_V=3000.0)
        with pytest.raises(AmplifierBackendError, match="open"):
            backend.write_voltage(10.0)
        backend.open()
        assert backend.is_open and backend.voltage_V == 0.0 and backend.history_V == [0.0]
        backend.write_voltage(1500.0)
        assert backend.voltage_V == 1500.0 and backend.read_monitor_V() == 1500.0
        assert backend.last_written_V == 1500.0
        backend.close()
        assert not backend.is_open and backend.voltage_V == 0.0
        assert backend.history_V == [0.0, 1500.0, 0.0]
        backend.close()  # idempotent
        assert backend.close_count == 1
        assert backend.read_monitor_V() is None

    @pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, -1.0, 3000.001, "5", None, True])
    def test_refuses_invalid_values_without_writing(self, bad):
        with InProcessAmplifierBackend(max_voltage_V=3000.0) as backend:
            backend.write_voltage(1000.0)
            with pytest.raises(AmplifierBackendError, match="InProcessAmplifierBackend"):
                backend.write_voltage(bad)
            assert backend.voltage_V == 1000.0
            assert backend.write_count == 2  # the 0 V of open and the 1000 V

    def test_without_max_any_finite_non_negative_value_passes(self):
        with InProcessAmplifierBackend() as backend:
            backend.write_voltage(1e4)
            assert backend.voltage_V == 1e4

    @pytest.mark.parametrize("bad_max", [0.0, -5.0, math.nan, math.inf, "3000"])
    def test_invalid_max_is_refused(self, bad_max):
        with pytest.raises(AmplifierBackendError, match="max_voltage_V"):
            InProcessAmplifierBackend(max_voltage_V=bad_max)

    def test_history_is_bounded(self):
        with InProcessAmplifierBackend(history_length=3) as backend:
            for v in (1.0, 2.0, 3.0, 4.0):
                backend.write_voltage(v)
            assert backend.history_V == [2.0, 3.0, 4.0]


# =========================================================================== UDP mock pair
class TestDatagram:
    def test_round_trip(self):
        data = encode_voltage_datagram(0xDEADBEEF, 42, 1234.5, 987.25)
        assert len(data) == DATAGRAM_SIZE == 32
        decoded = decode_voltage_datagram(data)
        assert (decoded.session_id, decoded.sequence, decoded.voltage_V, decoded.sent_monotonic_s) == (
            0xDEADBEEF, 42, 1234.5, 987.25)

    @pytest.mark.parametrize(
        "data, match",
        [
            (b"", "0 bytes"),
            (b"hello", "5 bytes"),
            (encode_voltage_datagram(1, 2, 3.0, 4.0) + b"x", "33 bytes"),
            (b"XXXX" + encode_voltage_datagram(1, 2, 3.0, 4.0)[4:], "magic"),
            (struct.pack("!4sIQdd", b"DEAV", 1, 2, math.nan, 4.0), "voltage"),
            (struct.pack("!4sIQdd", b"DEAV", 1, 2, -5.0, 4.0), "voltage"),
            (struct.pack("!4sIQdd", b"DEAV", 1, 2, 5.0, math.inf), "send time"),
        ],
    )
    def test_garbage_is_refused(self, data, match):
        with pytest.raises(ValueError, match=match):
            decode_voltage_datagram(data)


def _poll_until(receiver: MockAmplifierReceiver, predicate, timeout_s: float = 2.0):
    deadline = time.monotonic() + timeout_s
    while True:
        latest = receiver.poll()
        if predicate(latest):
            return latest
        if time.monotonic() > deadline:
            raise AssertionError(f"no matching datagram within {timeout_s} s; latest {latest}")
        time.sleep(0.001)


class TestUdpMockPair:
    def test_round_trip_on_ephemeral_port(self):
        with MockAmplifierReceiver(port=0) as receiver:
            assert receiver.port > 0
            assert receiver.poll() is None
            backend = MockAmplifierBackend(receiver.port, max_voltage_V=3000.0)
            with backend:
                first = _poll_until(receiver, lambda r: r is not None)
                assert first.voltage_V == 0.0 and first.sequence == 0  # open() sends 0 V
                assert first.session_id == backend.session_id
                for v in (100.0, 200.0, 2345.5):
                    backend.write_voltage(v)
                latest = _poll_until(receiver, lambda r: r is not None and r.sequence == 3)
                assert latest.voltage_V == 2345.5
                assert latest.sent_s <= latest.received_s  # both time.monotonic()
                assert latest.received_s <= time.monotonic()
                with pytest.raises(AmplifierBackendError, match="above max_voltage_V"):
                    backend.write_voltage(3000.5)
                assert backend.sent_count == 4
            closing = _poll_until(receiver, lambda r: r is not None and r.sequence == 4)
            assert closing.voltage_V == 0.0  # close() sends 0 V
            assert receiver.received_count == 5
            assert receiver.garbage_count == 0 and receiver.stale_count == 0
            assert receiver.poll() is closing  # no new data: the latest is kept

    def test_garbage_and_stale_datagrams_are_counted_and_ignored(self):
        fake_now = [100.0]
        with MockAmplifierReceiver(port=0, clock=lambda: fake_now[0]) as receiver, \
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
            target = ("127.0.0.1", receiver.port)
            garbage = [
                b"",
                b"hello",
                bytes(range(32)),
                b"XXXX" + encode_voltage_datagram(1, 0, 5.0, 1.0)[4:],
                struct.pack("!4sIQdd", b"DEAV", 1, 0, math.nan, 1.0),
                encode_voltage_datagram(1, 0, 5.0, 1.0) * 2,
            ]
            for data in garbage:
                raw.sendto(data, target)
            raw.sendto(encode_voltage_datagram(7, 5, 50.0, 1.0), target)
            raw.sendto(encode_voltage_datagram(7, 3, 30.0, 1.0), target)  # older: stale
            latest = _poll_until(receiver, lambda r: receiver.stale_count == 1)
            assert latest.voltage_V == 50.0 and latest.sequence == 5 and latest.received_s == 100.0
            assert receiver.garbage_count == len(garbage)
            raw.sendto(encode_voltage_datagram(8, 0, 80.0, 2.0), target)  # restarted sender
            fake_now[0] = 101.0
            latest = _poll_until(receiver, lambda r: r.session_id == 8)
            assert latest.voltage_V == 80.0 and latest.received_s == 101.0
            assert receiver.received_count == 2

    def test_sender_without_listener_does_not_fail(self):
        with MockAmplifierReceiver(port=0) as probe:
            free_port = probe.port  # bound and closed again: nobody listens there afterwards
        backend = MockAmplifierBackend(free_port)
        backend.open()
        try:
            for v in (1.0, 2.0, 3.0):
                backend.write_voltage(v)
            assert backend.read_monitor_V() is None
        finally:
            backend.close()
        assert not backend.is_open

    def test_receiver_errors(self):
        with MockAmplifierReceiver(port=0) as receiver:
            with pytest.raises(AmplifierBackendError, match="cannot bind"):
                MockAmplifierReceiver(port=receiver.port)
        with pytest.raises(AmplifierBackendError, match="after close"):
            receiver.poll()
        receiver.close()  # idempotent
        with pytest.raises(AmplifierBackendError, match="port"):
            MockAmplifierReceiver(port=70000)
        with pytest.raises(AmplifierBackendError, match="port"):
            MockAmplifierBackend(0)

    def test_flood_is_drained_in_bounded_batches(self):
        with MockAmplifierReceiver(port=0) as receiver:
            receiver.MAX_DATAGRAMS_PER_POLL = 10  # instance override, to see the batching
            backend = MockAmplifierBackend(receiver.port)
            with backend:
                for k in range(1, 50):
                    backend.write_voltage(float(k))
                time.sleep(0.05)  # let loopback deliver everything
                first = receiver.poll()
                assert first is not None and first.sequence == 9  # only 10 drained
                latest = _poll_until(receiver, lambda r: r.sequence == 49)
            assert latest.voltage_V == 49.0
            assert receiver.received_count == 50


# =========================================================================== fake uldaq
class FakeRig:
    """State of the fake hardware shared by the fake uldaq objects; records every call."""

    def __init__(self, uldaq):
        self.uldaq = uldaq
        self.calls: list[tuple] = []
        self.descriptors = [uldaq.DaqDeviceDescriptor("USB-1208HS-4AO", "01ABCDEF")]
        self.ao_ranges = [uldaq.Range.UNI10VOLTS, uldaq.Range.BIP10VOLTS]
        self.ao_channels = 4
        self.has_ao = True
        self.has_ai = True
        self.unplugged = False
        self.connect_error = None
        self.inventory_error = None
        self.monitor_daq_V = 0.0
        self.connected = False


def make_fake_uldaq() -> tuple[types.ModuleType, FakeRig]:
    """A stand-in for the uldaq package with its real names and signatures (see the
    MCC sources: uldaq/ao_device.py, daq_device.py, utils.py, ul_enums.py)."""
    ul = types.ModuleType("uldaq")

    class ULError(enum.IntEnum):
        DEV_NOT_FOUND = 6
        DEV_NOT_CONNECTED = 7
        DEAD_DEV = 8
        USB_DEV_NO_PERMISSION = 4
        BAD_RANGE = 13
        BAD_AO_CHAN = 55
        BAD_DA_VAL = 56

    class InterfaceType(enum.IntEnum):
        USB = 1
        BLUETOOTH = 2
        ETHERNET = 4
        ANY = 7

    class Range(enum.IntEnum):
        BIP10VOLTS = 5
        BIP5VOLTS = 6
        UNI10VOLTS = 1005
        UNI5VOLTS = 1006
        UNI1VOLTS = 1011

    class AOutFlag(enum.IntEnum):
        DEFAULT = 0

    class AInFlag(enum.IntEnum):
        DEFAULT = 0

    class AiInputMode(enum.IntEnum):
        DIFFERENTIAL = 1
        SINGLE_ENDED = 2

    class ULException(Exception):
        def __init__(self, error_code):
            self.error_code = ULError(error_code)
            self.error_message = self.error_code.name.replace("_", " ").lower()

        def __str__(self):
            return f"{self.error_code}: {self.error_message}"

    class DaqDeviceDescriptor:
        def __init__(self, product_name, unique_id):
            self.product_name = product_name
            self.unique_id = unique_id
            self.dev_string = product_name

    range_limits = {Range.BIP10VOLTS: (-10.0, 10.0), Range.BIP5VOLTS: (-5.0, 5.0),
                    Range.UNI10VOLTS: (0.0, 10.0), Range.UNI5VOLTS: (0.0, 5.0), Range.UNI1VOLTS: (0.0, 1.0)}

    class AoInfo:
        def get_num_chans(self):
            return rig.ao_channels

        def get_ranges(self):
            return list(rig.ao_ranges)

    class AoDevice:
        def get_info(self):
            return AoInfo()

        def a_out(self, channel, voltage_range, flags, data):
            rig.calls.append(("a_out", channel, voltage_range, flags, data))
            assert isinstance(voltage_range, Range) and isinstance(flags, AOutFlag)
            assert isinstance(data, float)
            if rig.unplugged or not rig.connected:
                raise ULException(ULError.DEV_NOT_CONNECTED)
            if not 0 <= channel < rig.ao_channels:
                raise ULException(ULError.BAD_AO_CHAN)
            if voltage_range not in rig.ao_ranges:
                raise ULException(ULError.BAD_RANGE)
            low, high = range_limits[voltage_range]
            if not low <= data <= high:
                raise ULException(ULError.BAD_DA_VAL)

    class AiDevice:
        def a_in(self, channel, input_mode, voltage_range, flags):
            rig.calls.append(("a_in", channel, input_mode, voltage_range, flags))
            assert isinstance(input_mode, AiInputMode) and isinstance(voltage_range, Range)
            assert isinstance(flags, AInFlag)
            if rig.unplugged:
                raise ULException(ULError.DEAD_DEV)
            return rig.monitor_daq_V

    class DaqDevice:
        def __init__(self, descriptor):
            rig.calls.append(("DaqDevice", descriptor.unique_id))

        def connect(self):
            rig.calls.append(("connect",))
            if rig.connect_error is not None:
                raise ULException(rig.connect_error)
            rig.connected = True

        def is_connected(self):
            return rig.connected and not rig.unplugged

        def get_ao_device(self):
            return AoDevice() if rig.has_ao else None

        def get_ai_device(self):
            return AiDevice() if rig.has_ai else None

        def disconnect(self):
            rig.calls.append(("disconnect",))
            if not rig.connected or rig.unplugged:
                raise ULException(ULError.DEV_NOT_CONNECTED)
            rig.connected = False

        def release(self):
            rig.calls.append(("release",))

    def get_daq_device_inventory(interface_type, number_of_devices=100):
        rig.calls.append(("get_daq_device_inventory", interface_type))
        if rig.inventory_error is not None:
            raise ULException(rig.inventory_error)
        return list(rig.descriptors)

    for obj in (ULError, InterfaceType, Range, AOutFlag, AInFlag, AiInputMode, ULException,
                DaqDeviceDescriptor, DaqDevice, get_daq_device_inventory):
        setattr(ul, obj.__name__, obj)
    rig = FakeRig(ul)
    return ul, rig


@pytest.fixture
def fake_uldaq(monkeypatch):
    ul, rig = make_fake_uldaq()
    monkeypatch.setitem(sys.modules, "uldaq", ul)
    return rig


def quiet_backend(**kwargs) -> UldaqAmplifierBackend:
    kwargs.setdefault("max_voltage_V", 2430.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AmplifierRangeWarning)
        return UldaqAmplifierBackend(**kwargs)


def a_out_values(rig) -> list[float]:
    return [call[4] for call in rig.calls if call[0] == "a_out"]


class TestUldaqConfiguration:
    def test_range_names(self):
        assert parse_daq_range("UNI10VOLTS") == (0.0, 10.0)
        assert parse_daq_range("BIP10VOLTS") == (-10.0, 10.0)
        assert parse_daq_range("bip2pt5volts") == (-2.5, 2.5)
        assert parse_daq_range("UNIPT625VOLTS") == (0.0, 0.625)
        for bad in ("10V", "UNIVOLTS", "UNI10", 10):
            with pytest.raises(AmplifierBackendError, match="Range"):
                parse_daq_range(bad)  # type: ignore[arg-type]

    def test_range_times_gain_above_max_warns(self):
        with pytest.warns(AmplifierRangeWarning, match="10000 V, above max_voltage_V = 2430 V"):
            backend = UldaqAmplifierBackend(max_voltage_V=2430.0)
        assert backend.daq_limit_V == pytest.approx(2.43)

    def test_strict_range_check_refuses(self):
        with pytest.raises(AmplifierBackendError, match="strict_range_check"):
            UldaqAmplifierBackend(max_voltage_V=2430.0, strict_range_check=True)

    def test_bipolar_range_counts_its_magnitude(self):
        with pytest.warns(AmplifierRangeWarning, match="BIP10VOLTS"):
            UldaqAmplifierBackend(ao_range="BIP10VOLTS", amplifier_gain_V_per_V=300.0, max_voltage_V=2500.0)

    def test_matching_range_and_gain_do_not_warn(self):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            backend = UldaqAmplifierBackend(ao_range="UNI5VOLTS", amplifier_gain_V_per_V=500.0,
                                            max_voltage_V=2500.0, strict_range_check=True)
        assert backend.daq_limit_V == 5.0

    def test_unreachable_max_warns_and_clamps_to_range(self):
        with pytest.warns(AmplifierRangeWarning, match="unreachable"):
            backend = UldaqAmplifierBackend(ao_range="UNI1VOLTS", max_voltage_V=2430.0)
        assert backend.daq_limit_V == 1.0
        assert backend.high_voltage_to_daq_V(2000.0) == 1.0

    def test_max_voltage_is_required(self):
        with pytest.raises(TypeError):
            UldaqAmplifierBackend()  # type: ignore[call-arg]
        with pytest.raises(AmplifierBackendError, match="max_voltage_V"):
            UldaqAmplifierBackend(max_voltage_V=None)  # type: ignore[arg-type]

    @pytest.mark.parametrize(
        "kwargs, field",
        [
            (dict(amplifier_gain_V_per_V=0.0), "amplifier_gain_V_per_V"),
            (dict(amplifier_gain_V_per_V=math.nan), "amplifier_gain_V_per_V"),
            (dict(amplifier_gain_V_per_V=-1000.0), "amplifier_gain_V_per_V"),
            (dict(channel=-1), "channel"),
            (dict(channel=1.0), "channel"),
            (dict(monitor_channel=-2), "monitor_channel"),
            (dict(ao_range="TEN_VOLTS"), "Range"),
            (dict(monitor_gain_V_per_V=0.0), "monitor_gain_V_per_V"),
        ],
    )
    def test_invalid_configuration(self, kwargs, field):
        with pytest.raises(AmplifierBackendError, match=field):
            quiet_backend(**kwargs)


class TestUldaqBackend:
    def test_open_write_close_converts_through_gain(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        backend = quiet_backend()
        backend.open()
        assert backend.is_open and "USB-1208HS-4AO" in backend.device_description
        assert fake_uldaq.calls[:4] == [
            ("get_daq_device_inventory", ul.InterfaceType.USB),
            ("DaqDevice", "01ABCDEF"),
            ("connect",),
            ("a_out", 0, ul.Range.UNI10VOLTS, ul.AOutFlag.DEFAULT, 0.0),  # 0 V on open
        ]
        backend.write_voltage(1500.0)
        backend.write_voltage(2430.0)
        assert a_out_values(fake_uldaq) == pytest.approx([0.0, 1.5, 2.43], rel=1e-12)
        assert backend.last_daq_V == pytest.approx(2.43)
        backend.close()
        assert fake_uldaq.calls[-3:] == [
            ("a_out", 0, ul.Range.UNI10VOLTS, ul.AOutFlag.DEFAULT, 0.0),  # 0 V on close
            ("disconnect",),
            ("release",),
        ]
        assert not backend.is_open and not fake_uldaq.connected
        n_calls = len(fake_uldaq.calls)
        backend.close()  # idempotent
        assert len(fake_uldaq.calls) == n_calls

    @pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0, 2430.5, 1e4])
    def test_refused_values_never_reach_the_daq(self, fake_uldaq, bad):
        with quiet_backend() as backend:
            backend.write_voltage(1000.0)
            with pytest.raises(AmplifierBackendError):
                backend.write_voltage(bad)
            assert a_out_values(fake_uldaq) == pytest.approx([0.0, 1.0])
            assert backend.last_written_V == 1000.0

    def test_output_is_clamped_to_the_ao_range(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        fake_uldaq.ao_ranges = [ul.Range.UNI1VOLTS]
        # The fake raises on out-of-range values, so the clamp is what makes this pass.
        with pytest.raises(ul.ULException):
            ul.DaqDevice(fake_uldaq.descriptors[0]).get_ao_device().a_out(0, ul.Range.UNI1VOLTS,
                                                                          ul.AOutFlag.DEFAULT, 1.5)
        with quiet_backend(ao_range="UNI1VOLTS") as backend:
            backend.write_voltage(2000.0)
            backend.write_voltage(500.0)
        assert a_out_values(fake_uldaq)[-3:] == pytest.approx([1.0, 0.5, 0.0])

    def test_channel_and_custom_gain(self, fake_uldaq):
        with quiet_backend(channel=3, amplifier_gain_V_per_V=300.0, max_voltage_V=3000.0) as backend:
            backend.write_voltage(1500.0)
        a_outs = [c for c in fake_uldaq.calls if c[0] == "a_out"]
        assert {c[1] for c in a_outs} == {3}
        assert a_outs[1][4] == pytest.approx(5.0)

    def test_selects_device_by_unique_id(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        fake_uldaq.descriptors = [ul.DaqDeviceDescriptor("USB-1608GX-2AO", "AAA"),
                                  ul.DaqDeviceDescriptor("USB-1208HS-4AO", "BBB")]
        with quiet_backend(unique_id="BBB") as backend:
            assert "BBB" in backend.device_description
        assert ("DaqDevice", "BBB") in fake_uldaq.calls
        with pytest.raises(AmplifierBackendError, match=r"unique_id 'CCC'.*\['AAA', 'BBB'\]"):
            quiet_backend(unique_id="CCC").open()

    def test_no_device_found(self, fake_uldaq):
        fake_uldaq.descriptors = []
        backend = quiet_backend()
        with pytest.raises(AmplifierBackendError, match="no Measurement Computing DAQ found"):
            backend.open()
        assert not backend.is_open

    def test_discovery_error_is_mapped(self, fake_uldaq):
        fake_uldaq.inventory_error = fake_uldaq.uldaq.ULError.USB_DEV_NO_PERMISSION
        with pytest.raises(AmplifierBackendError, match="udev") as info:
            quiet_backend().open()
        assert isinstance(info.value.__cause__, fake_uldaq.uldaq.ULException)

    def test_connect_error_releases_the_device(self, fake_uldaq):
        fake_uldaq.connect_error = fake_uldaq.uldaq.ULError.DEV_NOT_FOUND
        backend = quiet_backend()
        with pytest.raises(AmplifierBackendError, match="connecting.*lsusb"):
            backend.open()
        assert fake_uldaq.calls[-1] == ("release",)
        assert not backend.is_open

    def test_unsupported_range_is_refused_on_open(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        fake_uldaq.ao_ranges = [ul.Range.BIP10VOLTS]
        with pytest.raises(AmplifierBackendError, match=r"UNI10VOLTS is not supported.*BIP10VOLTS"):
            quiet_backend().open()
        assert fake_uldaq.calls[-2:] == [("disconnect",), ("release",)]
        assert a_out_values(fake_uldaq) == []

    def test_missing_channel_or_ao_subsystem(self, fake_uldaq):
        fake_uldaq.ao_channels = 2
        with pytest.raises(AmplifierBackendError, match="'channel' = 2.*2 analog output"):
            quiet_backend(channel=2).open()
        fake_uldaq.has_ao = False
        with pytest.raises(AmplifierBackendError, match="no analog output"):
            quiet_backend().open()
        assert fake_uldaq.calls[-1] == ("release",)

    def test_disconnect_mid_run_is_mapped_and_latched(self, fake_uldaq):
        backend = quiet_backend()
        backend.open()
        backend.write_voltage(1000.0)
        fake_uldaq.unplugged = True
        with pytest.raises(AmplifierBackendError, match="connection was lost") as info:
            backend.write_voltage(1100.0)
        assert isinstance(info.value.__cause__, fake_uldaq.uldaq.ULException)
        assert backend.faulted and backend.last_written_V == 1000.0
        n_a_out = len(a_out_values(fake_uldaq))
        with pytest.raises(AmplifierBackendError, match="faulted"):
            backend.write_voltage(1200.0)
        assert len(a_out_values(fake_uldaq)) == n_a_out  # nothing sent while faulted
        with pytest.raises(AmplifierBackendError, match="could not write 0 V"):
            backend.close()  # 0 V cannot be confirmed: says so, but still releases
        assert fake_uldaq.calls[-1] == ("release",)
        assert not backend.is_open
        backend.close()

    def test_reopen_after_replug(self, fake_uldaq):
        backend = quiet_backend()
        backend.open()
        fake_uldaq.unplugged = True
        with pytest.raises(AmplifierBackendError):
            backend.write_voltage(10.0)
        with pytest.raises(AmplifierBackendError):
            backend.close()
        fake_uldaq.unplugged = False
        fake_uldaq.connected = False
        backend.open()
        backend.write_voltage(10.0)
        assert backend.faulted is None and a_out_values(fake_uldaq)[-1] == pytest.approx(0.01)
        backend.close()

    def test_monitor_reading(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        with quiet_backend() as backend:
            assert backend.read_monitor_V() is None  # no monitor channel configured
        fake_uldaq.monitor_daq_V = 1.25
        with quiet_backend(monitor_channel=1) as backend:
            assert backend.read_monitor_V() == pytest.approx(1250.0)
        assert ("a_in", 1, ul.AiInputMode.SINGLE_ENDED, ul.Range.BIP10VOLTS, ul.AInFlag.DEFAULT) in fake_uldaq.calls
        with quiet_backend(monitor_channel=1, monitor_gain_V_per_V=2000.0) as backend:
            assert backend.read_monitor_V() == pytest.approx(2500.0)
            fake_uldaq.unplugged = True
            with pytest.raises(AmplifierBackendError, match="monitor.*connection was lost"):
                backend.read_monitor_V()
            fake_uldaq.unplugged = False
        fake_uldaq.has_ai = False
        with pytest.raises(AmplifierBackendError, match="no analog input"):
            quiet_backend(monitor_channel=0).open()


class _BrokenLibraryFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports 'uldaq' like the real package does when libuldaq.so is missing."""

    def find_spec(self, name, path=None, target=None):
        if name == "uldaq":
            return importlib.machinery.ModuleSpec(name, self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        raise OSError("libuldaq.so: cannot open shared object file: No such file or directory")


class TestUldaqImport:
    def test_missing_package_gives_install_hint(self, monkeypatch):
        monkeypatch.setitem(sys.modules, "uldaq", None)  # makes 'import uldaq' raise ImportError
        backend = quiet_backend()
        with pytest.raises(AmplifierBackendError, match="pip install uldaq.*libuldaq"):
            backend.open()
        assert not backend.is_open

    def test_missing_c_library_gives_install_hint(self, monkeypatch):
        monkeypatch.delitem(sys.modules, "uldaq", raising=False)
        monkeypatch.setattr(sys, "meta_path", [_BrokenLibraryFinder()] + sys.meta_path)
        with pytest.raises(AmplifierBackendError, match="libuldaq could not be loaded.*pip install uldaq"):
            quiet_backend().open()

    def test_module_import_does_not_need_uldaq(self):
        import dea_ros.hardware.amplifier_backends as module

        assert "uldaq" not in vars(module)
