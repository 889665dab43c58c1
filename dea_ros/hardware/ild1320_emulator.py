"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.sim.ild1320_emulator.

MockDisplacementSensor: dea_ros.sim.mock_sensor; DisplacementSource and the ERROR_* replies:
dea_ros.sim.ild1320_device. The fault injection (misbehave, inject_garbage, corrupt_next, pause,
record_limit / emitted_samples, EmittedSample) is test-only: test/fakes/faulty_ild1320.py.
"""
from ..sim.ild1320_device import (
    ERROR_INVALID_PARAMETER,
    ERROR_LINE_TOO_LONG,
    ERROR_UNKNOWN_COMMAND,
    ERROR_WRONG_PARAMETER_COUNT,
    DisplacementSource,
)
from ..sim.ild1320_emulator import DEFAULT_SYMLINK_PATH, ILD1320Emulator
from ..sim.mock_sensor import MockDisplacementSensor

__all__ = [
    "DEFAULT_SYMLINK_PATH", "DisplacementSource", "ILD1320Emulator", "MockDisplacementSensor",
    "ERROR_UNKNOWN_COMMAND", "ERROR_WRONG_PARAMETER_COUNT", "ERROR_INVALID_PARAMETER", "ERROR_LINE_TOO_LONG",
]
