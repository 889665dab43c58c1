"""Crash safety: SIGKILLed recorder, truncated and damaged files, recover_bag."""

import os
import select
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from dea_ros.bag import BagError, BagReader, BagTruncatedWarning, BagWarning, BagWriter, recover_bag
from dea_ros.bag.mcap_records import has_valid_footer
from dea_ros.bag.mcap_scan import scan_mcap

SCRIPT = Path(__file__).with_name("sigkill_writer_script.py")


def _check_prefix(messages):
    """Messages of the SIGKILL script: contiguous indexes 0..n-1 with the expected content."""
    ranges = [m for m in messages if m.topic == "/dea/range"]
    voltages = [m for m in messages if m.topic == "/dea/voltage"]
    for i, m in enumerate(ranges):
        assert m.message.header.stamp.nanosec == i
        assert m.message.header.frame_id == f"m{i}"
        assert m.message.range == i * 0.25
    for i, m in enumerate(voltages):
        assert m.message.data == i * 0.5
    assert abs(len(ranges) - len(voltages)) <= 1
    return ranges


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
def test_sigkill_loses_at_most_the_last_second(tmp_path):
    bag = tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, str(SCRIPT), str(bag), "0.2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        readable, _, _ = select.select([process.stdout], [], [], 60.0)
        assert readable, "writer process did not start within 60 s"
        line = process.stdout.readline()
        assert line.strip() == "ready", process.stderr.read()
        time.sleep(1.5)
        kill_time_ns = time.time_ns()
        os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == -signal.SIGKILL
    mcap_path = bag / "killed_0.mcap"
    assert not (bag / "metadata.yaml").exists()
    assert not has_valid_footer(mcap_path)

    # 1) The unfinished file is readable directly, with a truncation warning.
    with pytest.warns(BagWarning):
        with BagReader(bag) as reader:
            assert reader.truncated
            direct = list(reader.messages())
    ranges = _check_prefix(direct)
    assert len(ranges) > 100, "the writer should have recorded for more than a second"
    last_log_time = max(m.log_time_ns for m in direct)
    assert last_log_time >= kill_time_ns - 1_000_000_000, (
        f"lost {(kill_time_ns - last_log_time) / 1e9:.3f} s of data (> 1 s)"
    )

    # 2) recover_bag makes a complete bag with the same messages, readable by rosbags.
    report = recover_bag(bag)
    assert report.rewritten == [mcap_path]
    assert report.message_count == len(direct)
    assert (bag / "killed_0.mcap.truncated").exists() and has_valid_footer(mcap_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a recovered bag must read cleanly
        with BagReader(bag) as reader:
            assert not reader.truncated and reader.problems == []
            recovered = list(reader.messages())
            assert {t: i.message_count for t, i in reader.topics().items()} == report.topic_message_counts
            assert reader.topics()["/dea/range"].qos_profiles[0].reliability == "best_effort"
    assert [(m.topic, m.log_time_ns) for m in recovered] == [(m.topic, m.log_time_ns) for m in direct]
    _check_prefix(recovered)
    with AnyReader([bag]) as reader:
        assert reader.message_count == len(direct)
        frame_ids = [
            reader.deserialize(raw, c.msgtype).header.frame_id
            for c, _t, raw in reader.messages()
            if c.topic == "/dea/range"
        ]
        assert frame_ids == [f"m{i}" for i in range(len(ranges))]


def _small_bag(path: Path, count: int = 400, compression: str = "zstd") -> Path:
    with BagWriter(path, chunk_size_bytes=1024, flush_period_s=None, compression=compression) as writer:
        writer.add_topic("/dea/voltage", "std_msgs/msg/Float64")
        writer.add_topic("/dea/state", "std_msgs/msg/String")
        writer.add_metadata("protocol", {"step": "1"})
        for i in range(count):
            writer.write("/dea/voltage", {"data": float(i)}, 1_000_000 + 10 * i)
            if i % 4 == 0:
                writer.write("/dea/state", {"data": f"s{i}"}, 1_000_000 + 10 * i + 1)
    return path


def test_truncated_files_yield_their_complete_prefix(tmp_path):
    source = _small_bag(tmp_path / "source")
    mcap = source / "source_0.mcap"
    size = mcap.stat().st_size
    full_scan = scan_mcap(mcap)
    assert full_scan.complete and not full_scan.truncated
    written = [(m.channel_id, m.log_time, m.data) for m in full_scan.messages]
    previous = -1
    counts = {}
    cuts = sorted({200, size // 7, size // 3, size // 2, (2 * size) // 3, size - 200, size - 40, size - 1})
    for cut in cuts:
        bag = tmp_path / f"cut_{cut}"
        bag.mkdir()
        shutil.copyfile(mcap, bag / "cut_0.mcap")
        with open(bag / "cut_0.mcap", "r+b") as handle:
            handle.truncate(cut)
        with pytest.warns(BagWarning) as caught:
            reader = BagReader(bag)
        with reader:
            got = [(m.topic, m.log_time_ns, m.data) for m in reader.raw_messages()]
            if cut < full_scan.valid_end:
                assert reader.truncated
                assert any(issubclass(w.category, BagTruncatedWarning) for w in caught)
                assert any(str(bag / "cut_0.mcap") in p for p in reader.problems)
        # The readable messages are exactly the first k written ones (file order == time order here).
        topics = {1: "/dea/voltage", 2: "/dea/state"}
        expected_prefix = [(topics[c], t, d) for c, t, d in written[: len(got)]]
        assert got == expected_prefix
        assert len(got) >= previous
        previous = len(got)
        counts[cut] = len(got)
        report = recover_bag(bag, keep_original=False)
        assert report.message_count == len(got)
        assert not (bag / "cut_0.mcap.truncated").exists()
        with AnyReader([bag]) as independent:
            assert independent.message_count == len(got)
            assert [raw for _c, _t, raw in independent.messages()] == [d for _, _, d in got]
    assert 0 < counts[size // 7] < counts[size // 2] < len(written)  # the cuts really cut messages
    assert counts[size - 1] == len(written)  # only the summary was lost: every message survives


def test_file_cut_inside_the_header_is_reported(tmp_path):
    source = _small_bag(tmp_path / "source", count=10)
    bag = tmp_path / "stub"
    bag.mkdir()
    (bag / "stub_0.mcap").write_bytes((source / "source_0.mcap").read_bytes()[:40])
    with pytest.warns(BagWarning, match="metadata.yaml is missing"):
        with pytest.raises(BagError, match="ends before its MCAP Header"):
            BagReader(bag)
    with pytest.raises(BagError, match="ends before the MCAP Header"):
        recover_bag(bag)


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_damaged_chunk_stops_at_the_last_valid_record(tmp_path, compression):
    source = _small_bag(tmp_path / "damaged", compression=compression)
    mcap = source / "damaged_0.mcap"
    scan = scan_mcap(mcap)
    data = bytearray(mcap.read_bytes())
    if compression == "none":
        # Flip the last payload bytes of a message in the middle of the file: with uncompressed
        # chunks the record structure stays intact and only the chunk CRC detects the damage.
        victim = scan.messages[len(scan.messages) // 2]
        middle = bytes(data).index(victim.data) + len(victim.data) - 4
    else:
        middle = len(data) // 2  # inside some chunk's compressed data
    data[middle : middle + 4] = bytes(b ^ 0xFF for b in data[middle : middle + 4])
    (source / "metadata.yaml").unlink()
    mcap.write_bytes(bytes(data[: len(data) - 100]))  # and lose the footer
    damaged = scan_mcap(mcap)
    assert damaged.problem.startswith("damaged record at offset")
    assert len(damaged.messages) < len(scan.messages)
    assert [m.data for m in damaged.messages] == [m.data for m in scan.messages[: len(damaged.messages)]]
    with pytest.warns(BagWarning):
        with BagReader(source) as reader:
            assert reader.message_count == len(damaged.messages)


def test_recover_on_complete_bag_only_regenerates_metadata(tmp_path):
    bag = _small_bag(tmp_path / "healthy", count=50)
    before = (bag / "healthy_0.mcap").read_bytes()
    original_yaml = (bag / "metadata.yaml").read_text()
    (bag / "metadata.yaml").unlink()
    report = recover_bag(bag)
    assert report.rewritten == [] and report.dropped_bytes == 0
    assert (bag / "healthy_0.mcap").read_bytes() == before
    assert (bag / "metadata.yaml").read_text() == original_yaml


def test_idle_writer_is_flushed_by_the_background_thread(tmp_path):
    writer = BagWriter(tmp_path / "idle", flush_period_s=0.5, chunk_size_bytes=64 * 1024 * 1024)
    try:
        writer.add_topic("/x", "std_msgs/msg/Float64")
        for i in range(5):
            writer.write_serialized("/x", b"\x00\x01\x00\x00" + bytes(8), 100 + i)
        assert len(scan_mcap(writer.mcap_path).messages) == 0  # still in the open chunk
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and len(scan_mcap(writer.mcap_path).messages) < 5:
            time.sleep(0.02)
        assert len(scan_mcap(writer.mcap_path).messages) == 5
    finally:
        writer.close()


def test_recovered_humble_bag_keeps_the_humble_format(tmp_path):
    with BagWriter(tmp_path / "h", rosbag2_format="humble", chunk_size_bytes=256) as writer:
        writer.add_topic("/x", "std_msgs/msg/Float64")
        for i in range(100):
            writer.write("/x", {"data": float(i)}, 10 + i)
    mcap = tmp_path / "h" / "h_0.mcap"
    (tmp_path / "h" / "metadata.yaml").unlink()
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    report = recover_bag(tmp_path / "h")
    assert 0 < report.message_count < 100
    text = (tmp_path / "h" / "metadata.yaml").read_text()
    assert "version: 5\n" in text and "type_description_hash" not in text
    with AnyReader([tmp_path / "h"]) as reader:
        assert reader.message_count == report.message_count


# -- a full disk: recover never leaves a partial file and says so ------------------------------
def _run_with_file_size_limit(limit_bytes: int, *argv):
    """``python -m dea_ros.cli ARGV`` in a process that cannot grow a file beyond ``limit_bytes``
    (EFBIG, exactly what a full disk gives a writer)."""
    import resource

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "dea_ros.cli", *map(str, argv)], capture_output=True,
                          text=True, timeout=300, preexec_fn=limit)


def _cut_bag(tmp_path: Path, name: str, fraction: float = 0.6) -> Path:
    """A bag whose writer died in the middle of writing a chunk (at ``fraction`` of the file)."""
    bag = _small_bag(tmp_path / name, count=400)
    mcap = bag / f"{name}_0.mcap"
    data = mcap.read_bytes()
    chunk = next(c for c in scan_mcap(mcap).chunks if c.end > fraction * len(data))
    (bag / "metadata.yaml").unlink()
    mcap.write_bytes(data[: chunk.offset + chunk.record_length // 2])
    return bag


@pytest.mark.skipif(not hasattr(signal, "SIGXFSZ"), reason="needs POSIX file size limits")
def test_recover_on_a_full_disk_exits_2_and_leaves_no_partial_file(tmp_path):
    bag = _cut_bag(tmp_path, "full")
    mcap = bag / "full_0.mcap"
    before = mcap.read_bytes()
    run = _run_with_file_size_limit(len(before) // 3, "bag", "recover", bag)  # the copy cannot be written
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "disk full" in run.stderr and str(mcap) in run.stderr and "--in-place" in run.stderr
    assert sorted(p.name for p in bag.iterdir()) == ["full_0.mcap"]  # no .recovering, no 0-byte file
    assert mcap.read_bytes() == before
    # finishing where it lies needs no copy: it works under the same limit
    run = _run_with_file_size_limit(len(before) // 3 + len(before), "bag", "recover", "--in-place", bag)
    assert run.returncode == 0, run.stderr
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with BagReader(bag) as reader:
            assert reader.verify() == [] and not reader.truncated
            count = reader.message_count
    assert count == len(scan_mcap(bag / "full_0.mcap").messages) > 0
    with AnyReader([bag]) as reader:
        assert reader.message_count == count


@pytest.mark.skipif(not hasattr(signal, "SIGXFSZ"), reason="needs POSIX file size limits")
def test_metadata_yaml_that_cannot_be_written_leaves_no_partial_file(tmp_path):
    bag = _small_bag(tmp_path / "meta", count=50)
    (bag / "metadata.yaml").unlink()
    run = _run_with_file_size_limit(200, "bag", "recover", bag)  # metadata.yaml is ~1 kB
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert str(bag / "metadata.yaml") in run.stderr
    assert sorted(p.name for p in bag.iterdir()) == ["meta_0.mcap"]


def test_recover_checks_free_space_before_writing(tmp_path, monkeypatch):
    import dea_ros.bag.recover as recover_module

    bag = _cut_bag(tmp_path, "nospace")
    before = (bag / "nospace_0.mcap").read_bytes()
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(recover_module.shutil, "disk_usage", lambda _p: usage._replace(free=1000))
    with pytest.raises(BagError, match=r"nospace_0.mcap: disk full \(0.0 MiB free.*--in-place"):
        recover_bag(bag)
    assert sorted(p.name for p in bag.iterdir()) == ["nospace_0.mcap"]
    assert (bag / "nospace_0.mcap").read_bytes() == before


@pytest.mark.skipif(not hasattr(signal, "SIGXFSZ"), reason="needs POSIX file size limits")
def test_in_place_finish_writes_what_fits(tmp_path):
    """Room left by the disk after the valid prefix decides: summary, no summary, or nothing."""
    results = {}
    for room in (0, 60, 1_000_000):
        bag = _cut_bag(tmp_path, f"room{room}", fraction=0.55)
        mcap = bag / f"room{room}_0.mcap"
        scan = scan_mcap(mcap)
        run = _run_with_file_size_limit(scan.valid_end + room, "bag", "recover", "--in-place", bag)
        assert "Traceback" not in run.stderr
        results[room] = run.returncode
        if room == 0:  # not even Data End and Footer fit: cut back to the valid prefix, said so
            assert run.returncode == 2 and "disk full" in run.stderr and str(mcap) in run.stderr
            assert mcap.stat().st_size == scan.valid_end
            with pytest.warns(BagWarning):
                with BagReader(bag) as reader:
                    assert reader.message_count == len(scan.messages)
            continue
        assert run.returncode == 0, run.stderr
        finished = scan_mcap(mcap, verify=True)
        assert finished.complete and finished.damage == []
        assert len(finished.messages) == len(scan.messages)
        with AnyReader([bag]) as reader:
            assert reader.message_count == len(scan.messages)
        if room == 60:
            assert mcap.stat().st_size == scan.valid_end + 50  # Data End, Footer (no summary), magic
        else:
            assert mcap.stat().st_size > scan.valid_end + 1000  # with the summary and the rosbag2 record
    assert results == {0: 2, 60: 0, 1_000_000: 0}
