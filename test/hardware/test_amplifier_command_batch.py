"""CommandQueue (batched voltage commands): what a batch must be to be queued, and one sample per update.

Fed through the unchanged SafeVoltageController like amplifier_node does, a queued batch produces the
same outputs as the same commands sent one per update; a batch the queue refuses queues nothing.
"""
import math

import pytest

from dea_ros.hardware.amplifier.command_batch import CommandQueue
from dea_ros.hardware.amplifier.limits import SafetyLimits
from dea_ros.hardware.amplifier.safety import SafeVoltageController

PERIOD = 0.004
T0 = 1_795_000_000.0  # simulated time since the epoch, as the mock rig's clock


def _queue(max_length=10, span_s=0.5):
    return CommandQueue(max_length, PERIOD, span_s)


def _offsets(n):
    return [i * PERIOD for i in range(n)]


def test_an_accepted_batch_gives_one_sample_per_update_in_order():
    q = _queue()
    verdict = q.offer(T0 + PERIOD, _offsets(3), [10.0, 20.0, 30.0], last_update_s=T0, activated=True)
    assert verdict and verdict.last_sample_s == pytest.approx(T0 + 3 * PERIOD)
    assert [q.take(T0 + k * PERIOD) for k in (1, 2, 3, 4)] == [10.0, 20.0, 30.0, None]


@pytest.mark.parametrize("first_s, offsets, values, last_update_s, activated, reason", [
    (T0 + PERIOD, _offsets(11), [1.0] * 11, T0, True, "oversized"),
    (T0 + PERIOD, _offsets(3), [1.0] * 3, T0, False, "inactive"),
    (T0, _offsets(3), [1.0] * 3, T0, True, "stale"),                       # for the update already done
    (T0 - 1.0, _offsets(3), [1.0] * 3, T0, True, "stale"),                 # replayed / delayed
    (T0 + 3 * PERIOD, _offsets(3), [1.0] * 3, T0, True, "not for the next update"),
    (T0 + PERIOD, [0.0, 0.0, 0.0], [1.0] * 3, T0, True, "not one sample per update"),
    (T0 + PERIOD, [0.0, 2 * PERIOD], [1.0] * 2, T0, True, "not one sample per update"),
    (T0 + PERIOD, [0.0, math.nan], [1.0] * 2, T0, True, "not one sample per update"),
    (T0 + PERIOD, [], [], T0, True, "malformed"),
    (T0 + PERIOD, _offsets(2), [1.0] * 3, T0, True, "malformed"),
    (math.nan, _offsets(2), [1.0] * 2, T0, True, "stale"),
    (T0 + PERIOD, _offsets(2), [1.0] * 2, None, True, "stale"),
])
def test_a_refused_batch_queues_nothing_and_empties_the_queue(first_s, offsets, values, last_update_s,
                                                              activated, reason):
    q = _queue()
    assert q.offer(T0 + PERIOD, _offsets(3), [5.0] * 3, last_update_s=T0, activated=True)
    verdict = q.offer(first_s, offsets, values, last_update_s, activated)
    assert not verdict and verdict.reason == reason
    assert len(q) == 0 and q.take(T0 + PERIOD) is None
    assert q.counts()[f"rejected {reason}"] == 1


def test_a_batch_may_not_span_more_than_the_watchdog():
    q = CommandQueue(100, PERIOD, max_span_s=10 * PERIOD)
    assert q.offer(T0 + PERIOD, _offsets(10), [1.0] * 10, T0, True)
    verdict = q.offer(T0 + PERIOD, _offsets(11), [1.0] * 11, T0, True)
    assert not verdict and verdict.reason == "longer than the watchdog"


def test_samples_of_skipped_updates_are_dropped_not_applied_late():
    q = _queue()
    assert q.offer(T0 + PERIOD, _offsets(4), [1.0, 2.0, 3.0, 4.0], T0, True)
    assert q.take(T0 + 3 * PERIOD) == 3.0     # the clock jumped two updates: 1 and 2 are gone
    assert q.skipped_samples == 2
    assert q.take(T0 + 100 * PERIOD) is None  # a big jump: nothing left for a later update
    assert len(q) == 0


def _run(controller, commands_per_update, t_updates):
    out = []
    for t, command in zip(t_updates, commands_per_update):
        if command is not None:
            controller.command(command, t)
        out.append(controller.update(t))
    return out


def test_through_the_controller_a_batch_equals_the_same_single_commands():
    """The queue is only a delay line: every sample goes through the same controller at its own update
    (slew-limited step, watchdog), as K single commands sent one per update would."""
    limits = SafetyLimits(max_voltage_V=3000.0, slew_rate_V_per_s=100000.0, watchdog_timeout_s=0.05,
                          ramp_down_rate_V_per_s=50000.0)
    values = [0.0, 2500.0, 2500.0, 2600.0, 2600.0, 100.0, 100.0, 100.0]
    t_updates = [T0 + k * PERIOD for k in range(1, 40)]
    single = SafeVoltageController(limits)
    single.activate(T0)
    expected = _run(single, values + [None] * (len(t_updates) - len(values)), t_updates)

    batched = SafeVoltageController(limits)
    batched.activate(T0)
    q = _queue()
    assert q.offer(T0 + PERIOD, _offsets(len(values)), values, last_update_s=T0, activated=True)
    got = _run(batched, [q.take(t) for t in t_updates], t_updates)
    assert got == expected
    for k in range(1, len(got)):  # never faster than the slew limit over each update's own time step
        assert abs(got[k] - got[k - 1]) <= 100000.0 * (t_updates[k] - t_updates[k - 1]) * (1 + 1e-12)
    assert got[-1] == 0.0  # the watchdog ended it once the samples ran out, as after the last single command


def test_constructor_refuses_a_queue_without_bounds():
    with pytest.raises(ValueError):
        CommandQueue(0, PERIOD, 0.5)
    with pytest.raises(ValueError):
        CommandQueue(10, 0.0, 0.5)
