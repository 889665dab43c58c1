"""Experiment protocols: schedule, commanded waveforms, validation messages."""
import math

import pytest

from dea_ros.identify.protocols import Protocol, ProtocolError, load_protocol


def test_shipped_protocols_load():
    for name in ("paper", "quick", "test", "quick_adaptive"):
        p = load_protocol(name)
        segs = p.schedule()
        assert segs[0].start_s == 0.0
        assert all(a.end_s == pytest.approx(b.start_s) for a, b in zip(segs, segs[1:]))
        assert p.duration_s() == pytest.approx(segs[-1].end_s)


def test_waveforms():
    p = Protocol.from_dict({"protocol": {"segments": [
        {"kind": "static", "voltages_V": [0, 2000], "hold_s": 2.0, "measure_s": 0.5},
        {"kind": "step", "initial_V": 0, "final_V": 2200, "pre_s": 0.5, "hold_s": 2.0},
        {"kind": "sine", "amplitude_V": 2500, "frequencies_Hz": [3.3], "settle_s": 1.0, "measure_s": 1.0},
    ]}})
    s = p.schedule()
    assert [x.kind for x in s] == ["static", "static", "step", "sine"]
    assert s[1].voltage_at(3.0) == 2000 and (s[1].measure_start_s, s[1].measure_end_s) == (3.5, 4.0)
    assert s[2].voltage_at(4.4) == 0 and s[2].voltage_at(4.5) == 2200
    sine = s[3]
    # settle and measure windows are whole periods; no offset: |U sin| (the model sees u^2)
    f = 3.3
    assert (sine.measure_start_s - sine.start_s) * f == pytest.approx(round((sine.measure_start_s - sine.start_s) * f))
    assert sine.info["periods"] == math.ceil(1.0 * f)
    t = sine.start_s + 0.25 / f + 0.5 / f
    assert sine.voltage_at(t) == pytest.approx(2500 * abs(math.sin(2 * math.pi * f * (t - sine.start_s))))
    assert sine.voltage_at(t) >= 0


@pytest.mark.parametrize("segments, message", [
    ([], "non-empty"),
    ([{"kind": "jump"}], "unknown kind"),
    ([{"kind": "static", "voltages_V": [0], "hold_s": 1, "measure_s": 2}], "measure_s"),
    ([{"kind": "static", "voltages_V": [-5], "hold_s": 1}], "negative voltage"),
    ([{"kind": "sine", "amplitude_V": 1, "frequencies_Hz": [0], "settle_s": 1, "measure_s": 1}], "frequency"),
    ([{"kind": "step", "final_V": 100, "hold_s": 1, "typo": 3}], "unknown field"),
    ([{"kind": "step", "hold_s": 1}], "final_V"),
])
def test_invalid_protocols_name_the_problem(segments, message):
    with pytest.raises(ProtocolError, match=message):
        Protocol.from_dict({"protocol": {"segments": segments}})


def test_max_voltage_is_enforced():
    p = load_protocol("paper")
    with pytest.raises(ProtocolError, match="exceeds the rig's maximum"):
        p.schedule(max_voltage_V=2400.0)
