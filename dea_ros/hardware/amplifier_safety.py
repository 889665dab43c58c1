"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.hardware.amplifier.safety.

SafetyLimits, membrane_voltage_limit_V and the constants: dea_ros.hardware.amplifier.limits.
"""
from ..errors import SafetyConfigError
from .amplifier.limits import (
    ABSOLUTE_MAX_VOLTAGE_V,
    MAX_THICKNESS_M,
    MAX_TIME_TO_ZERO_S,
    MAX_WATCHDOG_TIMEOUT_S,
    MIN_THICKNESS_M,
    SafetyLimits,
    membrane_voltage_limit_V,
)
from .amplifier.safety import (
    ACCEPTED,
    CommandResult,
    ControlClock,
    ControllerDiagnostics,
    ControllerState,
    RejectionReason,
    SafeVoltageController,
    drive_to_zero,
)

__all__ = [
    "SafetyConfigError", "SafetyLimits", "ControllerState", "RejectionReason", "CommandResult", "ACCEPTED",
    "ControllerDiagnostics", "SafeVoltageController", "membrane_voltage_limit_V", "drive_to_zero", "ControlClock",
    "ABSOLUTE_MAX_VOLTAGE_V", "MAX_WATCHDOG_TIMEOUT_S", "MAX_TIME_TO_ZERO_S", "MIN_THICKNESS_M", "MAX_THICKNESS_M",
]
