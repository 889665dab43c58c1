"""Clear errors: unwritable outputs, foreign/malformed bags, wrong topics/types, writer misuse."""

import os
from pathlib import Path

import pytest
import yaml
from mcap.writer import Writer as PlainMcapWriter

from dea_ros.bag import BagError, BagReader, BagWarning, BagWriter, check_writable, MessageDefinitionStore


def _bag(path: Path) -> Path:
    with BagWriter(path) as writer:
        writer.add_topic("/dea/voltage", "std_msgs/msg/Float64")
        writer.add_topic("/dea/range", "sensor_msgs/msg/Range")
        for i in range(10):
            writer.write("/dea/voltage", {"data": float(i)}, 100 + i)
            writer.write("/dea/range", {"range": 0.5}, 100 + i)
    return path


# -- check_writable -------------------------------------------------------------------------------
def test_check_writable_accepts_new_and_empty_directories(tmp_path):
    assert check_writable(tmp_path / "new" / "nested", min_free_bytes=1) > 0
    (tmp_path / "empty").mkdir()
    assert check_writable(tmp_path / "empty", min_free_bytes=1) > 0


def test_parent_is_a_file(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(BagError, match=r"afile exists but is not a directory"):
        check_writable(tmp_path / "afile" / "bag")
    with pytest.raises(BagError, match="not a directory"):
        BagWriter(tmp_path / "afile" / "bag")


def test_existing_bag_directory_is_never_overwritten(tmp_path):
    bag = _bag(tmp_path / "bag")
    with pytest.raises(BagError, match=r"already exists and is not empty.*choose a new directory"):
        BagWriter(bag)
    (tmp_path / "file").write_text("x")
    with pytest.raises(BagError, match="exists and is not a directory"):
        check_writable(tmp_path / "file")


def test_too_little_free_space(tmp_path):
    with pytest.raises(BagError, match=r"not enough free disk space for bag .*MiB free.*required"):
        BagWriter(tmp_path / "bag", min_free_bytes=2**62)
    assert not (tmp_path / "bag").exists()  # nothing was created


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_unwritable_location_even_as_root():
    with pytest.raises(BagError, match=r"/proc is not writable .*choose a writable location"):
        check_writable("/proc/dea_bag_test")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores permission bits")
def test_read_only_directory(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(BagError, match="is not writable"):
            check_writable(locked / "bag")
    finally:
        locked.chmod(0o700)


# -- foreign / malformed bags ---------------------------------------------------------------------
def test_missing_path(tmp_path):
    with pytest.raises(BagError, match=r"does_not_exist does not exist"):
        BagReader(tmp_path / "does_not_exist")


def test_directory_that_is_not_a_bag(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match=r"is not a rosbag2 bag: it has no metadata.yaml and no .mcap file"):
        BagReader(tmp_path)


def test_file_that_is_not_mcap(tmp_path):
    (tmp_path / "x.mcap").write_bytes(b"SQLite format 3\x00" + bytes(100))
    with pytest.raises(BagError, match=r"x.mcap is not an MCAP file"):
        BagReader(tmp_path / "x.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(BagError, match="it is empty"):
        BagReader(tmp_path / "empty.mcap")


def test_mcap_without_ros2_profile_is_rejected(tmp_path):
    path = tmp_path / "foxglove.mcap"
    with open(path, "wb") as handle:
        writer = PlainMcapWriter(handle)
        writer.start(profile="", library="test")
        schema = writer.register_schema("Pose", "jsonschema", b"{}")
        channel = writer.register_channel("/pose", "json", schema)
        writer.add_message(channel, 1, b"{}", 1)
        writer.finish()
    with pytest.raises(BagError, match=r"profile '', not a ROS 2 bag"):
        BagReader(path)


def test_non_cdr_channel_cannot_be_decoded_but_is_listed(tmp_path):
    path = tmp_path / "idl.mcap"
    with open(path, "wb") as handle:
        writer = PlainMcapWriter(handle)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema("std_msgs/msg/Float64", "ros2idl", b"module std_msgs {};")
        channel = writer.register_channel("/idl", "cdr", schema, {"offered_qos_profiles": ""})
        writer.add_message(channel, 5, b"\x00\x01\x00\x00" + bytes(8), 5)
        writer.finish()
    with BagReader(path) as reader:
        assert reader.topics()["/idl"].type == "std_msgs/msg/Float64"
        assert [m.data for m in reader.raw_messages()] == [b"\x00\x01\x00\x00" + bytes(8)]
        with pytest.raises(BagError, match=r"cannot decode topic /idl .*schema encoding 'ros2idl'"):
            list(reader.messages())


def test_sqlite3_bag_is_rejected_with_conversion_hint(tmp_path):
    bag = _bag(tmp_path / "bag")
    document = yaml.safe_load((bag / "metadata.yaml").read_text())
    document["rosbag2_bagfile_information"]["storage_identifier"] = "sqlite3"
    (bag / "metadata.yaml").write_text(yaml.safe_dump(document))
    with pytest.raises(BagError, match=r"storage_identifier is 'sqlite3'.*ros2 bag convert"):
        BagReader(bag)


def test_malformed_metadata_yaml(tmp_path):
    bag = _bag(tmp_path / "bag")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    with pytest.raises(BagError, match=r"metadata.yaml is not valid YAML.*recover_bag"):
        BagReader(bag)
    (bag / "metadata.yaml").write_text("something_else: 1\n")
    with pytest.raises(BagError, match="top-level key 'rosbag2_bagfile_information' missing"):
        BagReader(bag)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda info: info.pop("relative_file_paths"), "field 'relative_file_paths' is missing"),
        (lambda info: info.__setitem__("version", "nine"), "field 'version' must be int"),
        (lambda info: info["duration"].pop("nanoseconds"), "field 'duration.nanoseconds' is missing"),
        (
            lambda info: info["topics_with_message_count"][0]["topic_metadata"].pop("type"),
            r"field 'topics_with_message_count\[0\].topic_metadata.type' is missing",
        ),
        (
            lambda info: info["topics_with_message_count"][0]["topic_metadata"].__setitem__(
                "offered_qos_profiles", [{"reliability": "sometimes"}]
            ),
            "unknown policy 'sometimes'",
        ),
    ],
)
def test_metadata_yaml_with_bad_fields_names_the_field(tmp_path, mutate, message):
    bag = _bag(tmp_path / "bag")
    document = yaml.safe_load((bag / "metadata.yaml").read_text())
    mutate(document["rosbag2_bagfile_information"])
    (bag / "metadata.yaml").write_text(yaml.safe_dump(document))
    with pytest.raises(BagError, match=message):
        BagReader(bag)


