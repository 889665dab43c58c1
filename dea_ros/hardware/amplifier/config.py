"""amplifier_node's configuration: its parameters, validated into limits and a hardware expectation.

:func:`amplifier_config_from_parameters` turns the node's parameters (:data:`AMPLIFIER_PARAMETERS`,
e.g. the ``ros__parameters`` of config/amplifier.yaml) into an :class:`AmplifierConfig`: the
:class:`~dea_ros.hardware.amplifier.limits.SafetyLimits` fixed at start-up and the
:class:`~dea_ros.hardware.amplifier.rig_description.AmplifierRigExpectation` the DAQ is checked
against, without ROS or hardware (amplifier_node at configure, ``dea-ros rig check``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from ...model.parameters import load_parameters
from .limits import SafetyLimits
from .udp import DEFAULT_MOCK_PORT
from .rig_description import AmplifierRigExpectation, describe_amplifier_rig

__all__ = ["AMPLIFIER_PARAMETERS", "BACKENDS", "AmplifierConfig", "amplifier_config_from_parameters"]

BACKENDS = ("mock", "uldaq", "inprocess")

#: amplifier_node's parameters, name -> (default, description); all fixed at start-up (read-only).
AMPLIFIER_PARAMETERS: dict[str, tuple[Any, str]] = {
    "backend": ("mock", "mock (UDP to mock_hardware_node), uldaq (MCC DAQ) or inprocess"),
    "params_file": ("A2", "membrane (preset or YAML, with breakdown_field_V_per_m) whose breakdown limit "
                          "bounds the output; read once at start-up"),
    "margin": (0.9, "fraction of the breakdown voltage allowed, in (0, 1)"),
    "max_voltage_V": (0.0, "maximum output, V (0: the membrane limit; above it is refused)"),
    "slew_rate_V_per_s": (100000.0, "largest rate of change of the output, V/s (1 .. 1e7)"),
    "ramp_down_rate_V_per_s": (10000.0, "rate of every ramp to 0 V, V/s (<= slew; 0 V within 10 s after "
                                        "the watchdog)"),
    "watchdog_timeout_s": (0.5, "ramp to 0 V after this long without a command, s"),
    "update_rate_hz": (1000.0, "output update and publication rate, Hz (1 .. 20000)"),
    "max_command_batch": (50, "simulated time only: most samples of one voltage_cmd_batch (one applied per "
                              "update, each through every limit; the batch may not span more than "
                              "watchdog_timeout_s; 0: batches refused)"),
    "mock_port": (DEFAULT_MOCK_PORT, "UDP port of mock_hardware_node (backend mock)"),
    "uldaq_unique_id": ("", "DAQ unique id (empty: the first USB device)"),
    "uldaq_channel": (0, "analog output channel wired to the amplifier input"),
    "uldaq_range": ("auto", "analog output range: auto (the smallest the board offers that covers "
                            "0 .. ceiling / gain) or a uldaq Range name"),
    "amplifier_gain_V_per_V": (1000.0, "amplifier gain, V/V (TREK 10/10B-HS: 1000)"),
    "amplifier_max_output_V": (10000.0, "rated output of the amplifier, V (TREK 10/10B-HS: 10000); the ceiling "
                                        "may not exceed it"),
    "amplifier_input_full_scale_V": (10.0, "amplifier input for the rated output, V (TREK: 10); gain x full "
                                           "scale must equal the rated output"),
    "monitor_channel": (-1, "uldaq analog input wired to the amplifier's voltage monitor (-1: none)"),
    "monitor_gain_V_per_V": (0.0, "high volts per monitor volt; required with a monitor (its own setting, from the "
                                  "amplifier's data sheet: no default to the amplifier gain)"),
    "monitor_range": ("auto", "monitor input range: auto or a uldaq Range name"),
    "monitor_input_mode": ("SINGLE_ENDED", "monitor input mode: SINGLE_ENDED or DIFFERENTIAL"),
    "monitor_tolerance_V": (50.0, "monitor vs command: allowed difference, V (plus the fraction below)"),
    "monitor_tolerance_fraction": (0.05, "monitor vs command: allowed difference as a fraction of the command"),
    "gain_check_V": (40.0, "with a monitor: the loop check's voltage on every activation, V (5 .. 200; below the "
                           "ceiling)"),
    "gain_check_tolerance_fraction": (0.2, "loop check: allowed |monitor / output - 1| (0.01 .. 0.5)"),
    "gain_check_settle_s": (0.05, "loop check: how long the output holds gain_check_V before the comparison, s"),
    "enable_port": ("", "uldaq digital port of the amplifier's enable/interlock input ('': none), e.g. AUXPORT"),
    "enable_bit": (0, "bit of enable_port"),
    "enable_active_high": (True, "enable_port level that enables the amplifier"),
    "enable_heartbeat": (False, "toggle the enable line on every update while enabled (for a hardware "
                                "watchdog relay that drops the enable when the toggling stops)"),
}


@dataclass(frozen=True)
class AmplifierConfig:
    """amplifier_node's configuration, validated: the limits and what it expects of the hardware."""

    values: dict[str, Any]  #: every parameter (defaults filled in)
    limits: SafetyLimits  #: the limits fixed at start-up (ceiling = ``limits.max_voltage_V``)
    expected: AmplifierRigExpectation

    @property
    def ceiling_V(self) -> float:
        return self.limits.max_voltage_V


