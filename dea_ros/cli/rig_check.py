"""``dea-ros rig check``: what is connected, what the configuration expects, every mismatch.

Runs before any voltage is applied and writes nothing to the hardware: it reads the node
configurations (the installed ``config/amplifier.yaml`` and ``config/laser_sensor.yaml`` by
default, or the files a lab uses with ``--params-file``), validates them with the same code the
nodes run at configure (:func:`~dea_ros.hardware.amplifier.config.amplifier_config_from_parameters`),
asks the DAQ what it offers (:func:`~dea_ros.hardware.amplifier.uldaq.query_uldaq_board`, uldaq
backend only) and the laser what it is and how it is set
(:func:`~dea_ros.hardware.laser.ild1320_serial.describe_ild1320`, ild1320 backend only), and compares.

Exit codes: 0 all consistent, 1 a mismatch or a device that cannot be reached, 2 a configuration
that is invalid in itself (the message names the parameter and the likely slip).
No ROS import: this works on a PC where the nodes are not running.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Mapping, Optional

import yaml

__all__ = ["RigCheckReport", "check_rig", "node_parameters_from_file", "register"]


@dataclass
class RigCheckReport:
    """Result of :func:`check_rig`: one section per device, each with its report lines."""

    sections: Dict[str, List[str]] = field(default_factory=dict)
    mismatches: List[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.mismatches

    def lines(self) -> List[str]:
        out: List[str] = []
        for name, lines in self.sections.items():
            out.append(f"[{name}]")
            out += [f"  {line}" for line in lines]
        out += [f"MISMATCH {m}" for m in self.mismatches]
        out.append("result: OK, configuration and hardware agree" if self.ok else
                   f"result: {len(self.mismatches)} mismatch(es); no voltage may be applied until they are fixed")
        return out

    def as_dict(self) -> Dict[str, Any]:
        return {"ok": self.ok, "sections": self.sections, "mismatches": self.mismatches}


def node_parameters_from_file(path: Path, node_name: str) -> Dict[str, Any]:
    """The ``ros__parameters`` of ``node_name`` in a ROS 2 parameters file.

    Accepts the section keyed ``node_name``, ``/ns/node_name`` or ``/**/node_name`` (as
    ``--params-file`` does). Raises ``ValueError`` naming the file when it has no such section.
    """
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read the parameters file ({exc})") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a ROS 2 parameters file (expected '<node>: ros__parameters: ...')")
    for key, section in data.items():
        if str(key).rstrip("/").split("/")[-1] == node_name and isinstance(section, dict):
            params = section.get("ros__parameters", {})
            if not isinstance(params, dict):
                raise ValueError(f"{path}: '{key}: ros__parameters' must be a mapping")
            return dict(params)
    raise ValueError(f"{path}: no section for {node_name} (keys: {list(data)}); "
                     f"expected '/**/{node_name}: ros__parameters: ...'")


def _check_amplifier(values: Mapping[str, Any], query_board: Callable[..., Any]):
    from ..errors import AmplifierBackendError
    from ..hardware.amplifier.config import amplifier_config_from_parameters
    from ..hardware.amplifier.rig_description import describe_amplifier_rig

    config = amplifier_config_from_parameters(values)  # ValueError: invalid in itself -> exit 2
    board = None
    lines: List[str] = []
    mismatches: List[str] = []
    if config.expected.backend == "uldaq":
        try:
            board = query_board(unique_id=config.expected.unique_id)
        except AmplifierBackendError as exc:
            mismatches.append(f"DAQ not reachable: {exc}")
    description = describe_amplifier_rig(config.expected, board)
    lines += description.lines()
    mismatches += list(description.mismatches)
    return lines, mismatches


def _check_laser(values: Mapping[str, Any], describe_sensor: Callable[..., Any]):
    from ..hardware.laser.ild1320_protocol import LaserSensorExpectation
    from ..hardware.laser import SensorError

    backend = str(values.get("backend", "ild1320"))
    if backend != "ild1320":
        return [f"laser backend: {backend} (simulated; nothing to query)"], []
    port = str(values.get("port", "/dev/ttyUSB0"))
    expected = LaserSensorExpectation(measuring_range_m=float(values.get("measuring_range_m", 0.01)),
                                      measuring_rate_hz=float(values.get("measuring_rate_hz", 2000.0)))
    try:
        report = describe_sensor(port, expected, baudrate=int(values.get("baudrate", 921600)))
    except SensorError as exc:
        return [f"laser on {port}: not reachable"], [f"laser not reachable on {port}: {exc}"]
    return [f"laser on {port}:"] + list(report.lines()), list(report.mismatches)


def check_rig(amplifier_values: Optional[Mapping[str, Any]], laser_values: Optional[Mapping[str, Any]], *,
              query_board: Optional[Callable[..., Any]] = None,
              describe_sensor: Optional[Callable[..., Any]] = None) -> RigCheckReport:
    """Compare what is connected with what the node configurations expect (writes nothing).

    ``amplifier_values`` / ``laser_values``: the nodes' parameters (None skips that device).
    ``query_board`` / ``describe_sensor``: the device queries (defaults: the real uldaq and
    ILD1320 readers; tests pass fakes). Raises ``ValueError`` for a configuration that is
    invalid in itself.
    """
    if query_board is None:
        from ..hardware.amplifier.uldaq import query_uldaq_board as query_board
    if describe_sensor is None:
        from ..hardware.laser.ild1320_serial import describe_ild1320 as describe_sensor
    report = RigCheckReport()
    if amplifier_values is not None:
        lines, mismatches = _check_amplifier(amplifier_values, query_board)
        report.sections["amplifier_node"] = lines
        report.mismatches += [f"amplifier_node: {m}" for m in mismatches]
    if laser_values is not None:
        lines, mismatches = _check_laser(laser_values, describe_sensor)
        report.sections["laser_sensor_node"] = lines
        report.mismatches += [f"laser_sensor_node: {m}" for m in mismatches]
    return report


def _overrides(pairs: List[str], option: str) -> Dict[str, Any]:
    out: Dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition(":=")
        if not sep or not key:
            raise ValueError(f"{option} {pair!r}: expected NAME:=VALUE (as ros2 run -p), e.g. backend:=uldaq")
        out[key.strip()] = yaml.safe_load(value)
    return out


def cmd_rig_check(args) -> int:
    from ..model.parameters import config_dir

    def values(skip: bool, params_file: Optional[str], default_name: str, node: str, sets: List[str], option: str):
        if skip:
            return None
        path = Path(params_file) if params_file else config_dir() / default_name
        merged = node_parameters_from_file(path, node)
        merged.update(_overrides(sets, option))
        return merged

    amplifier = values(args.no_amplifier, args.amplifier_params_file, "amplifier.yaml", "amplifier_node",
                       args.amplifier, "--amplifier")
    laser = values(args.no_laser, args.laser_params_file, "laser_sensor.yaml", "laser_sensor_node",
                   args.laser, "--laser")
    report = check_rig(amplifier, laser)
    if args.json:
        print(json.dumps(report.as_dict(), indent=2))
    else:
        print("\n".join(report.lines()))
    return 0 if report.ok else 1


def register(rig_subparsers) -> None:
    """Add ``check`` to the ``dea-ros rig`` subcommands."""
    p = rig_subparsers.add_parser(
        "check", help="what is connected vs what the configuration expects, before any voltage (writes nothing)")
    p.add_argument("--amplifier-params-file", help="amplifier_node parameters (default: the package's "
                                                   "config/amplifier.yaml)")
    p.add_argument("--laser-params-file", help="laser_sensor_node parameters (default: config/laser_sensor.yaml)")
    p.add_argument("--amplifier", action="append", metavar="NAME:=VALUE",
                   help="override an amplifier_node parameter, e.g. --amplifier backend:=uldaq")
    p.add_argument("--laser", action="append", metavar="NAME:=VALUE",
                   help="override a laser_sensor_node parameter, e.g. --laser port:=/dev/ttyUSB1")
    p.add_argument("--no-amplifier", action="store_true", help="skip the amplifier and its DAQ")
    p.add_argument("--no-laser", action="store_true", help="skip the laser sensor")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=cmd_rig_check)