def test_metadata_listing_a_missing_file(tmp_path):
    bag = _bag(tmp_path / "bag")
    (bag / "bag_0.mcap").rename(bag / "renamed.mcap")
    with pytest.raises(BagError, match=r"lists storage file 'bag_0.mcap', but .*bag_0.mcap does not exist"):
        BagReader(bag)


def test_missing_metadata_falls_back_to_mcap_with_warning(tmp_path):
    bag = _bag(tmp_path / "bag")
    (bag / "metadata.yaml").unlink()
    with pytest.warns(BagWarning, match=r"metadata.yaml is missing; reading bag_0.mcap directly"):
        reader = BagReader(bag)
    with reader:
        assert not reader.truncated
        assert reader.topics()["/dea/voltage"].message_count == 10
        assert [m.message.data for m in reader.messages("/dea/voltage")] == [float(i) for i in range(10)]


def test_stale_metadata_yaml_is_reported(tmp_path):
    bag = _bag(tmp_path / "bag")
    document = yaml.safe_load((bag / "metadata.yaml").read_text())
    document["rosbag2_bagfile_information"]["topics_with_message_count"][0]["message_count"] = 3
    (bag / "metadata.yaml").write_text(yaml.safe_dump(document))
    with pytest.warns(BagWarning, match="says 3 messages on /dea/voltage, the MCAP file has 10"):
        BagReader(bag).close()


