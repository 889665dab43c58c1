"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.hardware.amplifier.

Per name: base, inprocess, udp, uldaq, rig_description, config modules of dea_ros.hardware.amplifier;
MockAmplifierReceiver, ReceivedVoltage: dea_ros.sim.amplifier_receiver.
"""
from ..errors import AmplifierBackendError, AmplifierRangeWarning
from ..sim.amplifier_receiver import MockAmplifierReceiver, ReceivedVoltage
from .amplifier.base import AmplifierBackend
from .amplifier.config import AMPLIFIER_PARAMETERS, AmplifierConfig, amplifier_config_from_parameters
from .amplifier.inprocess import InProcessAmplifierBackend
from .amplifier.rig_description import (
    KNOWN_DAQ_BOARDS,
    AmplifierRigDescription,
    AmplifierRigExpectation,
    DaqBoardInfo,
    choose_daq_range,
    describe_amplifier_rig,
    parse_daq_range,
)
from .amplifier.udp import (
    DATAGRAM_MAGIC,
    DATAGRAM_SIZE,
    MockAmplifierBackend,
    VoltageDatagram,
    decode_voltage_datagram,
    encode_voltage_datagram,
)
from .amplifier.uldaq import ULDAQ_INSTALL_HINT, UldaqAmplifierBackend, query_uldaq_board

__all__ = [
    "AmplifierBackendError", "AmplifierRangeWarning", "AmplifierBackend", "InProcessAmplifierBackend",
    "MockAmplifierBackend", "MockAmplifierReceiver", "ReceivedVoltage", "VoltageDatagram", "encode_voltage_datagram",
    "decode_voltage_datagram", "DATAGRAM_MAGIC", "DATAGRAM_SIZE", "UldaqAmplifierBackend", "parse_daq_range",
    "choose_daq_range", "ULDAQ_INSTALL_HINT", "DaqBoardInfo", "AmplifierRigExpectation", "AmplifierRigDescription",
    "describe_amplifier_rig", "query_uldaq_board", "KNOWN_DAQ_BOARDS", "AMPLIFIER_PARAMETERS", "AmplifierConfig",
    "amplifier_config_from_parameters",
]
