"""A stand-in for the ``uldaq`` package that behaves like the real boards.

Names, enum values and signatures are those of the MCC Python binding (uldaq/ul_enums.py,
ao_device.py, ai_device.py, dio_device.py, *_info.py). The boards' capabilities are copied
independently from the libuldaq sources (src/usb/ao/AoUsb1208hs.cpp: ``addRange(BIP10VOLTS)``;
AoUsb1608g.cpp inherits it; AoUsb1208fsPlus.cpp and AoUsb20x.cpp: ``addRange(UNI5VOLTS)``;
src/usb/ai/*.cpp ``addRange(mode, range)`` and ``setNumChansByMode``; src/usb/dio/*.cpp
``addPort``), so a wrong table in the code under test does not hide behind the fake.

``a_out``, ``a_in``, ``d_config_bit`` and ``d_bit_out`` validate their arguments like
libuldaq's ``check_AOut_Args`` / ``check_AIn_Args`` / ``check_DBitOut_Args`` (AoDevice.cpp,
AiDevice.cpp, DioDevice.cpp) and raise ``ULException`` with the same error codes.

The fake board drives a fake amplifier: its output is the AO voltage x the *real* gain
(``rig.real_gain_V_per_V``) while the enable line is active (or when no enable line is
wired), and its monitor (``rig.monitor_wiring``) reads output / ``rig.real_monitor_V_per_V``.
Load it by path (tests run with ``--import-mode=importlib``) and call :func:`make`.
"""
from __future__ import annotations

import enum
import types

__all__ = [
    "make", "FakeRig", "BOARDS", "RANGE_LIMITS_V", "ULError", "ULException", "InterfaceType", "Range", "AOutFlag",
    "AInFlag", "AiInputMode", "DigitalDirection", "DigitalPortIoType", "DigitalPortType", "DaqDeviceDescriptor",
    "DioPortInfo",
]

# ----------------------------------------------------------------------------- enums (real values)


class ULError(enum.IntEnum):
    NO_ERROR = 0
    BAD_DEV_HANDLE = 2
    USB_DEV_NO_PERMISSION = 4
    USB_INTERFACE_CLAIMED = 5
    DEV_NOT_FOUND = 6
    DEV_NOT_CONNECTED = 7
    DEAD_DEV = 8
    BAD_RANGE = 13
    BAD_AI_CHAN = 14
    BAD_INPUT_MODE = 15
    BAD_FLAG = 33
    BAD_PORT_TYPE = 50
    WRONG_DIG_CONFIG = 51
    BAD_BIT_NUM = 52
    BAD_AO_CHAN = 55
    BAD_DA_VAL = 56
    NO_CONNECTION_ESTABLISHED = 73
    BAD_DIG_OPERATION = 83


class InterfaceType(enum.IntEnum):
    USB = 1 << 0
    BLUETOOTH = 1 << 1
    ETHERNET = 1 << 2
    ANY = USB | BLUETOOTH | ETHERNET


class Range(enum.IntEnum):
    BIP20VOLTS = 4
    BIP10VOLTS = 5
    BIP5VOLTS = 6
    BIP4VOLTS = 7
    BIP2PT5VOLTS = 8
    BIP2VOLTS = 9
    BIP1PT25VOLTS = 10
    BIP1VOLTS = 11
    UNI10VOLTS = 1005
    UNI5VOLTS = 1006
    UNI1VOLTS = 1011


RANGE_LIMITS_V = {
    Range.BIP20VOLTS: (-20.0, 20.0), Range.BIP10VOLTS: (-10.0, 10.0), Range.BIP5VOLTS: (-5.0, 5.0),
    Range.BIP4VOLTS: (-4.0, 4.0), Range.BIP2PT5VOLTS: (-2.5, 2.5), Range.BIP2VOLTS: (-2.0, 2.0),
    Range.BIP1PT25VOLTS: (-1.25, 1.25), Range.BIP1VOLTS: (-1.0, 1.0), Range.UNI10VOLTS: (0.0, 10.0),
    Range.UNI5VOLTS: (0.0, 5.0), Range.UNI1VOLTS: (0.0, 1.0),
}


class AOutFlag(enum.IntEnum):
    DEFAULT = 0
    NOSCALEDATA = 1 << 0
    NOCALIBRATEDATA = 1 << 1


class AInFlag(enum.IntEnum):
    DEFAULT = 0
    NOSCALEDATA = 1 << 0
    NOCALIBRATEDATA = 1 << 1


class AiInputMode(enum.IntEnum):
    DIFFERENTIAL = 1
    SINGLE_ENDED = 2
    PSEUDO_DIFFERENTIAL = 3