def test_requested_topics_and_types_are_checked(tmp_path):
    bag = _bag(tmp_path / "bag")
    with BagReader(bag) as reader:
        with pytest.raises(BagError,
                           match=r"topic\(s\) \['/nope'\] not in bag .*available: \['/dea/range', '/dea/voltage'\]"):
            list(reader.messages(["/dea/voltage", "/nope"]))
        with pytest.raises(BagError) as error:
            reader.require_topics(
                {
                    "/dea/voltage": "std_msgs/msg/Float64",
                    "/dea/range": "std_msgs/msg/Float64",
                    "/dea/current": "std_msgs/msg/Float64",
                }
            )
        text = str(error.value)
        assert "missing topics: /dea/current (std_msgs/msg/Float64)" in text
        assert "wrong types: /dea/range is sensor_msgs/msg/Range, expected std_msgs/msg/Float64" in text
        assert "/dea/voltage" not in text.split("Topics in the bag")[0]


# -- writer misuse --------------------------------------------------------------------------------
def test_writer_rejects_misuse_with_clear_messages(tmp_path):
    writer = BagWriter(tmp_path / "bag")
    with pytest.raises(BagError, match="must be an absolute ROS name"):
        writer.add_topic("dea/voltage", "std_msgs/msg/Float64")
    with pytest.raises(BagError, match="is not a ROS 2 type name"):
        writer.add_topic("/x", "Float64")
    with pytest.raises(BagError, match=r"no .msg definition for my_msgs/msg/Custom.*extra_definitions"):
        writer.add_topic("/x", "my_msgs/msg/Custom")
    writer.add_topic("/x", "std_msgs/msg/Float64")
    writer.add_topic("/x", "std_msgs/Float64")  # same type and QoS: no-op
    with pytest.raises(BagError, match="already registered .* as std_msgs/msg/Float64"):
        writer.add_topic("/x", "std_msgs/msg/String")
    with pytest.raises(BagError, match=r"topic '/y' is not registered .*add_topic\('/y'"):
        writer.write("/y", {"data": 1.0}, 1)
    with pytest.raises(BagError, match="must be bytes .*got str"):
        writer.write_serialized("/x", "data", 1)
    with pytest.raises(BagError, match="do not start with a CDR encapsulation header .*: 7b 7d"):
        writer.write_serialized("/x", b"{}", 1)
    with pytest.raises(BagError, match=r"log_time_ns=-1 must be an integer in \[0, 2\*\*64\)"):
        writer.write_serialized("/x", b"\x00\x01\x00\x00" + bytes(8), -1)
    with pytest.raises(BagError, match=r"log_time_ns=1.5 must be an integer"):
        writer.write_serialized("/x", b"\x00\x01\x00\x00" + bytes(8), 1.5)
    with pytest.raises(BagError, match=r"cannot serialize message for topic /x \(std_msgs/msg/Float64\)"):
        writer.write("/x", {"data": "not a number"}, 1)
    with pytest.raises(BagError, match="'rosbag2' is reserved"):
        writer.add_metadata("rosbag2", {"a": "b"})
    with pytest.raises(BagError, match=r"keys and values must be str .*\['gain'\]"):
        writer.add_metadata("protocol", {"gain": 2.0})
    writer.close()
    with pytest.raises(BagError, match="is closed"):
        writer.write("/x", {"data": 1.0}, 1)
    assert writer.close() == tmp_path / "bag"  # idempotent


def test_custom_type_through_extra_definitions(tmp_path):
    store = MessageDefinitionStore(
        extra_definitions={"dea_msgs/msg/Sample": "std_msgs/Header header\nfloat64 voltage\nfloat64[] strain\n"}
    )
    with BagWriter(tmp_path / "bag", definitions=store) as writer:
        writer.add_topic("/sample", "dea_msgs/msg/Sample")
        writer.write("/sample", {"header": {"frame_id": "f"}, "voltage": 2.5, "strain": [0.1, 0.2]}, 7)
    with BagReader(tmp_path / "bag") as reader:
        (message,) = list(reader.messages())
        assert message.message.voltage == 2.5 and list(message.message.strain) == [0.1, 0.2]
        assert message.message.header.frame_id == "f"


def test_exception_inside_with_block_still_produces_a_valid_bag(tmp_path):
    with pytest.raises(RuntimeError, match="experiment aborted"):
        with BagWriter(tmp_path / "bag") as writer:
            writer.add_topic("/x", "std_msgs/msg/Float64")
            writer.write("/x", {"data": 1.0}, 1)
            raise RuntimeError("experiment aborted")
    with BagReader(tmp_path / "bag") as reader:
        assert reader.message_count == 1 and reader.problems == []