def amplifier_config_from_parameters(values: Mapping[str, Any], use_sim_time: bool = False) -> AmplifierConfig:
    """Validate amplifier_node's parameters (e.g. the ``ros__parameters`` of config/amplifier.yaml;
    missing ones take their defaults) and derive the limits and the hardware expectation, without ROS
    or hardware. Raises ``ValueError`` (:class:`~dea_ros.errors.SafetyConfigError`,
    :class:`~dea_ros.errors.ParameterError`) naming the parameter and the likely slip.

    The board itself is checked by
    :func:`~dea_ros.hardware.amplifier.rig_description.describe_amplifier_rig` with ``result.expected``.
    """
    c, backend = _parameters_with_defaults(values, use_sim_time)
    configured_max = _check_ranges(c)
    limits = _membrane_limits(c, configured_max)
    expected = _expectation(c, backend, limits)
    description = describe_amplifier_rig(expected, None)  # the board is checked when connected
    if not description.ok:
        raise ValueError("; ".join(description.mismatches))
    return AmplifierConfig(dict(c), limits, expected)


def _parameters_with_defaults(values: Mapping[str, Any], use_sim_time: bool) -> tuple[dict[str, Any], str]:
    """Every parameter (unknown ones refused, missing ones defaulted) and the backend (simulated time: mock only)."""
    unknown = sorted(set(values) - set(AMPLIFIER_PARAMETERS) - {"autostart", "use_sim_time"})
    if unknown:
        raise ValueError(f"unknown amplifier_node parameter(s) {unknown}; known: {sorted(AMPLIFIER_PARAMETERS)}")
    c = {name: values.get(name, default) for name, (default, _) in AMPLIFIER_PARAMETERS.items()}
    use_sim_time = bool(values.get("use_sim_time", use_sim_time))
    backend = str(c["backend"]).strip()
    if backend not in BACKENDS:
        raise ValueError(f"parameter 'backend': one of {BACKENDS}, got {backend!r}")
    if use_sim_time and backend != "mock":
        raise ValueError(
            f"parameter 'use_sim_time': simulated time is accepted only with the mock backend (a simulated "
            f"clock must never pace real high voltage); backend is {backend!r}: set use_sim_time:=false")
    return c, backend


def _number_in(c: Mapping[str, Any], name: str, low: float, high: float, hint: str = "") -> float:
    """Parameter ``name`` as a finite number in ``[low, high]``; ``ValueError`` naming it otherwise."""
    try:
        value = float(c[name])
    except (TypeError, ValueError):
        raise ValueError(f"parameter '{name}': must be a number, got {c[name]!r}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"parameter '{name}': {value:g} is outside [{low:g}, {high:g}]" +
                         (f"; {hint}" if hint else ""))
    return value


