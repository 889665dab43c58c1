"""Offset sines u = offset + U sin (issue 21, session 20): the planner's second pass picks them, and until
session 20 the identification left every one out -- its data test took the response's component at f (u^2 has
one: 2 offset U sin) for a period-doubled one, and the model has no period-doubled orbit there. Records from
a held-voltage run from rest by converged integration (synth_rig), 1 um laser noise, ILD1320 quantisation."""
from __future__ import annotations

import numpy as np

from dea_ros.identify.classification import classify_records
from dea_ros.identify.protocols import Protocol
from dea_ros.identify.synth_rig import rig_experiments, rig_settle_times
from dea_ros.sim.plant import LASER_QUANTISATION_M

from .conftest import UNLIKE

FREQUENCIES_HZ = [2.0, 8.0, 9.5, 11.0]


def _experiments():
    settle = rig_settle_times(UNLIKE)
    proto = Protocol.from_dict({"name": "offsets", "membrane": "UNLIKE", "mass_kg": UNLIKE.mass_kg, "segments": [
        {"kind": "static", "voltages_V": [0.0, 2000.0], "hold_s": settle.static_hold_s, "measure_s": 1.0},
        {"kind": "sine", "amplitude_V": 2500.0, "frequencies_Hz": [9.0], "settle_s": settle.sine_settle_s,
         "measure_s": 2.0},
        {"kind": "sine", "amplitude_V": 1200.0, "offset_V": 1200.0, "frequencies_Hz": FREQUENCIES_HZ,
         "settle_s": settle.sine_settle_s, "measure_s": 2.0},
        {"kind": "rest", "hold_s": 0.5}]}, source="offsets")
    exp, _rec = rig_experiments(UNLIKE, proto, seed=7, quantisation_m=LASER_QUANTISATION_M)
    return exp


def test_offset_sines_are_periodic_records_with_the_period_of_their_excitation_and_are_fitted():
    exp = _experiments()
    plain, offset = exp.sines
    assert plain.waveform == "abs_sine" and offset.waveform == "sine"
    assert [plain.offset_V(k) for k in range(plain.frequency_Hz.size)] == [0.0]
    assert [offset.offset_V(k) for k in range(offset.frequency_Hz.size)] == [1200.0] * len(FREQUENCIES_HZ)
    assert [(a, o, list(sel)) for a, o, sel in offset.waveform_groups()] == [(1200.0, 1200.0, [0, 1, 2, 3])]
    # the data alone: period T for the offset sine (u^2 has a component at f), T/2 for |U sin|
    tests = [s.classify(exp.sensor_noise_m) for s in offset.series]
    assert [t["kind"] for t in tests] == ["periodic"] * len(FREQUENCIES_HZ)
    assert {t["forcing_period"] for t in tests} == {"T"}
    assert plain.series[0].classify(exp.sensor_noise_m)["forcing_period"] == "T/2"
    # the model at the truth: every record fitted on the branch of its own excitation, whose RMS is the record's
    entries = classify_records(UNLIKE, exp, noise_m=exp.sensor_noise_m)
    for e in entries:
        assert e["used"] == "periodic", e
        assert abs(e["fitted_model_rms_m"] / e["measured_rms_m"] - 1.0) < 0.01, e
    assert [e.get("offset_V", 0.0) for e in entries] == [0.0] + [1200.0] * len(FREQUENCIES_HZ)
    assert "guess" in entries[-1] and np.all(np.isfinite(entries[-1]["guess"]))


def test_a_sweep_that_cannot_start_at_the_records_starts_below_them_or_leaves_them_out(monkeypatch):
    """Session 20's CI: a planned pass's records at the resonance peak, the model's sweep started at the first of
    them did not solve (next to a fold) and the identification failed. The sweep starts again from half the lowest
    frequency (upward, as a slow sweep reaches them); if that fails too, the records are left out of the round."""
    import dea_ros.identify.classification as classification
    from dea_ros.errors import HarmonicBalanceError

    exp = _experiments()
    real = classification.sweep_for
    calls = []

    def starts_below_only(params, amplitude_V, freqs, n_harmonics, realised=True, offset_V=0.0):
        calls.append((amplitude_V, offset_V, float(np.min(freqs))))
        if offset_V and np.min(freqs) >= min(FREQUENCIES_HZ):
            raise HarmonicBalanceError("no solution at the first frequency (test)")
        return real(params, amplitude_V, freqs, n_harmonics, realised, offset_V)

    monkeypatch.setattr(classification, "sweep_for", starts_below_only)
    entries = classify_records(UNLIKE, exp, noise_m=exp.sensor_noise_m)
    assert (1200.0, 1200.0, 0.5 * min(FREQUENCIES_HZ)) in calls
    assert [e["used"] for e in entries] == ["periodic"] * (1 + len(FREQUENCIES_HZ))

    def never(params, amplitude_V, freqs, n_harmonics, realised=True, offset_V=0.0):
        if offset_V:
            raise HarmonicBalanceError("no solution (test)")
        return real(params, amplitude_V, freqs, n_harmonics, realised, offset_V)

    monkeypatch.setattr(classification, "sweep_for", never)
    entries = classify_records(UNLIKE, exp, noise_m=exp.sensor_noise_m)
    assert entries[0]["used"] == "periodic"
    for e in entries[1:]:
        assert e["used"] == "left out" and "could not be computed" in e["reason"] and "offset" in e["reason"]
