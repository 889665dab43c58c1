"""A bag's messages on their original schedule, for a replay (no ROS).

:func:`open_playback` checks the bag and the topics and finds the first real log time;
:func:`playback_schedule` yields each raw message with the time it is due after the start of a
pass (pauses in the log longer than ``max_gap_s`` cut out). ``dea-ros replay``'s node
(:mod:`dea_ros.nodes.replay_node`) publishes them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

from .reader import BagReader

__all__ = ["BagPlayback", "open_playback", "playback_schedule"]


@dataclass(frozen=True)
class BagPlayback:
    """What a replay plays: the bag, its topics (name -> topic info), the topics replayed and the
    first real log time, ns."""

    path: object
    topics: dict
    wanted: list
    first_log_time_ns: int


def open_playback(bag_path, topics=None) -> BagPlayback:
    """Check the bag and the topics (default: all); a ValueError names the topics it lacks."""
    with BagReader(bag_path) as bag:
        info = bag.topics()
        wanted = list(info) if not topics else list(topics)
        missing = [t for t in wanted if t not in info]
        if missing:
            raise ValueError(f"{bag_path}: topics {missing} are not in the bag (it has {sorted(info)})")
        # the first real log time (a message logged with time 0, e.g. before a simulated clock
        # started, would otherwise make the replay wait decades)
        t_first = next((m.log_time_ns for m in bag.raw_messages(wanted) if m.log_time_ns > 0), 0)
    return BagPlayback(bag_path, info, wanted, t_first)


def playback_schedule(playback: BagPlayback, start_offset_s: float = 0.0, max_gap_s: float = 10.0,
                      on_gap: Callable[[int], None] | None = None) -> Iterator[tuple[int, object]]:
    """One pass over the bag: (ns after the start of the pass at rate 1, raw message) in log-time order.

    Messages before ``start_offset_s`` (s after the first log time) are left out; a pause in the
    log longer than ``max_gap_s`` is cut out (``on_gap(pause_ns)`` is called for each).
    """
    offset_ns = int(start_offset_s * 1e9)
    skipped_ns = 0
    previous_ns = None
    with BagReader(playback.path) as bag:
        for msg in bag.raw_messages(playback.wanted):
            rel = msg.log_time_ns - playback.first_log_time_ns - offset_ns
            if rel < 0:
                continue
            if previous_ns is not None and msg.log_time_ns - previous_ns > max_gap_s * 1e9:
                skipped_ns += msg.log_time_ns - previous_ns  # a long pause in the log: do not wait it out
                if on_gap is not None:
                    on_gap(msg.log_time_ns - previous_ns)
            previous_ns = msg.log_time_ns
            yield rel - skipped_ns, msg
