"""Tests of the amplifier backends (dea_ros.hardware.amplifier): in-process, UDP mock pair, uldaq (faked)."""
from __future__ import annotations

import importlib.abc
import importlib.machinery
import math
import re
import socket
import struct
import sys
import time
import warnings

import pytest

from dea_ros.errors import AmplifierBackendError, AmplifierRangeWarning
from dea_ros.hardware.amplifier.base import AmplifierBackend
from dea_ros.hardware.amplifier.inprocess import InProcessAmplifierBackend
from dea_ros.hardware.amplifier.rig_description import (
    AmplifierRigExpectation,
    DaqBoardInfo,
    choose_daq_range,
    describe_amplifier_rig,
    parse_daq_range,
)
from dea_ros.hardware.amplifier.udp import (
    DATAGRAM_SIZE,
    MockAmplifierBackend,
    decode_voltage_datagram,
    encode_voltage_datagram,
)
from dea_ros.hardware.amplifier.uldaq import UldaqAmplifierBackend, query_uldaq_board
from dea_ros.sim import amplifier_receiver, free_udp_port
from dea_ros.sim.amplifier_receiver import MockAmplifierReceiver
from fakes import load_fake


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

    def test_deadman_drops_to_zero_when_datagrams_stop(self):
        """The mock amplifier's own interlock: a sender that dies at high voltage (SIGKILL, power
        loss) leaves 0 V after the dead-man timeout, not its last datagram."""
        now = [10.0]
        with MockAmplifierReceiver(port=0, clock=lambda: now[0], deadman_timeout_s=0.2) as receiver:
            assert receiver.applied_voltage_V() == 0.0  # nothing received yet: 0 V
            backend = MockAmplifierBackend(receiver.port, max_voltage_V=3000.0)
            backend.open()
            backend.write_voltage(3000.0)  # ... and the sender dies without a word
            _poll_until(receiver, lambda r: r is not None and r.voltage_V == 3000.0)
            assert receiver.applied_voltage_V() == 3000.0
            now[0] += 0.19
            assert receiver.applied_voltage_V() == 3000.0 and not receiver.deadman_expired()
            now[0] += 0.02
            assert receiver.deadman_expired() and receiver.applied_voltage_V() == 0.0
            assert receiver.applied_voltage_V() == 0.0 and receiver.deadman_trip_count == 1
            backend.write_voltage(1000.0)  # a live sender re-arms it
            _poll_until(receiver, lambda r: r is not None and r.voltage_V == 1000.0)
            assert receiver.applied_voltage_V() == 1000.0
            backend._close_socket()
        with pytest.raises(AmplifierBackendError, match="deadman_timeout_s"):
            MockAmplifierReceiver(port=0, deadman_timeout_s=0.0)

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
fake = load_fake("fake_uldaq")


@pytest.fixture
def fake_uldaq(monkeypatch):
    ul, rig = fake.make()
    monkeypatch.setitem(sys.modules, "uldaq", ul)
    return rig


def quiet_backend(**kwargs) -> UldaqAmplifierBackend:
    kwargs.setdefault("max_voltage_V", 2430.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AmplifierRangeWarning)
        return UldaqAmplifierBackend(**kwargs)


def a_out_values(rig) -> list[float]:
    return rig.a_out_values()


