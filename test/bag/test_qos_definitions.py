"""QoS serialization (Jazzy+ vs Humble encodings) and message definitions / type hashes."""

import re
from pathlib import Path

import pytest
import yaml
from rosbags.rosbag2.metadata import dump_qos_v8, dump_qos_v9, parse_qos as rosbags_parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from dea_ros.bag import (
    BagError,
    INFINITE_DURATION,
    MessageDefinitionStore,
    QosProfile,
    command_qos,
    parse_qos_profiles,
    qos_from_dict,
    qos_to_dict,
    sensor_data_qos,
    serialize_qos_profiles,
)
from dea_ros.bag.vendored_messages import VENDORED_MSG_TEXTS, VENDORED_PACKAGE_VERSIONS

RIG_TYPES = [
    "std_msgs/msg/Float64",
    "std_msgs/msg/String",
    "std_msgs/msg/Header",
    "builtin_interfaces/msg/Time",
    "sensor_msgs/msg/Range",
    "sensor_msgs/msg/BatteryState",
    "rosgraph_msgs/msg/Clock",
    "diagnostic_msgs/msg/DiagnosticArray",
    "diagnostic_msgs/msg/DiagnosticStatus",
    "diagnostic_msgs/msg/KeyValue",
]


def test_presets():
    assert command_qos() == QosProfile("keep_last", 10, "reliable", "volatile")
    assert sensor_data_qos() == QosProfile("keep_last", 5, "best_effort", "volatile")
    assert command_qos().deadline == INFINITE_DURATION == (9223372036, 854775807)


