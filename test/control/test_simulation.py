"""loop_delays: the sample -> applied-voltage delay recovered from recorded streams."""
import numpy as np

from dea_ros.control import loop_delays
from dea_ros.hardware.amplifier.limits import SafetyLimits
from dea_ros.hardware.amplifier.safety import SafeVoltageController

PERIOD = 1e-3
SLEW = 1e5


def record(delay_of, n=600, seed=1):
    """Commands of a noisy controller (small moves and jumps larger than the slew limit) and the output of
    the real safety core whose target at update j is the command of sample j - delay_of(j); float32 on the
    wire; 1 % of the commands lost (best effort)."""
    rng = np.random.default_rng(seed)
    u = 2000.0 + np.cumsum(rng.normal(0.0, 15.0, n))
    u[200:260] += 600.0                    # a jump: the output is slew-limited for several updates
    u[400:420] = 3150.0                    # saturated: repeated values
    amp = SafeVoltageController(SafetyLimits(max_voltage_V=3150.0, slew_rate_V_per_s=SLEW,
                                             watchdog_timeout_s=1.0, ramp_down_rate_V_per_s=1e4))
    t0 = 1795436000.0                      # epoch-like stamps, as in simulated time
    amp.activate(t0)
    amp.command(float(u[0]), t0)
    amp.update(t0)
    applied = []
    for j in range(1, n):
        k = j - delay_of(j)
        if k >= 0:
            amp.command(float(u[k]), t0 + j * PERIOD)
        applied.append((t0 + j * PERIOD, float(np.float32(amp.update(t0 + j * PERIOD)))))
    keep = rng.random(n) > 0.01
    commands = [(t0 + k * PERIOD, float(np.float32(u[k]))) for k in range(n) if keep[k]]
    return commands, applied


def test_a_constant_delay_is_recovered_for_every_countable_update():
    commands, applied = record(lambda j: 2)
    delays = loop_delays(commands, applied, PERIOD, SLEW)
    assert len(delays) > 300                 # all but the slew-limited, saturated and lost ones
    assert set(delays) == {2}


def test_a_varying_delay_is_seen_as_such():
    commands, applied = record(lambda j: 1 if j % 3 else 3)
    delays = loop_delays(commands, applied, PERIOD, SLEW)
    assert set(delays) == {1, 3}
    assert 1.5 < delays.count(1) / delays.count(3) < 2.5