class TestUldaqConfiguration:
    def test_range_names(self):
        assert parse_daq_range("UNI10VOLTS") == (0.0, 10.0)
        assert parse_daq_range("BIP10VOLTS") == (-10.0, 10.0)
        assert parse_daq_range("bip2pt5volts") == (-2.5, 2.5)
        assert parse_daq_range("UNIPT625VOLTS") == (0.0, 0.625)
        for bad in ("10V", "UNIVOLTS", "UNI10", 10):
            with pytest.raises(AmplifierBackendError, match="Range"):
                parse_daq_range(bad)  # type: ignore[arg-type]

    def test_named_range_times_gain_above_max_warns(self):
        with pytest.warns(AmplifierRangeWarning, match="10000 V, above max_voltage_V = 2430 V"):
            backend = UldaqAmplifierBackend(ao_range="BIP10VOLTS", max_voltage_V=2430.0)
        assert backend.daq_limit_V == pytest.approx(2.43)

    def test_strict_range_check_refuses(self):
        with pytest.raises(AmplifierBackendError, match="strict_range_check"):
            UldaqAmplifierBackend(ao_range="BIP10VOLTS", max_voltage_V=2430.0, strict_range_check=True)

    def test_matching_range_and_gain_do_not_warn(self):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            backend = UldaqAmplifierBackend(ao_range="UNI5VOLTS", amplifier_gain_V_per_V=500.0,
                                            max_voltage_V=2500.0, strict_range_check=True)
            auto = UldaqAmplifierBackend(max_voltage_V=2500.0)  # "auto": chosen on open
        assert backend.daq_limit_V == 5.0 and auto.daq_limit_V is None and auto.ao_range is None

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
            (dict(enable_bit=-1), "enable_bit"),
            (dict(amplifier_max_output_V=0.0), "amplifier_max_output_V"),
        ],
    )
    def test_invalid_configuration(self, kwargs, field):
        with pytest.raises(AmplifierBackendError, match=field):
            quiet_backend(**kwargs)


# =========================================================================== rig description (pure)
def expect(**kwargs) -> AmplifierRigExpectation:
    kwargs.setdefault("backend", "uldaq")
    kwargs.setdefault("ceiling_V", 3150.0)
    return AmplifierRigExpectation(**kwargs)