def test_channel_text_matches_rosbags_dumps_and_rosbag2_key_order():
    """Same content as rosbags' v8/v9 dumps; keys in rosbag2's encode order, no trailing newline."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    infinite = QosTime(9223372036, 854775807)
    theirs = Qos(
        QosHistory.KEEP_LAST, 5, QosReliability.BEST_EFFORT, QosDurability.VOLATILE,
        infinite, infinite, QosLiveliness.AUTOMATIC, infinite, False,
    )
    ours_v9 = serialize_qos_profiles([sensor_data_qos(), sensor_data_qos()], 9)
    assert yaml.safe_load(ours_v9) == dump_qos_v9([theirs, theirs])
    ours_v5 = serialize_qos_profiles([sensor_data_qos()], 5)
    assert yaml.safe_load(ours_v5) == yaml.safe_load(dump_qos_v8([theirs]))
    # Order of convert<Rosbag2QoS>::encode in rosbag2_storage/src/rosbag2_storage/qos.cpp.
    keys = [line.lstrip("- ").split(":")[0] for line in ours_v9.splitlines() if not line.startswith("    ")]
    assert keys[:9] == [
        "history", "depth", "reliability", "durability", "deadline", "lifespan",
        "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions",
    ]
    assert ours_v9.startswith("- history: keep_last\n  depth: 5\n  reliability: best_effort\n")
    assert "\n  deadline:\n    sec: 9223372036\n    nsec: 854775807\n" in ours_v9
    assert not ours_v9.endswith("\n")


def test_v9_uses_names_and_v5_uses_rmw_enum_integers():
    profile = QosProfile("keep_all", 0, "best_effort", "transient_local", liveliness="manual_by_topic")
    v9 = qos_to_dict(profile, 9)
    v5 = qos_to_dict(profile, 5)
    assert (v9["history"], v9["reliability"], v9["durability"], v9["liveliness"]) == (
        "keep_all", "best_effort", "transient_local", "manual_by_topic",
    )
    assert (v5["history"], v5["reliability"], v5["durability"], v5["liveliness"]) == (2, 2, 1, 3)
    for version in (5, 9):
        text = serialize_qos_profiles([profile, command_qos()], version)
        assert parse_qos_profiles(text) == [profile, command_qos()]
        parsed_by_rosbags = rosbags_parse_qos(text)
        assert [q.reliability.name.lower() for q in parsed_by_rosbags] == ["best_effort", "reliable"]
    assert serialize_qos_profiles([], 9) == ""
    assert parse_qos_profiles("") == [] and parse_qos_profiles(None) == []


def test_parse_accepts_metadata_lists_and_foxy_style_integers():
    foxy = (
        "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n"
        "  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n"
        "  avoid_ros_namespace_conventions: false"
    )
    (profile,) = parse_qos_profiles(foxy)
    assert profile.history == "unknown" and profile.reliability == "reliable" and profile.depth == 0
    listed = parse_qos_profiles([qos_to_dict(sensor_data_qos(), 9)])
    assert listed == [sensor_data_qos()]


@pytest.mark.parametrize(
    "bad, message",
    [
        ({"reliability": "mostly"}, "unknown policy 'mostly'"),
        ({"history": 17}, "unknown rmw enum value 17"),
        ({"deadline": {"sec": 1}}, "'deadline': expected"),
        ({"depth": "ten"}, "'depth': expected an integer"),
    ],
)
def test_bad_qos_fields_are_named(bad, message):
    with pytest.raises(ValueError, match=message):
        qos_from_dict(bad)


def test_qos_profile_validates_itself():
    with pytest.raises(ValueError, match=r"QosProfile.reliability='fast'"):
        QosProfile(reliability="fast")
    with pytest.raises(ValueError, match="depth"):
        QosProfile(depth=-1)
    assert QosProfile(deadline=(1, 2)).deadline == (1, 2)


def _installed_package_version(source: str) -> str:
    """``<version>`` of the package.xml beside an installed ``share/<pkg>/msg/<Type>.msg``."""
    package_xml = Path(source).parent.parent / "package.xml"
    match = re.search(r"<version>([^<]+)</version>", package_xml.read_text()) if package_xml.is_file() else None
    return match.group(1).strip() if match else ""


@pytest.mark.parametrize("type_name", RIG_TYPES)
def test_vendored_texts_are_the_kilted_definitions(type_name):
    """Field for field (RIHS01 covers names, types, defaults, constants), independent of any install."""
    kilted = getattr(Stores, "ROS2_KILTED", None)
    if kilted is None:
        pytest.skip("this rosbags has no ROS 2 Kilted type store")
    ours = get_typestore(Stores.EMPTY)
    ours.register(get_types_from_msg(VENDORED_MSG_TEXTS[type_name], type_name))
    for dependency in ("std_msgs/msg/Header", "builtin_interfaces/msg/Time", "diagnostic_msgs/msg/DiagnosticStatus",
                       "diagnostic_msgs/msg/KeyValue"):
        ours.register(get_types_from_msg(VENDORED_MSG_TEXTS[dependency], dependency))
    assert ours.hash_rihs01(type_name) == get_typestore(kilted).hash_rihs01(type_name)


@pytest.mark.parametrize("type_name", RIG_TYPES)
def test_recorded_text_is_the_installed_definition_of_the_distro_under_test(type_name):
    """The bag records the installed ``.msg`` (Humble's, Jazzy's, ...), not the vendored copy."""
    text, source = MessageDefinitionStore().msg_text(type_name)
    if source in ("vendored", "extra_definitions"):
        pytest.skip("no ROS message packages installed: the vendored definitions are used")
    package, _, name = type_name.split("/")
    assert Path(source).name == f"{name}.msg" and Path(source).parent.parent.name == package
    assert text == Path(source).read_text(encoding="utf-8")
    assert MessageDefinitionStore().full_definition(type_name).text.startswith(text)
    if _installed_package_version(source) == VENDORED_PACKAGE_VERSIONS[package]:
        assert VENDORED_MSG_TEXTS[type_name] == text  # same release: the copies are exact


def test_full_text_follows_rosbag2_local_message_definition_source():
    store = MessageDefinitionStore(search_prefixes=[])  # vendored only: deterministic
    separator = "=" * 80
    text = store.full_definition("diagnostic_msgs/msg/DiagnosticArray").text
    blocks = text.split("\n" + separator + "\n")
    assert blocks[0] == VENDORED_MSG_TEXTS["diagnostic_msgs/msg/DiagnosticArray"]
    # Dependencies: sorted per level, depth first, each once, named as written in the field.
    assert [b.split("\n", 1)[0] for b in blocks[1:]] == [
        "MSG: diagnostic_msgs/DiagnosticStatus",
        "MSG: diagnostic_msgs/KeyValue",
        "MSG: std_msgs/Header",
        "MSG: builtin_interfaces/Time",
    ]
    assert blocks[2].split("\n", 1)[1] == VENDORED_MSG_TEXTS["diagnostic_msgs/msg/KeyValue"]
    assert store.full_definition("std_msgs/msg/Float64").text == VENDORED_MSG_TEXTS["std_msgs/msg/Float64"]
    clock = store.full_definition("rosgraph_msgs/Clock")
    assert clock.type_name == "rosgraph_msgs/msg/Clock" and clock.type_hash == "" and clock.source == "vendored"


@pytest.mark.parametrize("type_name", RIG_TYPES)
def test_installed_type_hashes_match_an_independent_rihs01_computation(type_name, has_type_hash):
    store = MessageDefinitionStore()
    definition = store.full_definition(type_name)
    if not has_type_hash(type_name):  # Humble generates no type descriptions; none without ROS
        assert definition.type_hash == ""
        pytest.skip(f"no type description (.json) for {type_name} (Humble, or no ROS messages installed): "
                    "no RIHS01 hash to check")
    assert definition.type_hash.startswith("RIHS01_")
    typestore = get_typestore(Stores.EMPTY)
    typestore.register(get_types_from_msg(definition.text, type_name))
    assert typestore.hash_rihs01(type_name) == definition.type_hash


def test_share_directory_lookup_and_missing_types(tmp_path):
    share = tmp_path / "share" / "my_msgs" / "msg"
    share.mkdir(parents=True)
    (share / "Thing.msg").write_text("Part part\nstring name\n")
    (share / "Part.msg").write_text("float64 x\n")
    store = MessageDefinitionStore(search_prefixes=[tmp_path], use_vendored=False)
    definition = store.full_definition("my_msgs/msg/Thing")
    assert definition.text == "Part part\nstring name\n\n" + "=" * 80 + "\nMSG: my_msgs/Part\nfloat64 x\n"
    assert definition.source == str(share / "Thing.msg") and definition.type_hash == ""
    with pytest.raises(BagError, match=r"no .msg definition for std_msgs/msg/Float64: not found under .*share"):
        store.full_definition("std_msgs/msg/Float64")
    with pytest.raises(BagError, match="not a ROS 2 type name"):
        store.msg_text("my_msgs/msg/Thing/Extra")


def test_generated_metadata_is_yaml_cpp_compatible_shape(tmp_path):
    from dea_ros.bag.metadata import FileSummary, TopicSummary, build_bag_metadata, dump_metadata_yaml

    info = build_bag_metadata(
        version=9,
        files=[FileSummary("b_0.mcap", 10, 5, 2)],
        topics=[TopicSummary("/x", "std_msgs/msg/Float64", 2, [command_qos()], "RIHS01_ab")],
        ros_distro="jazzy",
    )
    text = dump_metadata_yaml(info)
    assert text.startswith("rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n")
    assert "  topics_with_message_count:\n    - topic_metadata:\n        name: /x\n" in text
    assert yaml.safe_load(text)["rosbag2_bagfile_information"] == info
    assert info["custom_data"] is None  # yaml-cpp writes '~' for an empty map
