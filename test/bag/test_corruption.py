"""Corrupt bags: every flipped byte is reported (exit 2 naming the file and record), never read as data.

A bag is damaged at random positions (several seeds), truncated, or has its metadata.yaml
replaced by garbage; ``dea-ros bag info``, ``bag recover`` and ``identify`` must say so clearly
(exit code 2, the file named, no traceback), ``bag recover`` must not change a file whose data
are damaged unless asked to ``--salvage``, and what it salvages must read back everywhere.
"""

import random
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from dea_ros.bag import BagError, BagReader, BagWriter
from dea_ros.bag.mcap_scan import scan_mcap
from dea_ros.cli import main


def _bag(path: Path, compression: str = "zstd") -> Path:
    """A bag like identifier_node's: several chunks, two topics, an experiment metadata record."""
    with BagWriter(path, chunk_size_bytes=2048, flush_period_s=None, compression=compression) as writer:
        writer.add_topic("/dea/voltage_cmd", "std_msgs/msg/Float64")
        writer.add_topic("/dea/displacement", "sensor_msgs/msg/Range")
        writer.add_metadata("dea_ros.experiment", {"protocol": "quick", "aborted": "false"})
        for i in range(300):
            writer.write("/dea/voltage_cmd", {"data": 10.0 * i}, 1_000_000_000 + 2_000_000 * i)
            writer.write("/dea/displacement", {"header": {"frame_id": "laser"}, "range": 7e-4 + 1e-7 * i},
                         1_000_000_001 + 2_000_000 * i)
    return path


def _mcap(bag: Path) -> Path:
    return bag / f"{bag.name}_0.mcap"


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    bag = _bag(tmp_path_factory.mktemp("pristine") / "bag")
    with BagReader(bag) as reader:
        assert reader.verify() == []
        messages = [(m.topic, m.log_time_ns, m.data) for m in reader.raw_messages()]
    return bag, _mcap(bag).read_bytes(), messages


def _damaged_copy(tmp_path: Path, pristine_bag: Path, data: bytes, positions) -> Path:
    bag = tmp_path / "bag"
    shutil.copytree(pristine_bag, bag)
    damaged = bytearray(data)
    for position, bit in positions:
        damaged[position] ^= 1 << bit
    _mcap(bag).write_bytes(bytes(damaged))
    return bag


@pytest.mark.parametrize("seed", range(12))
def test_flipped_bits_are_reported_by_info_recover_and_identify(tmp_path, capsys, pristine, seed):
    pristine_bag, data, _messages = pristine
    rng = random.Random(seed)
    flips = [(rng.randrange(len(data)), rng.randrange(8)) for _ in range(1 + seed % 3)]
    bag = _damaged_copy(tmp_path, pristine_bag, data, flips)
    mcap = _mcap(bag)
    damaged_bytes = mcap.read_bytes()

    code, _out, err = _cli(capsys, "bag", "info", bag)
    assert code == 2, f"flips {flips} not detected"
    assert str(mcap) in err and "Traceback" not in err
    assert "offset" in err or "not an MCAP file" in err  # the failing record is named

    code, out, err = _cli(capsys, "identify", bag, "--out", tmp_path / "fit", "--quiet", "--no-plots")
    assert code == 2 and str(mcap) in err and "Traceback" not in err
    assert not (tmp_path / "fit" / "params.yaml").exists()

    code, _out, err = _cli(capsys, "bag", "recover", bag)
    if code == 0:
        # only an index or the summary was hit: rebuilt from the intact data, nothing lost
        assert not scan_mcap(mcap.with_name(mcap.name + ".truncated")).data_lost
    else:
        assert code == 2 and str(mcap) in err and "--salvage" in err
        assert mcap.read_bytes() == damaged_bytes  # nothing was changed
        code, out, err = _cli(capsys, "bag", "recover", "--salvage", bag)
        if code == 2:  # the MCAP header itself was hit: nothing to salvage
            assert "not an MCAP file" in err or "Header" in err
            return
        assert code == 0 and "damage" in out
    code, _out, err = _cli(capsys, "bag", "info", bag)
    assert code == 0, err
    with AnyReader([bag]) as reader:  # what recover wrote reads back with another reader
        assert reader.message_count == sum(1 for _ in reader.messages())


