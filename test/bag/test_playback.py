"""The replay's schedule, without ROS: which messages are due when (offset, pauses cut out, time-0 messages)."""
import pytest

from dea_ros.bag import BagWriter
from dea_ros.bag.playback import open_playback, playback_schedule

T0 = 1_700_000_000_000_000_000


@pytest.fixture
def bag_dir(tmp_path):
    """A 0-stamped message (before a simulated clock), 10 messages 10 ms apart, a 30 s pause, 2 more."""
    path = tmp_path / "bag"
    with BagWriter(path) as bag:
        bag.add_topic("/a", "std_msgs/msg/Float64")
        bag.add_topic("/b", "std_msgs/msg/Float64")
        bag.write("/a", {"data": -1.0}, 0)
        for k in range(10):
            bag.write("/a" if k % 2 == 0 else "/b", {"data": float(k)}, T0 + k * 10_000_000)
        for k in range(2):
            bag.write("/a", {"data": 10.0 + k}, T0 + 30_000_000_000 + k * 10_000_000)
    return path


def test_the_first_log_time_is_the_first_real_one_and_every_topic_by_default(bag_dir):
    playback = open_playback(bag_dir)
    assert playback.first_log_time_ns == T0
    assert sorted(playback.wanted) == ["/a", "/b"]


def test_missing_topics_are_named(bag_dir):
    with pytest.raises(ValueError, match=r"\['/c'\] are not in the bag"):
        open_playback(bag_dir, ["/a", "/c"])


def test_long_pauses_are_cut_out_and_reported(bag_dir):
    gaps = []
    due = [(t, m.topic) for t, m in playback_schedule(open_playback(bag_dir), max_gap_s=10.0, on_gap=gaps.append)]
    assert [t for t, _ in due] == [k * 10_000_000 for k in range(10)] + [90_000_000, 100_000_000]
    assert gaps == [30_000_000_000 - 90_000_000]
    assert [t for t, _ in playback_schedule(open_playback(bag_dir), max_gap_s=60.0)][-1] == 30_010_000_000


def test_the_start_offset_and_the_topic_subset(bag_dir):
    due = list(playback_schedule(open_playback(bag_dir, ["/b"]), start_offset_s=0.05))
    # /b at 10, 30, ..., 90 ms: its first message starts the clock, 50 ms later leaves those at 70 and 90 ms
    assert [t for t, _ in due] == [10_000_000, 30_000_000]
    assert {m.topic for _, m in due} == {"/b"}
