"""The high-voltage amplifier: its safety core, its backends and amplifier_node's configuration (no ROS).

* :mod:`.limits`: :class:`SafetyLimits`, fixed at start-up (maximum from the membrane's breakdown
  field, slew rate, watchdog timeout, ramp-down rate);
* :mod:`.safety`: :class:`SafeVoltageController`, the state machine every output goes through
  (0 V unless active and fresh, never above the maximum nor faster than the slew limit, invalid
  commands rejected, ramp to 0 V on every exit), :func:`drive_to_zero` and :class:`ControlClock`;
* :mod:`.base`: :class:`AmplifierBackend`, the interface every backend implements;
* :mod:`.inprocess`, :mod:`.udp`, :mod:`.uldaq`: the backends (in memory; UDP datagrams to the
  simulated rig; a Measurement Computing DAQ, ``uldaq`` imported only when a device is used);
* :mod:`.rig_description`: a DAQ board against what the configuration expects (pure);
* :mod:`.config`: amplifier_node's parameters validated into limits and a hardware expectation;
* :mod:`.gain_check`: :class:`GainLoopCheck`, the low-voltage loop check of the amplifier gain
  against the monitor on activation.
"""
from .base import AmplifierBackend, AmplifierBackendError
from .config import AMPLIFIER_PARAMETERS, BACKENDS, AmplifierConfig, amplifier_config_from_parameters
from .gain_check import GainCheckResult, GainLoopCheck, unverified_gain_note
from .inprocess import InProcessAmplifierBackend
from .limits import SafetyConfigError, SafetyLimits, membrane_voltage_limit_V
from .rig_description import (
    KNOWN_DAQ_BOARDS,
    AmplifierRigDescription,
    AmplifierRigExpectation,
    DaqBoardInfo,
    choose_daq_range,
    describe_amplifier_rig,
    parse_daq_range,
)
from .safety import ControlClock, SafeVoltageController, drive_to_zero
from .udp import MockAmplifierBackend, decode_voltage_datagram, encode_voltage_datagram
from .uldaq import AmplifierRangeWarning, UldaqAmplifierBackend, query_uldaq_board

__all__ = [
    "SafetyLimits", "SafetyConfigError", "membrane_voltage_limit_V", "SafeVoltageController", "drive_to_zero",
    "ControlClock", "AmplifierBackend", "AmplifierBackendError", "AmplifierRangeWarning",
    "InProcessAmplifierBackend", "MockAmplifierBackend", "encode_voltage_datagram", "decode_voltage_datagram",
    "UldaqAmplifierBackend", "query_uldaq_board", "KNOWN_DAQ_BOARDS", "DaqBoardInfo", "AmplifierRigExpectation",
    "AmplifierRigDescription", "describe_amplifier_rig", "parse_daq_range", "choose_daq_range",
    "AMPLIFIER_PARAMETERS", "BACKENDS", "AmplifierConfig", "amplifier_config_from_parameters",
    "GainLoopCheck", "GainCheckResult", "unverified_gain_note",
]