class DigitalDirection(enum.IntEnum):
    INPUT = 1
    OUTPUT = 2


class DigitalPortIoType(enum.IntEnum):
    IN = 1
    OUT = 2
    IO = 3
    BITIO = 4
    NONCONFIG = 5


class DigitalPortType(enum.IntEnum):
    AUXPORT = 1
    AUXPORT1 = 2
    AUXPORT2 = 3
    FIRSTPORTA = 10
    FIRSTPORTB = 11
    FIRSTPORTC = 12


SE, DIFF = AiInputMode.SINGLE_ENDED, AiInputMode.DIFFERENTIAL
R = Range
#: product name -> capabilities, from the libuldaq sources (see the module docstring).
BOARDS = {
    "USB-1208HS-4AO": dict(
        ao_channels=4, ao_ranges=[R.BIP10VOLTS],
        ai={SE: (8, [R.BIP10VOLTS, R.BIP5VOLTS, R.BIP2PT5VOLTS, R.UNI10VOLTS]),
            DIFF: (4, [R.BIP20VOLTS, R.BIP10VOLTS, R.BIP5VOLTS])},
        dio=[(DigitalPortType.AUXPORT, 16, DigitalPortIoType.BITIO)]),
    "USB-1608GX-2AO": dict(
        ao_channels=2, ao_ranges=[R.BIP10VOLTS],
        ai={SE: (16, [R.BIP10VOLTS, R.BIP5VOLTS, R.BIP2VOLTS, R.BIP1VOLTS]),
            DIFF: (8, [R.BIP10VOLTS, R.BIP5VOLTS, R.BIP2VOLTS, R.BIP1VOLTS])},
        dio=[(DigitalPortType.AUXPORT, 8, DigitalPortIoType.BITIO)]),
    "USB-1208FS-Plus": dict(
        ao_channels=2, ao_ranges=[R.UNI5VOLTS],
        ai={SE: (8, [R.BIP10VOLTS]),
            DIFF: (4, [R.BIP20VOLTS, R.BIP10VOLTS, R.BIP5VOLTS, R.BIP4VOLTS, R.BIP2PT5VOLTS, R.BIP2VOLTS,
                       R.BIP1PT25VOLTS, R.BIP1VOLTS])},
        dio=[(DigitalPortType.FIRSTPORTA, 8, DigitalPortIoType.IO),
             (DigitalPortType.FIRSTPORTB, 8, DigitalPortIoType.IO)]),
    "USB-202": dict(
        ao_channels=2, ao_ranges=[R.UNI5VOLTS],
        ai={SE: (8, [R.BIP10VOLTS])},
        dio=[(DigitalPortType.AUXPORT, 8, DigitalPortIoType.BITIO)]),
    "USB-205": dict(
        ao_channels=2, ao_ranges=[R.UNI5VOLTS],
        ai={SE: (8, [R.BIP10VOLTS])},
        dio=[(DigitalPortType.AUXPORT, 8, DigitalPortIoType.BITIO)]),
}


class ULException(Exception):
    def __init__(self, error_code):
        self.error_code = ULError(error_code)
        self.error_message = self.error_code.name.replace("_", " ").lower()
        super().__init__(self.error_message)

    def __str__(self):
        return f"{self.error_code}: {self.error_message}"


class DaqDeviceDescriptor:
    def __init__(self, product_name, unique_id):
        self.product_name = product_name
        self.unique_id = unique_id
        self.dev_string = product_name


class DioPortInfo:
    def __init__(self, port_type, port_io_type, number_of_bits):
        self.type = port_type
        self.port_io_type = port_io_type
        self.number_of_bits = number_of_bits


