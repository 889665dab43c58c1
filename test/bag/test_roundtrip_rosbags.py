"""Write a bag with every rig type and read it back with the independent reader ``rosbags``."""

import subprocess
import sys

import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.rosbag2.metadata import parse_qos as rosbags_parse_qos

from dea_ros.bag import BagReader, BagWriter, MessageDefinitionStore, QosProfile, QosDuration


def _from_rosbags_qos(qos) -> QosProfile:
    """rosbags ``Qos`` -> our ``QosProfile`` (independent parse of what we wrote)."""
    return QosProfile(
        history=qos.history.name.lower(),
        depth=qos.depth,
        reliability=qos.reliability.name.lower(),
        durability=qos.durability.name.lower(),
        deadline=QosDuration(qos.deadline.sec, qos.deadline.nsec),
        lifespan=QosDuration(qos.lifespan.sec, qos.lifespan.nsec),
        liveliness=qos.liveliness.name.lower(),
        liveliness_lease_duration=QosDuration(
            qos.liveliness_lease_duration.sec, qos.liveliness_lease_duration.nsec
        ),
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions,
    )


def _write_bag(path, topics_spec, schedule, **options):
    with BagWriter(path, **options) as writer:
        for topic, (type_name, qos, _count, _make) in topics_spec.items():
            writer.add_topic(topic, type_name, qos)
        writer.add_metadata("protocol", {"waveform": "sine", "amplitude_V": "3000", "frequency_Hz": "2.5"})
        for topic, log_time, message in schedule:
            writer.write(topic, message, log_time, publish_time_ns=log_time - 1000)
    return path


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_rosbags_reads_every_message_field_by_field(tmp_path, topics_spec, schedule, fields_equal, compression,
                                                    has_type_hash):
    bag = _write_bag(
        tmp_path / "run",
        topics_spec,
        schedule,
        compression=compression,
        chunk_size_bytes=4096,  # many chunks: exercises chunk and message indexes
        rosbag2_format="jazzy",
        ros_distro="kilted",
        custom_data={"operator": "test", "membrane": "VHB4905"},
    )
    assert len(schedule) >= 400
    expected_by_topic = {}
    for topic, log_time, message in schedule:
        expected_by_topic.setdefault(topic, []).append((log_time, message))

    with AnyReader([bag]) as reader:  # also verifies RIHS01 hashes against the stored schemas
        connections = {c.topic: c for c in reader.connections}
        assert set(connections) == set(topics_spec)
        seen = {topic: 0 for topic in topics_spec}
        previous_time = -1
        for connection, log_time, raw in reader.messages():
            assert log_time >= previous_time
            previous_time = log_time
            expected_time, expected = expected_by_topic[connection.topic][seen[connection.topic]]
            assert log_time == expected_time
            decoded = reader.deserialize(raw, connection.msgtype)
            fields_equal(expected, decoded, f"{connection.topic}[{seen[connection.topic]}]")
            seen[connection.topic] += 1
        assert seen == {topic: spec[2] for topic, spec in topics_spec.items()}

    with RosbagsReader(bag) as reader:  # metadata.yaml as rosbags' rosbag2 reader parses it
        assert reader.message_count == len(schedule)
        assert reader.start_time == schedule[0][1]
        assert reader.end_time == schedule[-1][1] + 1
        for connection in reader.connections:
            type_name, qos, count, _make = topics_spec[connection.topic]
            assert connection.msgtype == type_name
            assert connection.msgcount == count
            assert connection.ext.serialization_format == "cdr"
            assert [_from_rosbags_qos(q) for q in connection.ext.offered_qos_profiles] == [qos]
            assert connection.digest == MessageDefinitionStore().type_hash(type_name)
            # RIHS01 hashes where the distro generates them (Iron+), none on Humble / without ROS
            assert connection.digest.startswith("RIHS01_") == has_type_hash(type_name)