def test_single_bit_flips_anywhere_never_read_as_data(tmp_path, pristine):
    """300 random positions over the whole file (header, records, chunks, indexes, summary, footer)."""
    _bag_dir, data, _messages = pristine
    target = tmp_path / "x.mcap"
    undetected = []
    for position in random.Random(1).sample(range(len(data)), 300):
        damaged = bytearray(data)
        damaged[position] ^= 0x10
        target.write_bytes(bytes(damaged))
        try:
            scan = scan_mcap(target, verify=True)
        except BagError:
            continue  # not MCAP at all: reported as such
        if not scan.damage and scan.complete:
            undetected.append(position)
    assert undetected == []


def test_reading_a_corrupt_complete_bag_raises_bag_error_naming_the_record(tmp_path, pristine):
    pristine_bag, data, _messages = pristine
    scan = scan_mcap(_mcap(pristine_bag))
    middle_chunk = scan.chunks[len(scan.chunks) // 2]
    bag = _damaged_copy(tmp_path, pristine_bag, data, [(middle_chunk.offset + 60, 3)])
    with BagReader(bag) as reader:  # the footer and summary are intact: opened through the index
        with pytest.raises(BagError, match=rf"{_mcap(bag)} is corrupt.*offset {middle_chunk.offset}"):
            list(reader.messages())
        assert any(f"offset {middle_chunk.offset}" in p for p in reader.verify())


@pytest.mark.parametrize("fraction", [0.2, 0.5, 0.9])
def test_truncated_bags_are_not_corrupt_and_recover(tmp_path, capsys, pristine, fraction):
    pristine_bag, data, messages = pristine
    bag = tmp_path / "bag"
    bag.mkdir()
    _mcap(bag).write_bytes(data[: int(len(data) * fraction)])
    code, out, err = _cli(capsys, "bag", "info", bag)
    assert code == 0 and "Traceback" not in err
    assert "TRUNCATED" in out or "inside the summary section" in err  # (only the summary was cut)
    assert "recover" in out + err
    code, out, _err = _cli(capsys, "bag", "recover", bag)
    assert code == 0 and "rewritten" in out
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with BagReader(bag) as reader:
            assert reader.verify() == []
            got = [(m.topic, m.log_time_ns, m.data) for m in reader.raw_messages()]
    assert 0 < len(got) <= len(messages) and got == messages[: len(got)]


def test_damaged_summary_is_rebuilt_without_loss(tmp_path, capsys, pristine):
    pristine_bag, data, messages = pristine
    scan = scan_mcap(_mcap(pristine_bag))
    summary_byte = scan.valid_end + 40  # inside the summary section (schemas)
    bag = _damaged_copy(tmp_path, pristine_bag, data, [(summary_byte, 0)])
    code, _out, err = _cli(capsys, "bag", "info", bag)
    assert code == 2 and "summary" in err
    code, out, _err = _cli(capsys, "bag", "recover", bag)  # no --salvage needed: the data are intact
    assert code == 0
    with BagReader(bag) as reader:
        assert reader.verify() == []
        assert [(m.topic, m.log_time_ns, m.data) for m in reader.raw_messages()] == messages


@pytest.mark.parametrize("content", [
    b"\x00\xff\xfe binary \x80\x81" * 50,
    ("rosbag2_bagfile_information: " + "[" * 600 + "]" * 600 + "\n").encode(),
    b"rosbag2_bagfile_information:\n  version: nine\n",
    b"{{{{ not yaml",
])
def test_garbage_metadata_yaml_is_reported_naming_it(tmp_path, capsys, pristine, content):
    pristine_bag, _data, messages = pristine
    bag = tmp_path / "bag"
    shutil.copytree(pristine_bag, bag)
    (bag / "metadata.yaml").write_bytes(content)
    code, _out, err = _cli(capsys, "bag", "info", bag)
    assert code == 2 and str(bag / "metadata.yaml") in err and "Traceback" not in err
    code, _out, err = _cli(capsys, "bag", "recover", bag)  # regenerates it from the intact .mcap
    assert code == 0, err
    with BagReader(bag) as reader:
        assert reader.verify() == [] and reader.message_count == len(messages)


def test_cli_on_a_corrupt_bag_has_no_traceback_in_a_real_process(tmp_path, pristine):
    pristine_bag, data, _messages = pristine
    bag = _damaged_copy(tmp_path, pristine_bag, data, [(len(data) // 2, 5)])
    for argv in (["bag", "info", bag], ["identify", bag, "--out", tmp_path / "o"]):
        run = subprocess.run([sys.executable, "-m", "dea_ros.cli", *map(str, argv)], capture_output=True,
                             text=True, timeout=300)
        assert run.returncode == 2 and "Traceback" not in run.stderr and str(_mcap(bag)) in run.stderr
