"""Bags that Humble's and Jazzy's rosbag2 read: format from ROS_DISTRO, parsing rules, conversion.

The rules each distro's rosbag2 applies to ``metadata.yaml`` and to the MCAP metadata are in
``rosbag2_rules.py`` beside this file (with the ros2/rosbag2 files and branches they come from).
"""

import importlib.util
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as RosbagsReader

from dea_ros.bag import (
    BagError,
    BagReader,
    BagWriter,
    QosDuration,
    QosProfile,
    convert_bag,
    default_rosbag2_format,
    resolve_rosbag2_format,
)

_spec = importlib.util.spec_from_file_location("rosbag2_rules", Path(__file__).with_name("rosbag2_rules.py"))
rules = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(rules)

#: a profile with every field away from the defaults (what a discovered publisher may offer)
ODD_QOS = QosProfile("keep_last", 7, "reliable", "transient_local", deadline=QosDuration(0, 250_000_000),
                     lifespan=QosDuration(3, 0), liveliness="manual_by_topic",
                     liveliness_lease_duration=QosDuration(1, 5), avoid_ros_namespace_conventions=True)
DISCOVERED = QosProfile("unknown", 0, "best_effort", "volatile")  # what DDS discovery reports for history


def _write(path, topics_spec, schedule, **options):
    with BagWriter(path, **options) as writer:
        for topic, (type_name, qos, _count, _make) in topics_spec.items():
            writer.add_topic(topic, type_name, qos)
        writer.add_topic("/dea/odd", "std_msgs/msg/Float64", [ODD_QOS, DISCOVERED])
        writer.add_metadata("protocol", {"waveform": "sine"})
        for topic, log_time, message in schedule:
            writer.write(topic, message, log_time, publish_time_ns=log_time - 7)
        writer.write("/dea/odd", {"data": 1.5}, schedule[-1][1])
    return path


def _expected_qos(topics_spec):
    expected = {topic: [spec[1]] for topic, spec in topics_spec.items()}
    expected["/dea/odd"] = [ODD_QOS, DISCOVERED]
    return expected


def _assert_decoded_qos(decoded_topics, expected):
    assert set(decoded_topics) == set(expected)
    for topic, profiles in expected.items():
        got = decoded_topics[topic]
        got = got["qos"] if isinstance(got, dict) else got
        assert len(got) == len(profiles), topic
        assert all(rules.same_qos(g, p) for g, p in zip(got, profiles)), (topic, got, profiles)