def test_metadata_yaml_and_mcap_layout_match_rosbag2(tmp_path, topics_spec, schedule, has_type_hash):
    bag = _write_bag(tmp_path / "exp_042", topics_spec, schedule, rosbag2_format="jazzy", ros_distro="kilted",
                     custom_data={"k": "v"})
    document = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = document["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["exp_042_0.mcap"]
    assert info["message_count"] == len(schedule)
    assert info["starting_time"]["nanoseconds_since_epoch"] == schedule[0][1]
    assert info["duration"]["nanoseconds"] == schedule[-1][1] - schedule[0][1]
    assert info["files"] == [
        {
            "path": "exp_042_0.mcap",
            "starting_time": {"nanoseconds_since_epoch": schedule[0][1]},
            "duration": {"nanoseconds": schedule[-1][1] - schedule[0][1]},
            "message_count": len(schedule),
        }
    ]
    assert info["compression_format"] == "" and info["compression_mode"] == ""
    assert info["custom_data"] == {"k": "v"}
    assert info["ros_distro"] == "kilted"
    entries = {e["topic_metadata"]["name"]: e for e in info["topics_with_message_count"]}
    assert set(entries) == set(topics_spec)
    for name, entry in entries.items():
        type_name, qos, count, _ = topics_spec[name]
        assert entry["message_count"] == count
        metadata = entry["topic_metadata"]
        assert metadata["type"] == type_name
        assert metadata["serialization_format"] == "cdr"
        assert metadata["type_description_hash"] == MessageDefinitionStore().type_hash(type_name)
        assert metadata["type_description_hash"].startswith("RIHS01_") == has_type_hash(type_name)
        (profile,) = metadata["offered_qos_profiles"]  # v9: a YAML list with string enums
        assert list(profile) == [
            "history", "depth", "reliability", "durability", "deadline", "lifespan",
            "liveliness", "liveliness_lease_duration", "avoid_ros_namespace_conventions",
        ]
        assert profile["history"] == "keep_last" and profile["depth"] == qos.depth
        assert profile["reliability"] == qos.reliability
        assert profile["deadline"] == {"sec": 9223372036, "nsec": 854775807}

    store = MessageDefinitionStore()
    with open(bag / "exp_042_0.mcap", "rb") as handle:
        reader = make_reader(handle)
        header = reader.get_header()
        assert header.profile == "ros2" and header.library.startswith("dea_ros.bag")
        summary = reader.get_summary()
        assert summary.statistics.message_count == len(schedule)
        assert len(summary.chunk_indexes) >= 1
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {spec[0] for spec in topics_spec.values()}
        for schema in schemas.values():
            assert schema.encoding == "ros2msg"
            assert schema.data.decode() == store.full_definition(schema.name).text
        range_text = schemas["sensor_msgs/msg/Range"].data.decode()
        assert "\n" + "=" * 80 + "\nMSG: std_msgs/Header\n" in range_text
        assert "\n" + "=" * 80 + "\nMSG: builtin_interfaces/Time\n" in range_text
        for channel in summary.channels.values():
            type_name, qos, _, _ = topics_spec[channel.topic]
            assert channel.message_encoding == "cdr"
            if has_type_hash(type_name):
                assert set(channel.metadata) == {"offered_qos_profiles", "topic_type_hash"}
                assert channel.metadata["topic_type_hash"] == store.type_hash(type_name)
            else:  # Humble / no ROS: no hash to store
                assert set(channel.metadata) == {"offered_qos_profiles"}
            text = channel.metadata["offered_qos_profiles"]
            assert text.startswith("- history: keep_last\n  depth: ") and not text.endswith("\n")
            assert [_from_rosbags_qos(q) for q in rosbags_parse_qos(text)] == [qos]
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert records["protocol"] == {"waveform": "sine", "amplitude_V": "3000", "frequency_Hz": "2.5"}
    serialized = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert serialized == info  # the rosbag2 record holds the final bag information


def test_bag_reader_matches_what_was_written(tmp_path, topics_spec, schedule, fields_equal):
    bag = _write_bag(tmp_path / "run", topics_spec, schedule, rosbag2_format="jazzy")
    with BagReader(bag) as reader:
        assert not reader.truncated and reader.problems == []
        topics = reader.topics()
        assert {name: (info.type, info.message_count, info.qos_profiles) for name, info in topics.items()} == {
            name: (spec[0], spec[2], [spec[1]]) for name, spec in topics_spec.items()
        }
        assert reader.metadata()["protocol"]["amplitude_V"] == "3000"
        assert reader.message_count == len(schedule)
        assert (reader.start_time_ns, reader.end_time_ns) == (schedule[0][1], schedule[-1][1])
        decoded = list(reader.messages())
        assert len(decoded) == len(schedule)
        for (topic, log_time, expected), message in zip(schedule, decoded):
            assert (message.topic, message.log_time_ns) == (topic, log_time)
            fields_equal(expected, message.message, topic)
        only = list(reader.messages(["/dea/range", "/clock"]))
        assert [m.topic for m in only] == [t for t, _, _ in schedule if t in ("/dea/range", "/clock")]
        raw = list(reader.raw_messages("/dea/voltage_cmd"))
        assert len(raw) == topics_spec["/dea/voltage_cmd"][2]
        assert all(r.publish_time_ns == r.log_time_ns - 1000 for r in raw)
        reader.require_topics({"/dea/range": "sensor_msgs/Range", "/clock": "rosgraph_msgs/msg/Clock"})


def test_single_mcap_file_is_readable_by_bag_reader(tmp_path, topics_spec, schedule):
    bag = _write_bag(tmp_path / "run", topics_spec, schedule)
    with BagReader(bag / "run_0.mcap") as reader:
        assert reader.message_count == len(schedule)
        assert reader.files == [bag / "run_0.mcap"]


def test_humble_format_is_version_5_with_integer_qos(tmp_path, monkeypatch, topics_spec, schedule, fields_equal):
    monkeypatch.delenv("ROS_DISTRO", raising=False)  # recorded distro: the format's name
    bag = _write_bag(tmp_path / "humble", topics_spec, schedule, rosbag2_format="humble")
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 5
    assert "custom_data" not in info and "ros_distro" not in info
    for entry in info["topics_with_message_count"]:
        metadata = entry["topic_metadata"]
        assert "type_description_hash" not in metadata
        assert isinstance(metadata["offered_qos_profiles"], str)  # Humble stores a YAML string
        (profile,) = yaml.safe_load(metadata["offered_qos_profiles"])
        qos = topics_spec[metadata["name"]][1]
        assert profile["history"] == 1  # RMW_QOS_POLICY_HISTORY_KEEP_LAST
        assert profile["reliability"] == (2 if qos.reliability == "best_effort" else 1)
        assert profile["durability"] == 2 and profile["liveliness"] == 1
    with open(bag / "humble_0.mcap", "rb") as handle:
        reader = make_reader(handle)
        store = MessageDefinitionStore()
        for channel in reader.get_summary().channels.values():  # hash kept for Jazzy (Humble ignores it)
            schema_name = topics_spec[channel.topic][0]
            assert channel.metadata.get("topic_type_hash", "") == store.type_hash(schema_name)
        # Humble's storage plugin records only ROS_DISTRO (MCAPStorage::ensure_rosdistro_metadata_added)
        records = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        assert records[0] == ("rosbag2", {"ROS_DISTRO": "humble"})
        assert [name for name, _ in records] == ["rosbag2", "protocol"]
    with RosbagsReader(bag) as reader:
        for connection in reader.connections:
            assert [_from_rosbags_qos(q) for q in connection.ext.offered_qos_profiles] == [
                topics_spec[connection.topic][1]
            ]
    with BagReader(bag) as reader:
        assert reader.problems == []
        assert {t: i.qos_profiles for t, i in reader.topics().items()} == {
            t: [spec[1]] for t, spec in topics_spec.items()
        }
    with AnyReader([bag]) as reader:
        count = 0
        battery = [c for c in reader.connections if c.topic == "/dea/battery"]
        for connection, _t, raw in reader.messages(connections=battery):
            fields_equal(topics_spec["/dea/battery"][3](count), reader.deserialize(raw, connection.msgtype))
            count += 1
        assert count == topics_spec["/dea/battery"][2]


def test_vendored_definitions_give_readable_schemas_without_hashes(tmp_path, topics_spec, schedule, fields_equal):
    vendored = MessageDefinitionStore(search_prefixes=[])
    bag = _write_bag(tmp_path / "vendored", topics_spec, schedule[:100], definitions=vendored,
                     rosbag2_format="jazzy")
    with open(bag / "vendored_0.mcap", "rb") as handle:
        summary = make_reader(handle).get_summary()
        for schema in summary.schemas.values():
            assert schema.data.decode() == vendored.full_definition(schema.name).text
        assert all("topic_type_hash" not in c.metadata for c in summary.channels.values())
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert all(e["topic_metadata"]["type_description_hash"] == "" for e in info["topics_with_message_count"])
    with AnyReader([bag]) as reader:
        for index, (connection, _t, raw) in enumerate(reader.messages()):
            fields_equal(schedule[index][2], reader.deserialize(raw, connection.msgtype))


def test_out_of_order_log_times_are_read_back_sorted(tmp_path):
    times = [50, 10, 40, 20, 30, 10]
    with BagWriter(tmp_path / "ooo", chunk_size_bytes=64) as writer:
        writer.add_topic("/x", "std_msgs/msg/Float64")
        for index, t in enumerate(times):
            writer.write("/x", {"data": float(index)}, t)
    with BagReader(tmp_path / "ooo") as reader:
        got = [(m.log_time_ns, m.message.data) for m in reader.messages()]
    assert got == sorted(((t, float(i)) for i, t in enumerate(times)), key=lambda item: item[0])
    with AnyReader([tmp_path / "ooo"]) as reader:
        assert [t for _c, t, _r in reader.messages()] == sorted(times)


def test_empty_bag_is_valid(tmp_path):
    with BagWriter(tmp_path / "empty") as writer:
        writer.add_topic("/x", "std_msgs/msg/String")
    info = yaml.safe_load((tmp_path / "empty" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["message_count"] == 0
    assert info["starting_time"]["nanoseconds_since_epoch"] == 2**63 - 1  # as rosbag2
    with RosbagsReader(tmp_path / "empty") as reader:
        assert reader.message_count == 0 and [c.topic for c in reader.connections] == ["/x"]
    with BagReader(tmp_path / "empty") as reader:
        assert reader.topics()["/x"].message_count == 0 and list(reader.messages()) == []


def test_concurrent_writers_lose_nothing(tmp_path):
    import threading

    with BagWriter(tmp_path / "threads", flush_period_s=0.05, chunk_size_bytes=2048) as writer:
        for k in range(4):
            writer.add_topic(f"/t{k}", "std_msgs/msg/Float64")

        def produce(k):
            for i in range(300):
                writer.write_serialized(f"/t{k}", b"\x00\x01\x00\x00" + float(i).hex().encode()[:8], 1000 * i + k)

        threads = [threading.Thread(target=produce, args=(k,)) for k in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert writer.topic_message_counts() == {f"/t{k}": 300 for k in range(4)}
    with BagReader(tmp_path / "threads") as reader:
        assert {t: i.message_count for t, i in reader.topics().items()} == {f"/t{k}": 300 for k in range(4)}
        assert len(list(reader.raw_messages())) == 1200


def test_package_import_does_not_import_rclpy():
    code = "import sys, dea_ros.bag; assert 'rclpy' not in sys.modules, 'rclpy imported'; print('ok')"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "ok"


@pytest.mark.parametrize("version", [8, 9])
def test_bag_written_by_rosbags_is_readable(tmp_path, version):
    """Interoperability the other way round: an MCAP bag from the independent rosbags writer."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    Float64 = typestore.types["std_msgs/msg/Float64"]
    infinite = QosTime(9223372036, 854775807)
    qos = Qos(
        QosHistory.KEEP_LAST, 7, QosReliability.BEST_EFFORT, QosDurability.TRANSIENT_LOCAL,
        infinite, infinite, QosLiveliness.AUTOMATIC, infinite, False,
    )
    bag = tmp_path / "from_rosbags"
    with Writer(bag, version=version, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/v", "std_msgs/msg/Float64",
                                           typestore=typestore, offered_qos_profiles=[qos])
        for i in range(20):
            writer.write(connection, 100 + i, typestore.serialize_cdr(Float64(data=i * 1.5), "std_msgs/msg/Float64"))
    with BagReader(bag) as reader:
        info = reader.topics()["/v"]
        assert (info.type, info.message_count) == ("std_msgs/msg/Float64", 20)
        assert info.qos_profiles == [QosProfile("keep_last", 7, "best_effort", "transient_local")]
        assert [(m.log_time_ns, m.message.data) for m in reader.messages()] == [(100 + i, i * 1.5) for i in range(20)]
