"""Every error and warning class of dea_ros, in one family.

``except DeaRosError`` catches anything this package raises on purpose; the command line turns it
into a one-line message and exit code 2. Each class also keeps the builtin it derived from before
the family existed (``ValueError`` for bad input, ``RuntimeError`` for a failed computation or
device), so callers that catch the builtin keep working.

The classes are grouped by the layer that raises them; the messages always name the file, field
or option concerned and the fix.
"""
from __future__ import annotations

__all__ = [
    "DeaRosError", "DeaRosWarning",
    # model
    "ParameterError", "NoEquilibriumError",
    # solvers
    "HarmonicBalanceError", "ContinuationError", "IntegrationError", "SteadyStateError", "TransientError",
    "VoltageRecordError",
    # identification
    "ExperimentError", "StaticFitError", "DynamicFitError", "JointFitError", "IdentificationError",
    "PlanningError", "ProtocolError",
    # control
    "UnreachableReferenceError", "RetuneWorkerError",
    # study
    "SpecError", "EngineError", "StudyInterrupted",
    # bags
    "BagError", "McapSummaryMissing", "BagWarning", "BagTruncatedWarning",
    # hardware
    "SafetyConfigError", "AmplifierBackendError", "AmplifierRangeWarning",
    "SensorError", "SensorDisconnected", "SensorConfigurationError", "CommandError", "FrameFormatError",
    # command line
    "CliError",
]


class DeaRosError(Exception):
    """Base of every error dea_ros raises on purpose (bad input, failed computation, device fault)."""


class DeaRosWarning(UserWarning):
    """Base of every warning dea_ros issues."""


# --------------------------------------------------------------------------- model
class ParameterError(DeaRosError, ValueError):
    """A parameter set is invalid. The message names the field and the fix."""


class NoEquilibriumError(DeaRosError, ValueError):
    """No static equilibrium exists for the requested voltage and mass."""


# --------------------------------------------------------------------------- solvers
class HarmonicBalanceError(DeaRosError, RuntimeError):
    """Harmonic balance did not converge (the message says how far it got and what to try)."""


class FallbackRefused(HarmonicBalanceError):
    """Harmonic balance failed at a point of an optimiser's scan or trial where forward integration is not
    spent (identify.dynamic_objective): the point is skipped or rejected, not integrated."""


class ContinuationError(DeaRosError, RuntimeError):
    """The continuation could not follow the branch (step size underflow)."""


class IntegrationError(DeaRosError, RuntimeError):
    """The adaptive integrator failed."""


class SteadyStateError(DeaRosError, RuntimeError):
    """Forward integration did not reach the periodic steady state in the time allowed."""


class VoltageRecordError(DeaRosError, ValueError):
    """A recorded voltage that cannot drive a simulation (e.g. one row: an instant, not a record)."""


class TransientError(DeaRosError, RuntimeError):
    """The collocation Newton iteration did not converge (the message says what to try)."""


# --------------------------------------------------------------------------- identification
class ExperimentError(DeaRosError, ValueError):
    """Invalid experiment data; the message names the file, column and row, and the fix."""


class StaticFitError(ExperimentError):
    """The static data cannot support the fit (too few points, no voltage points, ...)."""


class DynamicFitError(ExperimentError):
    """The dynamic data cannot support the fit, or every simulation failed."""


class JointFitError(ExperimentError):
    """The joint refinement cannot run on these data."""


class IdentificationError(ExperimentError):
    """The experiment set cannot be identified as asked (the message says what is missing)."""


class PlanningError(DeaRosError, ValueError):
    """An experiment plan cannot be made from these inputs (a params.yaml without the first fit's
    Fisher information, limits that admit no candidate, ...); the message says what is missing."""


class ProtocolError(DeaRosError, ValueError):
    """A protocol file is invalid (the message names the segment and field)."""


# --------------------------------------------------------------------------- control
class UnreachableReferenceError(DeaRosError, ValueError):
    """A reference the actuator cannot follow (outside the range, or needing u^2 < 0 / too fast)."""


class RetuneWorkerError(DeaRosError, RuntimeError):
    """The retune worker process died, answered too late or failed: no retune this time (it is restarted)."""


# --------------------------------------------------------------------------- study
class SpecError(DeaRosError, ValueError):
    """An invalid study spec; the message names the field and the fix."""


class EngineError(DeaRosError, RuntimeError):
    """The engine cannot run as asked (e.g. Dask missing for ``--scheduler``); the message says the fix."""


class StudyInterrupted(DeaRosError, RuntimeError):
    """The study stopped before all chunks were done; finished chunks are kept for a resume."""


# --------------------------------------------------------------------------- bags
class BagError(DeaRosError):
    """A bag cannot be written or read as requested.

    The message always names the file or directory concerned, what is wrong with it and, where
    there is one, the fix (e.g. "run dea_ros.bag.recover_bag(<dir>)").
    """


class McapSummaryMissing(DeaRosError):
    """A complete MCAP file without a summary section (the reader then scans the records)."""


class BagWarning(DeaRosWarning):
    """A bag was readable but not as expected (e.g. ``metadata.yaml`` missing, fell back to MCAP)."""


class BagTruncatedWarning(BagWarning):
    """An MCAP file ends early (writer killed); only the complete prefix was read."""


# --------------------------------------------------------------------------- hardware
class SafetyConfigError(DeaRosError, ValueError):
    """Invalid safety limits. The message names the field and the fix."""


class AmplifierBackendError(DeaRosError, RuntimeError):
    """An amplifier backend failed or refused a value. The message says what to do."""


class AmplifierRangeWarning(DeaRosWarning):
    """The DAQ range times the amplifier gain does not match the configured maximum voltage."""


class SensorError(DeaRosError, RuntimeError):
    """A displacement sensor operation failed (bad reply, not open, timeout, ...)."""


class SensorDisconnected(SensorError):
    """The sensor delivers no usable data: serial error, port gone, or silence.

    Call :meth:`DisplacementSensor.reconnect` to recover.
    """


class SensorConfigurationError(SensorError):
    """The connected sensor differs from the configuration (model, range, rate, ...).

    ``mismatches`` lists every difference as a sentence naming the setting, what
    the sensor reports and what the configuration expects.
    """

    def __init__(self, message: str, mismatches: "tuple[str, ...]" = ()) -> None:
        super().__init__(message)
        self.mismatches = tuple(mismatches)


class CommandError(SensorError):
    """The sensor refused a command with an ``Exxx`` error message."""

    def __init__(self, command: str, code: int, message: str) -> None:
        super().__init__(f"sensor refused {command!r}: E{code:03d} {message}".rstrip())
        self.command = command
        self.code = code
        self.message = message


class FrameFormatError(DeaRosError, ValueError):
    """Bytes that are not one valid 3-byte measurement frame."""


# --------------------------------------------------------------------------- command line
class CliError(DeaRosError):
    """A user-facing error of the command line: printed without a traceback, exit code 2."""