def _read_everywhere(bag, count, fields_equal=None, schedule=None):
    """rosbags (metadata.yaml + mcap) and the mcap reader with mcap_ros2 decode every message."""
    with RosbagsReader(bag) as reader:
        assert reader.message_count == count
    with AnyReader([bag]) as reader:
        n = 0
        for connection, _t, raw in reader.messages():
            reader.deserialize(raw, connection.msgtype)
            n += 1
        assert n == count
    (mcap_file,) = sorted(Path(bag).glob("*.mcap"))
    with open(mcap_file, "rb") as handle:
        decoded = list(make_reader(handle, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    assert len(decoded) == count
    if schedule is not None:
        by_topic = {}
        for topic, _t, message in schedule:
            by_topic.setdefault(topic, []).append(message)
        seen = {}
        for _schema, channel, _message, ros_msg in decoded:
            if channel.topic in by_topic:
                index = seen.get(channel.topic, 0)
                fields_equal(by_topic[channel.topic][index], ros_msg, f"{channel.topic}[{index}]")
                seen[channel.topic] = index + 1


@pytest.mark.parametrize("distro", ["humble", "iron", "jazzy", "kilted", "rolling", "", None])
def test_the_default_format_is_the_one_every_distro_reads(monkeypatch, distro):
    if distro is None:
        monkeypatch.delenv("ROS_DISTRO", raising=False)  # PyPI wheels: no ROS sourced
    else:
        monkeypatch.setenv("ROS_DISTRO", distro)
    assert default_rosbag2_format() == "humble"
    assert resolve_rosbag2_format(None) == resolve_rosbag2_format("auto") == "humble"
    assert resolve_rosbag2_format("jazzy") == "jazzy"  # only when asked for
    with pytest.raises(BagError, match="rosbag2_format='iron' is not supported; use 'jazzy'"):
        resolve_rosbag2_format("iron")


@pytest.mark.parametrize("distro", [None, "jazzy"])
def test_a_bag_recorded_without_ros_sourced_passes_humble_and_jazzy_rules(tmp_path, monkeypatch, topics_spec,
                                                                          schedule, fields_equal, distro):
    """Issue 20: the default bag, recorded with no ROS sourced (or on Jazzy), opens on Humble too."""
    if distro is None:
        monkeypatch.delenv("ROS_DISTRO", raising=False)
    else:
        monkeypatch.setenv("ROS_DISTRO", distro)
    bag = _write(tmp_path / "n", topics_spec, schedule, custom_data={"operator": "lab"})  # the default format
    expected = _expected_qos(topics_spec)
    for reader_distro in ("humble", "jazzy"):
        info = rules.check_bag(bag, reader_distro)
        assert info["version"] == 5 and info["message_count"] == len(schedule) + 1
        _assert_decoded_qos(info["topics"], expected)
        _assert_decoded_qos(info["mcap"]["n_0.mcap"]["topics"], expected)
    assert rules.check_mcap(bag / "n_0.mcap", "jazzy")["ros_distro"] == (distro or "humble")
    _read_everywhere(bag, len(schedule) + 1, fields_equal, schedule)
    # nothing lost: converted to the Jazzy format, custom_data is back in metadata.yaml
    assert rules.check_bag(convert_bag(bag, "jazzy"), "jazzy")["custom_data"] == {"operator": "lab"}


def test_humble_bag_passes_humble_and_jazzy_rules(tmp_path, monkeypatch, topics_spec, schedule, fields_equal):
    monkeypatch.setenv("ROS_DISTRO", "humble")
    bag = _write(tmp_path / "h", topics_spec, schedule)  # format from ROS_DISTRO
    expected = _expected_qos(topics_spec)
    for distro in ("humble", "jazzy"):
        info = rules.check_bag(bag, distro)
        assert info["version"] == 5 and info["message_count"] == len(schedule) + 1
        _assert_decoded_qos(info["topics"], expected)  # metadata.yaml
        _assert_decoded_qos(info["mcap"]["h_0.mcap"]["topics"], expected)  # channel metadata
    # Jazzy reads ROS_DISTRO from the MCAP record Humble's storage plugin writes
    assert rules.check_mcap(bag / "h_0.mcap", "jazzy")["ros_distro"] == "humble"
    assert rules.check_mcap(bag / "h_0.mcap", "jazzy")["version"] == 8
    _read_everywhere(bag, len(schedule) + 1, fields_equal, schedule)


@pytest.mark.parametrize("ros_distro, recorded", [("jazzy", "jazzy"), ("kilted", "kilted"), (None, "jazzy")])
def test_jazzy_bag_passes_jazzy_rules_and_names_its_distro(tmp_path, monkeypatch, topics_spec, schedule,
                                                           fields_equal, ros_distro, recorded):
    if ros_distro is None:
        monkeypatch.delenv("ROS_DISTRO", raising=False)
    else:
        monkeypatch.setenv("ROS_DISTRO", ros_distro)
    bag = _write(tmp_path / "j", topics_spec, schedule, custom_data={"operator": "lab"}, rosbag2_format="jazzy")
    info = rules.check_bag(bag, "jazzy")
    assert info["version"] == 9 and info["ros_distro"] == recorded  # never empty
    assert info["custom_data"] == {"operator": "lab"}
    expected = _expected_qos(topics_spec)
    _assert_decoded_qos(info["topics"], expected)
    mcap = info["mcap"]["j_0.mcap"]
    assert mcap["version"] == 9 and mcap["ros_distro"] == recorded
    _assert_decoded_qos(mcap["topics"], expected)
    # Humble's metadata_io.cpp reads offered_qos_profiles as<std::string>(): a list throws
    with pytest.raises(rules.RuleError, match=r"offered_qos_profiles: as<std::string>\(\) needs a scalar"):
        rules.check_bag(bag, "humble")
    # ... and its player reads channel policies as<int>(): Jazzy's names throw
    with pytest.raises(rules.RuleError, match=r"history: as<int>\(\) cannot convert 'keep_last'"):
        rules.check_mcap(bag / "j_0.mcap", "humble")
    _read_everywhere(bag, len(schedule) + 1, fields_equal, schedule)


@pytest.mark.parametrize(
    "edit, distro, message",
    [
        (lambda i: i.pop("ros_distro"), "jazzy", r"ros_distro: missing"),
        (lambda i: i.update(ros_distro=None), "jazzy", r"ros_distro: as<std::string>\(\) needs a scalar, got null"),
        (lambda i: i.pop("custom_data"), "jazzy", r"custom_data: missing"),
        (lambda i: i.update(custom_data=["a"]), "jazzy", r"custom_data: a map"),
        (lambda i: i["files"][0].pop("message_count"), "jazzy", r"files\[0\]\.message_count: missing"),
        (lambda i: i.update(message_count=-1), "jazzy", r"message_count: as<uint64_t>\(\) cannot convert '-1'"),
        (lambda i: i["topics_with_message_count"][0]["topic_metadata"].pop("type_description_hash"), "jazzy",
         r"type_description_hash: missing"),
        (lambda i: i["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"][0].update(
            depth="ten"), "jazzy", r"depth: as<int>\(\) cannot convert 'ten'"),
        (lambda i: i["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"][0].update(
            reliability="mostly"), "jazzy", r"'mostly' is not an rmw policy name"),
        (lambda i: i["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"][0].update(
            avoid_ros_namespace_conventions="maybe"), "jazzy", r"as<bool>\(\) cannot convert 'maybe'"),
        (lambda i: i.update(version=5), "jazzy", r"offered_qos_profiles: as<std::string>\(\) needs a scalar"),
    ],
)
def test_rules_reject_what_rosbag2_rejects(tmp_path, edit, distro, message):
    """The validator is not a rubber stamp: each field the parser needs, removed or mistyped, fails."""
    with BagWriter(tmp_path / "b", rosbag2_format="jazzy") as writer:
        writer.add_topic("/x", "std_msgs/msg/Float64")
        writer.write("/x", {"data": 1.0}, 10)
    document = yaml.safe_load((tmp_path / "b" / "metadata.yaml").read_text())
    rules.check_metadata_yaml(yaml.safe_dump(document), distro)  # unchanged: passes
    edit(document["rosbag2_bagfile_information"])
    with pytest.raises(rules.RuleError, match=message):
        rules.check_metadata_yaml(yaml.safe_dump(document), distro)


def test_humble_rules_need_integer_policies_and_jazzy_accepts_both():
    names = "- history: keep_last\n  depth: 5\n  reliability: reliable\n  durability: volatile\n" \
            "  deadline: {sec: 0, nsec: 0}\n  lifespan: {sec: 0, nsec: 0}\n  liveliness: automatic\n" \
            "  liveliness_lease_duration: {sec: 0, nsec: 0}\n  avoid_ros_namespace_conventions: false"
    integers = names.replace("keep_last", "1").replace("reliable", "1").replace("volatile", "2") \
        .replace("automatic", "1")
    with pytest.raises(rules.RuleError, match="as<int>"):
        rules.decode_qos_text(names, "humble", "qos")
    assert rules.decode_qos_text(names, "jazzy", "qos") == rules.decode_qos_text(integers, "jazzy", "qos") \
        == rules.decode_qos_text(integers, "humble", "qos")
    with pytest.raises(rules.RuleError, match="not an rmw reliability policy on humble"):
        rules.decode_qos_text(integers.replace("reliability: 1", "reliability: 4"), "humble", "qos")
    assert rules.decode_qos_text("", "humble", "qos") == []


def _mcap_contents(mcap_path):
    with open(mcap_path, "rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        schemas = sorted((s.name, s.encoding, s.data) for s in summary.schemas.values())
        channels = sorted((c.topic, c.message_encoding, sorted(c.metadata.items())) for c in summary.channels.values())
        records = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        messages = [(c.topic, m.log_time, m.publish_time, m.sequence, m.data)
                    for _s, c, m in reader.iter_messages(log_time_order=False)]
    return schemas, channels, records, messages


@pytest.mark.parametrize("first, second", [("jazzy", "humble"), ("humble", "jazzy")])
def test_convert_round_trips(tmp_path, monkeypatch, topics_spec, schedule, first, second):
    monkeypatch.setenv("ROS_DISTRO", "kilted")
    original = _write(tmp_path / "run", topics_spec, schedule, rosbag2_format=first,
                      custom_data={"membrane": "VHB"})
    there = convert_bag(original, second)
    assert there == tmp_path / f"run_{second}"
    rules.check_bag(there, second)
    rules.check_bag(there, "jazzy")
    back = convert_bag(there, first, out=tmp_path / "back" / "run")
    assert (back / "metadata.yaml").read_text() == (original / "metadata.yaml").read_text()
    assert _mcap_contents(back / "run_0.mcap") == _mcap_contents(original / "run_0.mcap")
    # the intermediate bag holds the same messages, QoS, schemas and distro in the other format
    o_schemas, o_channels, o_records, o_messages = _mcap_contents(original / "run_0.mcap")
    t_schemas, _t_channels, _t_records, t_messages = _mcap_contents(there / f"run_{second}_0.mcap")
    assert t_schemas == o_schemas and t_messages == o_messages
    with BagReader(there) as reader:
        assert {t: i.qos_profiles for t, i in reader.topics().items()} == _expected_qos(topics_spec)
    jazzy_view = rules.check_bag(there if second == "jazzy" else original, "jazzy")
    assert jazzy_view["ros_distro"] == "kilted" and jazzy_view["custom_data"] == {"membrane": "VHB"}


def test_convert_cli(tmp_path, capsys):
    from dea_ros.cli import main

    with BagWriter(tmp_path / "b", rosbag2_format="jazzy") as writer:
        writer.add_topic("/x", "std_msgs/msg/Float64")
        writer.write("/x", {"data": 1.0}, 10)
    args = ["bag", "convert", str(tmp_path / "b")]
    assert main(args + ["--to", "humble", "--out", str(tmp_path / "h")]) == 0
    assert rules.check_bag(tmp_path / "h", "humble")["version"] == 5
    assert main(args + ["--to", "humble", "--out", str(tmp_path / "h")]) == 2
    assert "already exists and is not empty" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(args + ["--to", "iron"])
    assert exit_info.value.code == 2 and "invalid choice: 'iron'" in capsys.readouterr().err


def test_convert_refuses_a_truncated_bag(tmp_path):
    with BagWriter(tmp_path / "t", rosbag2_format="jazzy", chunk_size_bytes=256) as writer:
        writer.add_topic("/x", "std_msgs/msg/Float64")
        for i in range(50):
            writer.write("/x", {"data": float(i)}, 10 + i)
    mcap = tmp_path / "t" / "t_0.mcap"
    (tmp_path / "t" / "metadata.yaml").unlink()
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    with pytest.raises(BagError, match="truncated .* run `dea-ros bag recover"):
        convert_bag(tmp_path / "t", "humble")
