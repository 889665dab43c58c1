"""The connected ILD1320 against the configuration: what it reports, what is expected (pure, no I/O).

The sources of the facts below are in :mod:`dea_ros.hardware.laser.ild1320_protocol`.

*Known state on connect* [1320 manual A 3.5.3.2, A 3.6; 1420 manual A 3.4.6.2,
A 3.5.1]: ``OUTPUT RS422`` (values on the serial line), ``OUTADD_RS422 NONE``
(no additional values: exposure, counter, ... would interleave with the
distances), ``OUTHOLD NONE`` (an error value is sent as an error, never replaced
by the last valid value: a held value would look like a fresh, valid sample),
``MASTERMV NONE`` (no mastering), ``MEASRATE`` as configured; each read back.
The query replies are assumed to follow the general reply format ``<Command>
<Parameter> ...`` (``OUTHOLD NONE``, ``MASTERMV NONE``, ``OUTADD_RS422 NONE``):
**unverified** on a real ILD1320. :func:`check_laser_sensor` compares what the
sensor reports with the configuration (:class:`LaserSensorReport`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from .commands import ALLOWED_MEASURING_RATES_HZ, validate_measuring_rate_hz
from .frames import DEFAULT_MEASURING_RANGE_M

__all__ = [
    "MODEL_PREFIX",
    "KNOWN_STATE",
    "LaserSensorSettings",
    "LaserSensorExpectation",
    "LaserSensorReport",
    "check_laser_sensor",
]

#: Model name prefix of the sensors this backend drives (``GETINFO`` ``Name:`` line).
MODEL_PREFIX = "ILD1320"

#: The state the backend puts the sensor into on every connect (query reply values).
KNOWN_STATE: dict[str, object] = {
    "output": "RS422",
    "additional_outputs": (),
    "output_hold": "NONE",
    "mastering": "NONE",
}

_RANGE_ABS_TOL_M = 5e-6  # GETINFO prints the range in mm with 2 decimals


@dataclass(frozen=True)
class LaserSensorSettings:
    """What a connected ILD1320 reports about itself (``None``: not read / unreadable).

    ``measuring_rate_hz`` is the number the sensor sent, not validated (it may be
    0 or 7000 on a misbehaving sensor). ``unreadable`` has one sentence per reply
    that could not be read.
    """

    model: str = ""
    serial_number: str = ""
    measuring_range_m: float | None = None
    measuring_rate_hz: float | None = None
    output: str | None = None
    additional_outputs: tuple[str, ...] | None = None
    output_hold: str | None = None
    mastering: str | None = None
    unreadable: tuple[str, ...] = ()


@dataclass(frozen=True)
class LaserSensorExpectation:
    """What the configuration expects of the sensor.

    ``measuring_range_m``: the head's measuring range (laser_sensor_node parameter
    ``measuring_range_m``); ``None`` accepts any range the sensor reports.
    ``measuring_rate_hz``: the rate the node sets on connect (``None``: keep).
    """

    measuring_range_m: float | None = DEFAULT_MEASURING_RANGE_M
    measuring_rate_hz: float | None = None


@dataclass(frozen=True)
class LaserSensorReport:
    """The connected sensor, the configuration's expectation and their differences.

    ``mismatches``: differences that make the sensor unusable with this
    configuration (another model or measuring range, a rate that is not an
    ILD1320 rate, an unreadable identity): the node refuses to stream.
    ``to_reset``: settings that differ from :data:`KNOWN_STATE` or the configured
    rate; the backend sets them on connect (and reads them back).
    """

    settings: LaserSensorSettings
    expected: LaserSensorExpectation
    mismatches: tuple[str, ...] = ()
    to_reset: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.mismatches

    def lines(self) -> list[str]:
        """Human-readable report, one fact per line."""
        s, e = self.settings, self.expected

        def mm(value: float | None) -> str:
            return "unknown" if value is None else f"{value * 1e3:g} mm"

        def hz(value: float | None) -> str:
            return "unknown" if value is None else f"{value:g} Hz"

        extra = "unknown" if s.additional_outputs is None else (" ".join(s.additional_outputs) or "NONE")
        out = [
            f"laser sensor: {s.model or 'unknown model'}, serial {s.serial_number or 'unknown'}",
            f"  measuring range: {mm(s.measuring_range_m)} (configuration: "
            f"{'any' if e.measuring_range_m is None else mm(e.measuring_range_m)})",
            f"  measuring rate: {hz(s.measuring_rate_hz)} (configuration: "
            f"{'keep' if e.measuring_rate_hz is None else hz(e.measuring_rate_hz)})",
            f"  output {s.output or 'unknown'}, additional outputs {extra}, "
            f"hold {s.output_hold or 'unknown'}, mastering {s.mastering or 'unknown'}",
        ]
        out += [f"  unreadable: {text}" for text in s.unreadable]
        out += [f"  reset on connect: {text}" for text in self.to_reset]
        out += [f"  MISMATCH: {text}" for text in self.mismatches]
        return out


def _range_from_model_m(model: str) -> float | None:
    match = re.match(r"^ILD\s*1320\s*-\s*(\d+(?:\.\d+)?)\b", model.strip(), re.IGNORECASE)
    return None if match is None else float(match.group(1)) * 1e-3


def check_laser_sensor(settings: LaserSensorSettings, expected: LaserSensorExpectation) -> LaserSensorReport:
    """Compare what the sensor reports with the configuration (pure, no I/O).

    Returns a :class:`LaserSensorReport` whose ``mismatches`` name the setting,
    the sensor's value, the configuration's value and the fix.
    """
    mismatches: list[str] = []
    to_reset: list[str] = []
    model = settings.model.strip()
    if not model:
        mismatches.append("model: GETINFO reported no 'Name:'; cannot identify the sensor")
    elif not model.replace(" ", "").upper().startswith(MODEL_PREFIX):
        mismatches.append(f"model: the sensor is a {model!r}; this backend drives an {MODEL_PREFIX} "
                          f"(other models use other rates and codes)")
    reported_range = settings.measuring_range_m
    if reported_range is None:
        mismatches.append("measuring range: GETINFO reported no 'Measuring range: <n>mm'; distances "
                          "cannot be converted without it")
    elif not (math.isfinite(reported_range) and reported_range > 0.0):
        mismatches.append(f"measuring range: GETINFO reported {reported_range!r} m, not a positive range")
    else:
        model_range = _range_from_model_m(model)
        if model_range is not None and abs(model_range - reported_range) > _RANGE_ABS_TOL_M:
            mismatches.append(f"measuring range: GETINFO is inconsistent, name {model!r} but measuring range "
                              f"{reported_range * 1e3:g} mm")
        if expected.measuring_range_m is not None \
                and abs(reported_range - expected.measuring_range_m) > _RANGE_ABS_TOL_M:
            mismatches.append(f"measuring range: the sensor reports {reported_range * 1e3:g} mm but parameter "
                              f"measuring_range_m is {expected.measuring_range_m * 1e3:g} mm; set "
                              f"measuring_range_m to the head's range or connect the right head")
    if expected.measuring_rate_hz is not None:
        try:
            validate_measuring_rate_hz(expected.measuring_rate_hz)
        except ValueError as exc:
            mismatches.append(f"measuring rate: parameter measuring_rate_hz: {exc}")
    rate = settings.measuring_rate_hz
    if rate is not None:
        try:
            rate = validate_measuring_rate_hz(rate)
        except ValueError:
            mismatches.append(f"measuring rate: the sensor reports {rate:g} Hz, which is not an ILD1320 rate "
                              f"({', '.join(f'{r:g}' for r in ALLOWED_MEASURING_RATES_HZ)} Hz)")
        else:
            if expected.measuring_rate_hz is not None and not math.isclose(rate, expected.measuring_rate_hz):
                to_reset.append(f"measuring rate {rate:g} Hz -> {expected.measuring_rate_hz:g} Hz")
    if settings.output is not None and settings.output != KNOWN_STATE["output"]:
        to_reset.append(f"output {settings.output} -> {KNOWN_STATE['output']}")
    if settings.additional_outputs:
        to_reset.append(f"additional outputs {' '.join(settings.additional_outputs)} -> NONE")
    if settings.output_hold is not None and settings.output_hold != KNOWN_STATE["output_hold"]:
        to_reset.append(f"hold mode OUTHOLD {settings.output_hold} -> NONE (errors reported as errors)")
    if settings.mastering is not None and settings.mastering != KNOWN_STATE["mastering"]:
        to_reset.append(f"mastering MASTERMV {settings.mastering} (shifts every distance) -> NONE")
    return LaserSensorReport(settings, expected, tuple(mismatches), tuple(to_reset))