def _check_ranges(c: Mapping[str, Any]) -> float:
    """Every numeric parameter within its plausible range (unit slips); returns max_voltage_V (0: none)."""
    _number_in(c, "update_rate_hz", 1.0, 20000.0, "Hz")
    _number_in(c, "slew_rate_V_per_s", 1.0, 1e7, "V/s (2.2 kV in 22 ms = 1e5 V/s; a value in V/ms?)")
    _number_in(c, "mock_port", 1, 65535)
    _number_in(c, "max_command_batch", 0, 1000, "samples per batch")
    _number_in(c, "uldaq_channel", 0, 255)
    _number_in(c, "enable_bit", 0, 63)
    _number_in(c, "monitor_channel", -1, 255, "-1 for no monitor")
    _number_in(c, "monitor_tolerance_V", 1.0, 1e4, "V")
    _number_in(c, "monitor_tolerance_fraction", 0.0, 0.5)
    _number_in(c, "monitor_gain_V_per_V", 0.0, 1e6, "high volts per monitor volt")
    if int(c["monitor_channel"]) >= 0 and not float(c["monitor_gain_V_per_V"]) > 0.0:
        raise ValueError(
            f"parameter 'monitor_gain_V_per_V': required with a monitor (monitor_channel {int(c['monitor_channel'])}); "
            "set it from the amplifier's data sheet (TREK 10/10B-HS: 1000 V/V). It is a separate setting: "
            "defaulting it to amplifier_gain_V_per_V would make a gain slip invisible to the monitor")
    _number_in(c, "gain_check_V", 5.0, 200.0, "V (a few tens of volts)")
    _number_in(c, "gain_check_tolerance_fraction", 0.01, 0.5)
    _number_in(c, "gain_check_settle_s", 0.0, 5.0, "s")
    _number_in(c, "amplifier_max_output_V", 1.0, 30000.0, "V (TREK 10/10B-HS: 10000; a value in kV?)")
    _number_in(c, "amplifier_input_full_scale_V", 0.1, 20.0, "V (TREK: 10)")
    _number_in(c, "amplifier_gain_V_per_V", 1.0, 1e5, "V/V (TREK 10/10B-HS: 1000)")
    return _number_in(c, "max_voltage_V", 0.0, 30000.0, "V, 0 for the membrane limit (a value in kV?)")


def _membrane_limits(c: Mapping[str, Any], configured_max: float) -> SafetyLimits:
    """The limits of the membrane in ``params_file`` (its breakdown limit bounds the output)."""
    try:
        membrane = load_parameters(str(c["params_file"]), require=("breakdown_field_V_per_m",))
    except FileNotFoundError as exc:
        raise ValueError(f"parameter 'params_file': {exc}") from None
    return SafetyLimits.from_membrane(
        membrane.thickness_m, membrane.breakdown_field_V_per_m, float(c["margin"]),
        slew_rate_V_per_s=float(c["slew_rate_V_per_s"]),
        watchdog_timeout_s=float(c["watchdog_timeout_s"]),
        ramp_down_rate_V_per_s=float(c["ramp_down_rate_V_per_s"]),
        max_voltage_V=configured_max if configured_max > 0 else None,
    )


def _expectation(c: Mapping[str, Any], backend: str, limits: SafetyLimits) -> AmplifierRigExpectation:
    """What the configuration expects of the amplifier and its DAQ."""
    monitor_channel = int(c["monitor_channel"])
    return AmplifierRigExpectation(
        backend=backend, ceiling_V=limits.max_voltage_V,
        amplifier_gain_V_per_V=float(c["amplifier_gain_V_per_V"]),
        amplifier_max_output_V=float(c["amplifier_max_output_V"]),
        amplifier_input_full_scale_V=float(c["amplifier_input_full_scale_V"]),
        unique_id=str(c["uldaq_unique_id"]) or None, ao_channel=int(c["uldaq_channel"]),
        ao_range=str(c["uldaq_range"]),
        monitor_channel=monitor_channel if monitor_channel >= 0 else None,
        monitor_gain_V_per_V=float(c["monitor_gain_V_per_V"]) or None,
        monitor_range=str(c["monitor_range"]), monitor_input_mode=str(c["monitor_input_mode"]),
        enable_port=str(c["enable_port"]).strip() or None, enable_bit=int(c["enable_bit"]),
    )