class FakeRig:
    """The fake hardware behind the fake module; every call is recorded in ``calls``."""

    def __init__(self, product="USB-1208HS-4AO", unique_id="01ABCDEF"):
        self.calls: list = []
        self.descriptors = [DaqDeviceDescriptor(product, unique_id)]
        self.set_board(product)
        self.has_ao = self.has_ai = self.has_dio = True
        self.unplugged = False
        self.connect_error = None
        self.inventory_error = None
        self.connected = False
        # fake amplifier and its wiring
        self.ao_values = {}
        self.amplifier_channel = 0
        self.real_gain_V_per_V = 1000.0
        self.real_monitor_V_per_V = 1000.0
        self.monitor_wiring = (SE, 0)  # (input mode, channel) the monitor is wired to
        self.monitor_override = None  # None, a float (DAQ volts) or an exception to raise
        self.enable_wiring = None  # (port, bit) of the amplifier's enable input; None: always enabled
        self.enable_active_high = True
        self.bit_levels = {}  # (port, bit) -> 0/1
        self.output_bits = set()  # (port, bit) configured as outputs

    def set_board(self, product):
        """Make the (first) connected device a ``product`` of :data:`BOARDS`."""
        spec = BOARDS[product]
        if self.descriptors:
            self.descriptors[0] = DaqDeviceDescriptor(product, self.descriptors[0].unique_id)
        self.product = product
        self.ao_channels = spec["ao_channels"]
        self.ao_ranges = list(spec["ao_ranges"])
        self.ai = dict(spec["ai"])
        self.dio = list(spec["dio"])

    @property
    def amplifier_enabled(self):
        if self.enable_wiring is None:
            return True
        level = self.bit_levels.get(self.enable_wiring, 0)
        return bool(level) == self.enable_active_high

    @property
    def amplifier_output_V(self):
        """What the fake amplifier puts on the membrane, V."""
        if not self.amplifier_enabled:
            return 0.0
        return self.ao_values.get(self.amplifier_channel, 0.0) * self.real_gain_V_per_V

    def a_out_values(self):
        return [c[4] for c in self.calls if c[0] == "a_out"]

    def check_connected(self):
        """Raise what libuldaq raises on a device that is unplugged or not connected."""
        if self.unplugged:
            raise ULException(ULError.DEV_NOT_CONNECTED)
        if not self.connected:
            raise ULException(ULError.NO_CONNECTION_ESTABLISHED)

    def find_port(self, port_type):
        """(bits, io type) of a digital port of the board."""
        assert isinstance(port_type, DigitalPortType)
        for port, bits, io_type in self.dio:
            if port == port_type:
                return bits, io_type
        raise ULException(ULError.BAD_PORT_TYPE)


class AoInfo:
    def __init__(self, rig):
        self._rig = rig

    def get_num_chans(self):
        return self._rig.ao_channels

    def get_ranges(self):
        return list(self._rig.ao_ranges)


class AoDevice:
    def __init__(self, rig):
        self._rig = rig

    def get_info(self):
        return AoInfo(self._rig)

    def a_out(self, channel, analog_range, flags, data):
        rig = self._rig
        rig.calls.append(("a_out", channel, analog_range, flags, data))
        assert isinstance(analog_range, Range) and isinstance(flags, AOutFlag)
        assert isinstance(data, float)
        if not 0 <= channel < rig.ao_channels:
            raise ULException(ULError.BAD_AO_CHAN)
        if analog_range not in rig.ao_ranges:
            raise ULException(ULError.BAD_RANGE)
        low, high = RANGE_LIMITS_V[analog_range]
        if not low <= data <= high:
            raise ULException(ULError.BAD_DA_VAL)
        rig.check_connected()
        rig.ao_values[channel] = data


class AiInfo:
    def __init__(self, rig):
        self._rig = rig

    def get_num_chans(self):
        return max(n for n, _ in self._rig.ai.values())

    def get_num_chans_by_mode(self, input_mode):
        assert isinstance(input_mode, AiInputMode)
        return self._rig.ai.get(input_mode, (0, []))[0]

    def get_ranges(self, input_mode):
        assert isinstance(input_mode, AiInputMode)
        return list(self._rig.ai.get(input_mode, (0, []))[1])


class AiDevice:
    def __init__(self, rig):
        self._rig = rig

    def get_info(self):
        return AiInfo(self._rig)

    def a_in(self, channel, input_mode, analog_range, flags):
        rig = self._rig
        rig.calls.append(("a_in", channel, input_mode, analog_range, flags))
        assert isinstance(input_mode, AiInputMode) and isinstance(analog_range, Range)
        assert isinstance(flags, AInFlag)
        if input_mode not in rig.ai:
            raise ULException(ULError.BAD_INPUT_MODE)
        n_channels, ranges = rig.ai[input_mode]
        if not 0 <= channel < n_channels:
            raise ULException(ULError.BAD_AI_CHAN)
        if analog_range not in ranges:
            raise ULException(ULError.BAD_RANGE)
        if flags & ~(AInFlag.NOSCALEDATA | AInFlag.NOCALIBRATEDATA):
            raise ULException(ULError.BAD_FLAG)
        rig.check_connected()
        if isinstance(rig.monitor_override, BaseException):
            raise rig.monitor_override
        if rig.monitor_override is not None:
            value = float(rig.monitor_override)
        elif (input_mode, channel) == rig.monitor_wiring:
            value = rig.amplifier_output_V / rig.real_monitor_V_per_V
        else:
            value = 0.0  # an unwired input
        low, high = RANGE_LIMITS_V[analog_range]
        return min(max(value, low), high)  # the ADC saturates at the range ends