class TestRigDescription:
    @pytest.mark.parametrize("product", sorted(fake.BOARDS))
    def test_known_boards_table_matches_what_the_boards_report(self, fake_uldaq, product):
        fake_uldaq.set_board(product)
        fake_uldaq.descriptors = [fake_uldaq.uldaq.DaqDeviceDescriptor(product, "SN1")]
        assert query_uldaq_board() == DaqBoardInfo.known(product, "SN1")
        assert not any(c[0] in ("a_out", "d_bit_out") for c in fake_uldaq.calls)  # a query writes nothing
        assert fake_uldaq.calls[-1] == ("release",)

    @pytest.mark.parametrize("product, chosen", [("USB-1208HS-4AO", "BIP10VOLTS"), ("USB-1608GX-2AO", "BIP10VOLTS"),
                                                 ("USB-1208FS-Plus", "UNI5VOLTS"), ("USB-202", "UNI5VOLTS")])
    def test_range_is_chosen_from_what_the_board_offers(self, product, chosen):
        d = describe_amplifier_rig(expect(), DaqBoardInfo.known(product, "SN1"))
        assert d.ok and d.ao_range == chosen and d.needed_daq_V == pytest.approx(3.15)
        assert any("DAQ: " + product in line for line in d.lines())
        assert choose_daq_range(["BIP10VOLTS", "UNI10VOLTS", "UNI5VOLTS"], 3.15) == "UNI5VOLTS"
        assert choose_daq_range(["BIP10VOLTS", "UNI10VOLTS"], 3.15) == "UNI10VOLTS"  # unipolar wins a tie

    def test_no_range_covers_the_needed_output(self):
        d = describe_amplifier_rig(expect(ceiling_V=6000.0), DaqBoardInfo.known("USB-1208FS-Plus", "SN1"))
        assert not d.ok and d.ao_range is None
        assert re.search(r"no analog output range of USB-1208FS-Plus \(SN1\) \(ranges \['UNI5VOLTS'\]\) covers "
                         r"the needed 0..6 V", d.mismatches[0])
        assert "no voltage will be applied" in d.lines()[-1]

    def test_named_range_must_be_offered_and_cover(self):
        d = describe_amplifier_rig(expect(ao_range="UNI10VOLTS"), DaqBoardInfo.known("USB-1208HS-4AO", "SN1"))
        assert not d.ok and "UNI10VOLTS is not offered by USB-1208HS-4AO (SN1); it offers ['BIP10VOLTS']" in \
            d.mismatches[0]

    def test_gain_slip_is_caught(self):
        """The reproduction: gain 100 configured on a 1000 V/V amplifier (3150 V -> 10 kV)."""
        d = describe_amplifier_rig(expect(amplifier_gain_V_per_V=100.0), DaqBoardInfo.known("USB-1208HS-4AO"))
        text = " ".join(d.mismatches)
        assert "amplifier_gain_V_per_V = 100 V/V x amplifier_input_full_scale_V = 10 V = 1000 V" in text
        assert "covers the needed 0..31.5 V" in text
        d = describe_amplifier_rig(expect(backend="mock", amplifier_gain_V_per_V=100.0))  # whatever the backend
        assert not d.ok and "gain slip" in d.mismatches[0]

    def test_ceiling_above_the_amplifier_rating_is_a_membrane_slip(self):
        """The reproduction: A1 thickness x10 gives a 24.3 kV limit on a 10 kV amplifier."""
        d = describe_amplifier_rig(expect(backend="mock", ceiling_V=24300.0))
        assert not d.ok and re.search(r"ceiling 24300.0 V .* rated output amplifier_max_output_V = 10000 V: a "
                                      r"thickness or breakdown-field slip", d.mismatches[0])

    def test_monitor_and_enable_are_checked_against_the_board(self):
        board = DaqBoardInfo.known("USB-1208HS-4AO", "SN1")
        d = describe_amplifier_rig(expect(monitor_channel=1, enable_port="AUXPORT", enable_bit=3), board)
        assert d.ok and d.monitor_range == "BIP10VOLTS"  # covers 10 kV / 1000 V/V; bipolar shows a polarity error
        bad = describe_amplifier_rig(expect(monitor_channel=8, monitor_input_mode="SINGLE_ENDED",
                                            enable_port="FIRSTPORTA",
                                            enable_bit=3), board)
        assert any("monitor_channel = 8" in m and "0..7" in m for m in bad.mismatches)
        assert any("enable_port = FIRSTPORTA" in m and "AUXPORT" in m for m in bad.mismatches)
        bad = describe_amplifier_rig(expect(monitor_channel=0, monitor_input_mode="DIFFERENTIAL", enable_port="AUXPORT",
                                            enable_bit=16, monitor_gain_V_per_V=100.0), board)
        assert any("enable_bit = 16" in m for m in bad.mismatches)
        assert any("covers the monitor signal 0..100 V" in m for m in bad.mismatches)
        for backend in ("mock", "inprocess"):
            d = describe_amplifier_rig(expect(backend=backend, monitor_channel=0, enable_port="AUXPORT"))
            assert len(d.mismatches) == 2 and all("uldaq only" in m for m in d.mismatches)


