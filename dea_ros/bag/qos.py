"""QoS profiles as rosbag2 stores them (``offered_qos_profiles``), without rclpy.

rosbag2 records, per topic, the list of QoS profiles offered by the publishers. It stores that
list twice: in ``metadata.yaml`` (``topics_with_message_count[].topic_metadata.offered_qos_profiles``)
and in the MCAP channel metadata (key ``offered_qos_profiles``). Two encodings exist, verified
against ``rosbag2_storage/src/rosbag2_storage/qos.cpp`` (ros2/rosbag2) and the independent reader
``rosbags.rosbag2.metadata`` (``dump_qos_v8`` / ``dump_qos_v9``):

* metadata version >= 9 (rosbag2 0.26+, i.e. **Jazzy, Kilted, Rolling**; ros2/rosbag2 PR #1476):
  policies are lower-case strings from ``rmw_qos_*_policy_to_str`` (``keep_last``, ``reliable``,
  ``best_effort``, ``volatile``, ``transient_local``, ``automatic`` ...). In ``metadata.yaml`` the
  profiles are a YAML *sequence*; in the channel metadata they are the ``YAML::Dump`` text of that
  sequence (block style, no trailing newline).
* metadata version <= 8 (**Humble** writes version 5, Iron 8): policies are the integer values of
  the ``rmw_qos_*_policy_e`` enums and the profiles are a YAML *string* in both places.

Durations are ``{sec, nsec}`` mappings. An "infinite" duration is ``RMW_DURATION_INFINITE`` =
``{sec: 9223372036, nsec: 854775807}``, which is what ``ros2 bag record`` stores for a default
publisher (deadline, lifespan, liveliness lease duration).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import yaml

__all__ = [
    "QosDuration",
    "QosProfile",
    "INFINITE_DURATION",
    "command_qos",
    "sensor_data_qos",
    "qos_to_dict",
    "qos_from_dict",
    "serialize_qos_profiles",
    "parse_qos_profiles",
]


class QosDuration(NamedTuple):
    """A QoS duration as rmw stores it: whole seconds plus nanoseconds."""

    sec: int
    nsec: int


#: ``RMW_DURATION_INFINITE`` (rmw/types.h): what rosbag2 records for "no deadline" etc.
INFINITE_DURATION = QosDuration(9223372036, 854775807)

# rmw_qos_*_policy_e values (rmw/types.h) <-> rmw_qos_*_policy_to_str names.
_HISTORY = {"system_default": 0, "keep_last": 1, "keep_all": 2, "unknown": 3}
_RELIABILITY = {
    "system_default": 0,
    "reliable": 1,
    "best_effort": 2,
    "unknown": 3,
    "best_available": 4,
}
_DURABILITY = {
    "system_default": 0,
    "transient_local": 1,
    "volatile": 2,
    "unknown": 3,
    "best_available": 4,
}
_LIVELINESS = {
    "system_default": 0,
    "automatic": 1,
    "manual_by_node": 2,
    "manual_by_topic": 3,
    "unknown": 4,
    "best_available": 5,
}
_POLICIES = {
    "history": _HISTORY,
    "reliability": _RELIABILITY,
    "durability": _DURABILITY,
    "liveliness": _LIVELINESS,
}
_DURATIONS = ("deadline", "lifespan", "liveliness_lease_duration")

#: Metadata versions from which rosbag2 writes string policy names (ros2/rosbag2 PR #1476).
_FIRST_STRING_ENUM_VERSION = 9


@dataclass(frozen=True)
class QosProfile:
    """One offered QoS profile, in rosbag2's field order.

    Policies are the rmw names (``"keep_last"``, ``"reliable"``, ``"best_effort"``, ``"volatile"``,
    ``"transient_local"``, ``"automatic"`` ...); durations are :class:`QosDuration`.
    ``depth`` is the history depth (number of messages kept for ``keep_last``).
    """

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline: QosDuration = INFINITE_DURATION
    lifespan: QosDuration = INFINITE_DURATION
    liveliness: str = "automatic"
    liveliness_lease_duration: QosDuration = INFINITE_DURATION
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        for field_name, allowed in _POLICIES.items():
            value = getattr(self, field_name)
            if value not in allowed:
                raise ValueError(
                    f"QosProfile.{field_name}={value!r} is not a valid rmw policy name; "
                    f"use one of {sorted(allowed)}"
                )
        if not isinstance(self.depth, int) or isinstance(self.depth, bool) or self.depth < 0:
            raise ValueError(f"QosProfile.depth={self.depth!r} must be an integer >= 0")
        for field_name in _DURATIONS:
            value = getattr(self, field_name)
            if not isinstance(value, QosDuration):
                # Accept plain (sec, nsec) tuples; frozen dataclass -> object.__setattr__.
                try:
                    sec, nsec = value
                    value = QosDuration(int(sec), int(nsec))
                except (TypeError, ValueError):
                    raise ValueError(
                        f"QosProfile.{field_name}={value!r} must be a (sec, nsec) pair"
                    ) from None
                object.__setattr__(self, field_name, value)
            if value.sec < 0 or value.nsec < 0:
                raise ValueError(f"QosProfile.{field_name}={value!r} must not be negative")


def command_qos(depth: int = 10) -> QosProfile:
    """Default profile for commands/state: reliable, volatile, keep_last ``depth`` (rclpy default)."""
    return QosProfile(history="keep_last", depth=depth, reliability="reliable", durability="volatile")


def sensor_data_qos(depth: int = 5) -> QosProfile:
    """Sensor-data profile (``rclpy.qos.qos_profile_sensor_data``): best_effort, volatile, keep_last 5."""
    return QosProfile(
        history="keep_last", depth=depth, reliability="best_effort", durability="volatile"
    )


def qos_to_dict(profile: QosProfile, metadata_version: int) -> dict:
    """Profile as the mapping rosbag2 serializes, for the given ``metadata.yaml`` version."""
    use_names = metadata_version >= _FIRST_STRING_ENUM_VERSION

    def policy(name: str) -> str | int:
        value = getattr(profile, name)
        return value if use_names else _POLICIES[name][value]

    def duration(name: str) -> dict:
        value = getattr(profile, name)
        return {"sec": int(value.sec), "nsec": int(value.nsec)}

    return {
        "history": policy("history"),
        "depth": int(profile.depth),
        "reliability": policy("reliability"),
        "durability": policy("durability"),
        "deadline": duration("deadline"),
        "lifespan": duration("lifespan"),
        "liveliness": policy("liveliness"),
        "liveliness_lease_duration": duration("liveliness_lease_duration"),
        "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
    }


def _policy_from_value(field_name: str, value: Any) -> str:
    table = _POLICIES[field_name]
    if isinstance(value, bool):
        raise ValueError(f"QoS field {field_name!r}: boolean {value!r} is not a policy")
    if isinstance(value, int):
        for name, number in table.items():
            if number == value:
                return name
        raise ValueError(f"QoS field {field_name!r}: unknown rmw enum value {value}")
    if isinstance(value, str):
        key = value.strip().lower()
        if key in table:
            return key
        raise ValueError(
            f"QoS field {field_name!r}: unknown policy {value!r}; expected one of {sorted(table)}"
        )
    raise ValueError(f"QoS field {field_name!r}: expected a name or integer, got {value!r}")


def qos_from_dict(data: Mapping[str, Any]) -> QosProfile:
    """Parse one profile mapping (string or integer policies, any rosbag2 metadata version).

    Missing fields take the :class:`QosProfile` defaults; malformed fields raise ``ValueError``
    naming the field.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"QoS profile must be a mapping, got {type(data).__name__}: {data!r}")
    kwargs: dict = {}
    for field_name in _POLICIES:
        if field_name in data:
            kwargs[field_name] = _policy_from_value(field_name, data[field_name])
    if "depth" in data:
        try:
            kwargs["depth"] = int(data["depth"])
        except (TypeError, ValueError):
            raise ValueError(f"QoS field 'depth': expected an integer, got {data['depth']!r}") from None
    for field_name in _DURATIONS:
        if field_name in data:
            value = data[field_name]
            try:
                kwargs[field_name] = QosDuration(int(value["sec"]), int(value["nsec"]))
            except (TypeError, KeyError, ValueError):
                raise ValueError(
                    f"QoS field {field_name!r}: expected {{sec: int, nsec: int}}, got {value!r}"
                ) from None
    if "avoid_ros_namespace_conventions" in data:
        kwargs["avoid_ros_namespace_conventions"] = bool(data["avoid_ros_namespace_conventions"])
    return QosProfile(**kwargs)


def serialize_qos_profiles(profiles: Iterable[QosProfile], metadata_version: int) -> str:
    """The ``offered_qos_profiles`` string rosbag2 writes (``YAML::Dump`` of the sequence).

    Used verbatim as MCAP channel metadata (all versions) and, for metadata versions <= 8
    (Humble), as the string value in ``metadata.yaml``. An empty list gives ``""``.
    """
    items = [qos_to_dict(p, metadata_version) for p in profiles]
    if not items:
        return ""
    return yaml.safe_dump(items, default_flow_style=False, sort_keys=False).rstrip("\n")


def parse_qos_profiles(value: str | Sequence[Mapping[str, Any]] | None) -> list[QosProfile]:
    """Parse ``offered_qos_profiles`` from metadata.yaml or channel metadata (string or list)."""
    if value is None or value == "" or value == []:
        return []
    items: Any | None = value
    if isinstance(value, str):
        try:
            items = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ValueError(f"offered_qos_profiles is not valid YAML: {exc}") from None
        if items is None:
            return []
    if not isinstance(items, list):
        raise ValueError(
            f"offered_qos_profiles must be a YAML sequence of profiles, got {type(items).__name__}"
        )
    return [qos_from_dict(item) for item in items]