class DioInfo:
    def __init__(self, rig):
        self._rig = rig

    def get_num_ports(self):
        return len(self._rig.dio)

    def get_port_types(self):
        return [p for p, _, _ in self._rig.dio]

    def get_port_info(self, port_type):
        for port, bits, io_type in self._rig.dio:
            if port == port_type:
                return DioPortInfo(port, io_type, bits)
        raise ULException(ULError.BAD_PORT_TYPE)


class DioDevice:
    def __init__(self, rig):
        self._rig = rig

    def get_info(self):
        return DioInfo(self._rig)

    def d_config_port(self, port_type, direction):
        rig = self._rig
        rig.calls.append(("d_config_port", port_type, direction))
        bits, io_type = rig.find_port(port_type)
        assert isinstance(direction, DigitalDirection)
        rig.check_connected()
        if io_type not in (DigitalPortIoType.IO, DigitalPortIoType.BITIO):
            raise ULException(ULError.BAD_DIG_OPERATION)
        for bit in range(bits):
            if direction == DigitalDirection.OUTPUT:
                rig.output_bits.add((port_type, bit))
            else:
                rig.output_bits.discard((port_type, bit))

    def d_config_bit(self, port_type, bit_number, direction):
        rig = self._rig
        rig.calls.append(("d_config_bit", port_type, bit_number, direction))
        bits, io_type = rig.find_port(port_type)
        assert isinstance(direction, DigitalDirection)
        if not 0 <= bit_number < bits:
            raise ULException(ULError.BAD_BIT_NUM)
        rig.check_connected()
        if io_type != DigitalPortIoType.BITIO:  # "the port must be configurable (BITIO)"
            raise ULException(ULError.BAD_DIG_OPERATION)
        if direction == DigitalDirection.OUTPUT:
            rig.output_bits.add((port_type, bit_number))
        else:
            rig.output_bits.discard((port_type, bit_number))

    def d_bit_out(self, port_type, bit_number, data):
        rig = self._rig
        rig.calls.append(("d_bit_out", port_type, bit_number, data))
        bits, io_type = rig.find_port(port_type)
        if not 0 <= bit_number < bits:
            raise ULException(ULError.BAD_BIT_NUM)
        if io_type == DigitalPortIoType.IN:
            raise ULException(ULError.BAD_DIG_OPERATION)
        if (port_type, bit_number) not in rig.output_bits:
            raise ULException(ULError.WRONG_DIG_CONFIG)
        rig.check_connected()
        rig.bit_levels[(port_type, bit_number)] = 1 if data else 0


class FakeDaqDevice:
    """uldaq's ``DaqDevice(descriptor)``; :func:`make` binds a subclass to its rig (class attribute ``rig``)."""

    rig: FakeRig

    def __init__(self, descriptor):
        self._rig = type(self).rig
        self._rig.calls.append(("DaqDevice", descriptor.unique_id))

    def connect(self):
        rig = self._rig
        rig.calls.append(("connect",))
        if rig.connect_error is not None:
            raise ULException(rig.connect_error)
        rig.connected = True

    def is_connected(self):
        return self._rig.connected and not self._rig.unplugged

    def get_ao_device(self):
        return AoDevice(self._rig) if self._rig.has_ao else None

    def get_ai_device(self):
        return AiDevice(self._rig) if self._rig.has_ai else None

    def get_dio_device(self):
        return DioDevice(self._rig) if self._rig.has_dio else None

    def disconnect(self):
        rig = self._rig
        rig.calls.append(("disconnect",))
        if not rig.connected or rig.unplugged:
            raise ULException(ULError.DEV_NOT_CONNECTED)
        rig.connected = False

    def release(self):
        self._rig.calls.append(("release",))


def make(product="USB-1208HS-4AO", unique_id="01ABCDEF"):
    """(module, rig): a fake ``uldaq`` module and the fake hardware it drives."""
    rig = FakeRig(product, unique_id)
    ul = types.ModuleType("uldaq")

    def get_daq_device_inventory(interface_type, number_of_devices=100):
        rig.calls.append(("get_daq_device_inventory", interface_type))
        assert isinstance(interface_type, InterfaceType)
        if rig.inventory_error is not None:
            raise ULException(rig.inventory_error)
        return list(rig.descriptors)

    daq_device = type("DaqDevice", (FakeDaqDevice,), {"rig": rig})
    for obj in (ULError, InterfaceType, Range, AOutFlag, AInFlag, AiInputMode, DigitalDirection, DigitalPortIoType,
                DigitalPortType, ULException, DaqDeviceDescriptor, daq_device, get_daq_device_inventory):
        setattr(ul, obj.__name__, obj)
    rig.uldaq = ul
    return ul, rig