class TestUldaqBackend:
    def test_open_write_close_converts_through_gain(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        backend = quiet_backend()
        backend.open()
        assert backend.is_open and "USB-1208HS-4AO" in backend.device_description
        assert backend.ao_range == "BIP10VOLTS" and backend.rig_description.ok  # the only range of the board
        assert fake_uldaq.calls[:4] == [
            ("get_daq_device_inventory", ul.InterfaceType.USB),
            ("DaqDevice", "01ABCDEF"),
            ("connect",),
            ("a_out", 0, ul.Range.BIP10VOLTS, ul.AOutFlag.DEFAULT, 0.0),  # 0 V on open
        ]
        backend.write_voltage(1500.0)
        backend.write_voltage(2430.0)
        assert a_out_values(fake_uldaq) == pytest.approx([0.0, 1.5, 2.43], rel=1e-12)
        assert backend.last_daq_V == pytest.approx(2.43)
        assert fake_uldaq.amplifier_output_V == pytest.approx(2430.0)
        backend.close()
        assert fake_uldaq.calls[-3:] == [
            ("a_out", 0, ul.Range.BIP10VOLTS, ul.AOutFlag.DEFAULT, 0.0),  # 0 V on close
            ("disconnect",),
            ("release",),
        ]
        assert not backend.is_open and not fake_uldaq.connected
        n_calls = len(fake_uldaq.calls)
        backend.close()  # idempotent
        assert len(fake_uldaq.calls) == n_calls

    @pytest.mark.parametrize("product", sorted(fake.BOARDS))
    def test_every_real_board_drives_the_membrane_limit(self, fake_uldaq, product):
        fake_uldaq.set_board(product)
        with quiet_backend(max_voltage_V=3150.0) as backend:
            backend.write_voltage(3150.0)
            assert fake_uldaq.amplifier_output_V == pytest.approx(3150.0)
            assert backend.ao_range == ("BIP10VOLTS" if "AO" in product else "UNI5VOLTS")

    @pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0, 2430.5, 1e4])
    def test_refused_values_never_reach_the_daq(self, fake_uldaq, bad):
        with quiet_backend() as backend:
            backend.write_voltage(1000.0)
            with pytest.raises(AmplifierBackendError):
                backend.write_voltage(bad)
            assert a_out_values(fake_uldaq) == pytest.approx([0.0, 1.0])
            assert backend.last_written_V == 1000.0

    def test_daq_output_never_exceeds_ceiling_over_gain(self, fake_uldaq):
        with quiet_backend() as backend:
            assert backend.daq_limit_V == pytest.approx(2.43)
            assert backend.high_voltage_to_daq_V(1e9) == pytest.approx(2.43)  # clamp below the write check
            backend.write_voltage(2430.0)
        assert max(a_out_values(fake_uldaq)) == pytest.approx(2.43)

    def test_channel_and_custom_gain(self, fake_uldaq):
        with quiet_backend(channel=3, amplifier_gain_V_per_V=300.0, amplifier_max_output_V=3000.0,
                           max_voltage_V=3000.0) as backend:
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

    def test_board_without_a_covering_range_refuses_to_start(self, fake_uldaq):
        """The default UNI10VOLTS of old does not exist on these boards: named ranges must be offered,
        and 'auto' refuses when no offered range covers the needed output, naming board and ranges."""
        fake_uldaq.set_board("USB-1208HS-4AO")
        with pytest.raises(AmplifierBackendError, match=r"USB-1208HS-4AO \(01ABCDEF\) does not match.*UNI10VOLTS "
                                                        r"is not offered.*\['BIP10VOLTS'\]"):
            quiet_backend(ao_range="UNI10VOLTS").open()
        fake_uldaq.set_board("USB-1208FS-Plus")
        with pytest.raises(AmplifierBackendError, match=r"no analog output range of USB-1208FS-Plus .*\['UNI5VOLTS'\]"):
            quiet_backend(max_voltage_V=6000.0).open()
        assert fake_uldaq.calls[-2:] == [("disconnect",), ("release",)]
        assert a_out_values(fake_uldaq) == []  # nothing was written

    def test_missing_channel_or_ao_subsystem(self, fake_uldaq):
        fake_uldaq.set_board("USB-1608GX-2AO")
        with pytest.raises(AmplifierBackendError, match="uldaq_channel = 2.*channels 0..1"):
            quiet_backend(channel=2).open()
        fake_uldaq.has_ao = False
        with pytest.raises(AmplifierBackendError, match="has no analog output"):
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

    def test_monitor_reads_the_amplifier_output(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        with quiet_backend() as backend:
            assert backend.read_monitor_V() is None and not backend.has_monitor  # no monitor channel configured
        fake_uldaq.monitor_wiring = (ul.AiInputMode.SINGLE_ENDED, 1)
        with quiet_backend(monitor_channel=1, monitor_gain_V_per_V=1000.0) as backend:
            backend.write_voltage(1250.0)
            assert backend.read_monitor_V() == pytest.approx(1250.0)
        assert ("a_in", 1, ul.AiInputMode.SINGLE_ENDED, ul.Range.BIP10VOLTS, ul.AInFlag.DEFAULT) in fake_uldaq.calls
        fake_uldaq.real_gain_V_per_V = 10000.0  # a x10 gain slip: the monitor shows the truth
        with quiet_backend(monitor_channel=1, monitor_gain_V_per_V=1000.0) as backend:
            backend.write_voltage(500.0)
            assert backend.read_monitor_V() == pytest.approx(5000.0)
            fake_uldaq.unplugged = True
            with pytest.raises(AmplifierBackendError, match="monitor.*connection was lost"):
                backend.read_monitor_V()
            fake_uldaq.unplugged = False
        fake_uldaq.has_ai = False
        with pytest.raises(AmplifierBackendError, match="analog input modes \\[\\]"):
            quiet_backend(monitor_channel=0, monitor_gain_V_per_V=1000.0).open()

    @pytest.mark.parametrize("product, port, config_call",
                             [("USB-1208HS-4AO", "AUXPORT", "d_config_bit"),
                              ("USB-1208FS-Plus", "FIRSTPORTA", "d_config_port")])
    def test_enable_line(self, fake_uldaq, product, port, config_call):
        ul = fake_uldaq.uldaq
        fake_uldaq.set_board(product)
        key = (ul.DigitalPortType[port], 3)
        fake_uldaq.enable_wiring = key
        backend = quiet_backend(enable_port=port, enable_bit=3)
        backend.open()
        assert any(c[0] == config_call for c in fake_uldaq.calls)
        assert fake_uldaq.bit_levels[key] == 0 and not fake_uldaq.amplifier_enabled  # inactive after open
        backend.set_output_enabled(True)
        backend.write_voltage(1000.0)
        assert fake_uldaq.amplifier_output_V == pytest.approx(1000.0)
        backend.close()
        assert fake_uldaq.bit_levels[key] == 0 and fake_uldaq.amplifier_output_V == 0.0

    def test_enable_heartbeat_toggles_while_enabled(self, fake_uldaq):
        ul = fake_uldaq.uldaq
        key = (ul.DigitalPortType.AUXPORT, 0)
        with quiet_backend(enable_port="AUXPORT", enable_bit=0, enable_heartbeat=True) as backend:
            backend.write_voltage(0.0)
            levels = [c[3] for c in fake_uldaq.calls if c[0] == "d_bit_out"]
            assert levels == [0]  # disabled: rests inactive, no toggling
            backend.set_output_enabled(True)
            for _ in range(4):
                backend.write_voltage(100.0)
            levels = [c[3] for c in fake_uldaq.calls if c[0] == "d_bit_out"]
            assert levels[-5:] == [1, 0, 1, 0, 1]
        assert fake_uldaq.bit_levels[key] == 0


class TestFakeValidatesLikeTheLibrary:
    """The fake must refuse what libuldaq refuses, or the backend tests prove nothing."""

    def test_a_in_and_a_out_arguments(self):
        ul, rig = fake.make("USB-1208HS-4AO")
        device = ul.DaqDevice(rig.descriptors[0])
        ai, ao = device.get_ai_device(), device.get_ao_device()
        E = ul.ULError
        cases = [
            (lambda: ai.a_in(0, ul.AiInputMode.PSEUDO_DIFFERENTIAL, ul.Range.BIP10VOLTS, ul.AInFlag.DEFAULT),
             E.BAD_INPUT_MODE),
            (lambda: ai.a_in(4, ul.AiInputMode.DIFFERENTIAL, ul.Range.BIP10VOLTS, ul.AInFlag.DEFAULT), E.BAD_AI_CHAN),
            (lambda: ai.a_in(0, ul.AiInputMode.SINGLE_ENDED, ul.Range.BIP20VOLTS, ul.AInFlag.DEFAULT), E.BAD_RANGE),
            (lambda: ai.a_in(0, ul.AiInputMode.SINGLE_ENDED, ul.Range.BIP10VOLTS, ul.AInFlag.DEFAULT),
             E.NO_CONNECTION_ESTABLISHED),
            (lambda: ao.a_out(4, ul.Range.BIP10VOLTS, ul.AOutFlag.DEFAULT, 1.0), E.BAD_AO_CHAN),
            (lambda: ao.a_out(0, ul.Range.UNI10VOLTS, ul.AOutFlag.DEFAULT, 1.0), E.BAD_RANGE),
            (lambda: ao.a_out(0, ul.Range.BIP10VOLTS, ul.AOutFlag.DEFAULT, 10.5), E.BAD_DA_VAL),
        ]
        for call, code in cases:
            with pytest.raises(ul.ULException) as info:
                call()
            assert info.value.error_code == code
        device.connect()
        assert ai.a_in(0, ul.AiInputMode.SINGLE_ENDED, ul.Range.UNI10VOLTS, ul.AInFlag.DEFAULT) == 0.0
        dio = device.get_dio_device()
        with pytest.raises(ul.ULException) as info:
            dio.d_bit_out(ul.DigitalPortType.AUXPORT, 0, 1)  # not configured as output
        assert info.value.error_code == E.WRONG_DIG_CONFIG
        rig.set_board("USB-1208FS-Plus")
        with pytest.raises(ul.ULException) as info:
            dio.d_config_bit(ul.DigitalPortType.FIRSTPORTA, 0, ul.DigitalDirection.OUTPUT)  # IO port: no bits
        assert info.value.error_code == E.BAD_DIG_OPERATION


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
        import dea_ros.hardware.amplifier.uldaq as module

        assert "uldaq" not in vars(module)


# =========================================================================== amplifier_node configuration (pure)
class TestAmplifierConfig:
    def test_shipped_config_derives_the_ceiling(self):
        from pathlib import Path

        import yaml

        from dea_ros.hardware.amplifier.config import amplifier_config_from_parameters

        path = Path(__file__).resolve().parents[2] / "config" / "amplifier.yaml"
        values = yaml.safe_load(path.read_text())["/**/amplifier_node"]["ros__parameters"]
        config = amplifier_config_from_parameters(values)
        assert config.ceiling_V == pytest.approx(3150.0) and config.expected.backend == "mock"
        board = DaqBoardInfo.known("USB-1208FS-Plus", "SN1")
        uldaq = amplifier_config_from_parameters({**values, "backend": "uldaq"})
        assert describe_amplifier_rig(uldaq.expected, board).ao_range == "UNI5VOLTS"

    @pytest.mark.parametrize("values, message", [
        ({"amplifier_gain_V_per_V": 100.0}, "amplifier_gain_V_per_V = 100 V/V"),
        ({"max_voltage_kV": 3.0}, r"unknown amplifier_node parameter\(s\) \['max_voltage_kV'\]"),
        ({"backend": "inprocess", "use_sim_time": True}, "use_sim_time"),
        ({"margin": 1.0}, "margin"),
        ({"update_rate_hz": "fast"}, "update_rate_hz.*number"),
        ({"params_file": "/nonexistent/membrane.yaml"}, "no such parameters file"),
    ])
    def test_slips_are_named(self, values, message):
        from dea_ros.hardware.amplifier.config import amplifier_config_from_parameters

        with pytest.raises(ValueError, match=message):
            amplifier_config_from_parameters(values)


def test_free_udp_port_is_bindable_and_outside_the_ephemeral_range(monkeypatch):
    """``dea-ros rig`` picks the amplifier's port before the mock binds it: a port from bind(0) could be
    any process's next ephemeral port meanwhile (every DDS participant binds some), so the pick comes
    from below the kernel's ephemeral range, and a port in use is never returned."""
    low_ephemeral = int(open("/proc/sys/net/ipv4/ip_local_port_range").read().split()[0])
    ports = {free_udp_port() for _ in range(20)}
    assert all(amplifier_receiver.FREE_PORT_RANGE[0] <= p < min(low_ephemeral, 7000) for p in ports), ports
    receiver = MockAmplifierReceiver(port=ports.pop())
    try:
        held = receiver.port
        monkeypatch.setattr(amplifier_receiver, "FREE_PORT_RANGE", (held, held + 1))
        with pytest.raises(AmplifierBackendError, match="no free UDP port.*pass amplifier_port"):
            free_udp_port(attempts=5)
        monkeypatch.setattr(amplifier_receiver, "FREE_PORT_RANGE", (held, held + 2))
        assert free_udp_port() == held + 1   # never the held one
    finally:
        receiver.close()
