"""Synthetic experiments as the rig records them (issue 21, session 11): the held voltage integrated from
rest converges (halving the tolerance, and against SciPy's DOP853 restarted at every hold), and a membrane
unlike the presets identified from one such run lies within its intervals; two recorded passes (an adaptive
protocol's) are cut each on its own time line, as from identifier_node's bag, a frequency recorded twice
in records of its own."""
from __future__ import annotations

import math

import numpy as np
import pytest

from dea_ros.identify.pipeline import identify
from dea_ros.identify.protocols import Protocol
from dea_ros.identify.static_fit import EXTENDED_COMBINATION_MATRIX
from dea_ros.identify.synth_rig import (RecordedPass, passes_experiments, record_protocol, rig_experiments,
                                        rig_protocol, rig_settle_times, rig_sine_settle_s)
from dea_ros.model.equilibrium import static_equilibrium
from dea_ros.sim.plant import LASER_QUANTISATION_M
from dea_ros.solvers.inputs import SampledVoltage
from dea_ros.solvers.integrate import simulate, simulate_held

from fakes.membranes import F07

from .conftest import PAPER_FREQUENCIES_HZ, UNLIKE


def test_held_integration_converges_and_agrees_with_dop853_restarted_at_every_hold():
    period = 1.0 / 500.0
    t = np.arange(60) * period
    u = np.where(t < 0.02, 0.0, 2200.0)
    u[t >= 0.06] = np.abs(2500.0 * np.sin(2 * np.pi * 9.3 * t[t >= 0.06] + 0.7))
    run = simulate_held(UNLIKE, u, period)
    half = simulate_held(UNLIKE, u, period, rtol=5e-11, atol_scale=5e-11)
    assert run.time_s.size == u.size + 1 and run.time_s[-1] == pytest.approx(u.size * period)
    assert np.max(np.abs(run.displacement_m - half.displacement_m)) < 1e-11
    ref = simulate(UNLIKE, SampledVoltage(t, u, hold="zoh"), run.time_s[-1], t_eval=run.time_s, rtol=1e-11,
                   atol_scale=1e-11)
    assert np.max(np.abs(run.state - ref.state) / np.abs(ref.state).max(axis=1, keepdims=True)) < 1e-8
    assert np.max(np.abs(run.displacement_m - ref.displacement_m)) < 1e-10
    assert np.ptp(run.displacement_m) > 5e-6          # it moved: the step and the sine are in it


def test_a_protocol_run_from_rest_is_converged_continuous_and_starts_each_sine_at_a_random_phase():
    settle = rig_settle_times(UNLIKE)
    assert settle.sine_settle_s >= 7 * UNLIKE.eta1_Pa_s / UNLIKE.k1_Pa * 0.9   # the creep mode sets it here
    proto = rig_protocol(UNLIKE, (9.0, 40.0), settle)
    rec = record_protocol(UNLIKE, proto, seed=3, quantisation_m=LASER_QUANTISATION_M)
    assert rec.tolerance_check_m < 1e-9                  # 1e-3 of the laser noise, checked in every run
    sines = [s for s in rec.segments if s.kind == "sine"]
    phases = [(rec.start_shift_s[s.index] * s.info["frequency_Hz"]) % 1.0 for s in sines]
    assert len(set(np.round(phases, 6))) == 2 and all(0.0 <= p < 1.0 for p in phases)
    for s in sines:                                     # the held voltage at the segment's start is the shifted sine
        k = int(np.searchsorted(rec.time_s, s.start_s - 1e-9))
        expected = abs(2500.0 * math.sin(2 * math.pi * s.info["frequency_Hz"] * (rec.time_s[k] - s.start_s
                                                                                 + rec.start_shift_s[s.index])))
        assert rec.voltage_V[k] == pytest.approx(expected, abs=1e-6)
    # one run from rest: the laser reads noise (1 um) and quantisation around the true displacement
    resid = rec.displacement_measured_m - rec.displacement_true_m
    assert 0.9e-6 < np.std(resid) < 1.1e-6
    assert abs(rec.displacement_true_m[0] - rec.displacement_true_m[:50].mean()) < 1e-9   # at rest at 0 V


def test_identification_from_a_held_run_is_within_its_intervals():
    proto = rig_protocol(UNLIKE, PAPER_FREQUENCIES_HZ)
    exp, rec = rig_experiments(UNLIKE, proto, seed=5, other_masses_kg=(0.0, 0.001, 0.002, 0.003, 0.004, 0.005),
                               quantisation_m=LASER_QUANTISATION_M)
    assert exp.sines[0].waveform == "abs_sine" and len(exp.sines[0].inputs) == 4   # cut as from a bag
    res = identify(exp, evaluate_fit=False)
    st = res.statistics
    combos = EXTENDED_COMBINATION_MATRIX @ np.r_[UNLIKE.beta_Pa, UNLIKE.gamma_Pa]
    truth = {"eps_r": UNLIKE.relative_permittivity, "k1_Pa": UNLIKE.k1_Pa, "eta1_Pa_s": UNLIKE.eta1_Pa_s,
             "eta2_Pa_s": UNLIKE.eta2_Pa_s, "sigma_h(1)_Pa": combos[0]}
    for name, value in truth.items():
        i = st.names.index(name)
        assert st.ci_low[i] <= value <= st.ci_high[i], (name, st.values[i], value, st.ci_low[i], st.ci_high[i])
        assert abs(st.values[i] / value - 1) < 0.01, name


def test_two_recorded_passes_are_cut_each_on_its_own_time_line():
    first = rig_protocol(UNLIKE, (9.0, 40.0))
    second = Protocol.from_dict({"name": "planned", "membrane": "UNLIKE", "mass_kg": UNLIKE.mass_kg, "segments": [
        {"kind": "rest", "hold_s": 2.0}, {"kind": "step", "initial_V": 0.0, "final_V": 1500.0, "pre_s": 0.2,
                                          "hold_s": 1.0},
        {"kind": "sine", "amplitude_V": 1000.0, "offset_V": 1200.0, "frequencies_Hz": [7.0], "settle_s": 3.0,
         "measure_s": 1.0},
        {"kind": "sine", "amplitude_V": 1500.0, "frequencies_Hz": [9.0], "settle_s": 3.0, "measure_s": 1.0},
        {"kind": "rest", "hold_s": 0.5}]}, source="planned")
    rec1 = record_protocol(UNLIKE, first, seed=2)
    rec2 = record_protocol(UNLIKE, second, seed=3)
    start2 = rec1.segments[-1].end_s + 30.0
    passes = [RecordedPass(first, rec1), RecordedPass(second, rec2, start2, {"plan_json": "{}"})]
    exp = passes_experiments(UNLIKE, passes, seed=2)
    assert sorted(float(s.voltage_V.max()) for s in exp.steps) == [1500.0, 2200.0]
    step2 = next(s for s in exp.steps if s.voltage_V.max() == 1500.0)
    # pass 2's step is pass 2's recording, at its own t0: its samples are rec2's readings, in order
    k = int(np.flatnonzero(rec2.displacement_measured_m == step2.displacement_m[0])[0])
    assert np.array_equal(step2.displacement_m, rec2.displacement_measured_m[k:k + step2.displacement_m.size])
    # pass 2's offset sine is a record of its own; its 9 Hz at 1500 V (pass 1 has 9 Hz at 2500 V) is in a
    # second |U sin| record, as a frequency appears once in each (the planner picks a frequency at two
    # amplitudes: session 20, the identification of such a bag failed)
    got = [(s.waveform, list(s.frequency_Hz), list(s.amplitude_V)) for s in exp.sines]
    assert got == [("abs_sine", [9.0, 40.0], [2500.0, 2500.0]), ("abs_sine", [9.0], [1500.0]),
                   ("sine", [7.0], [1000.0])]
    assert exp.sines[1].source.endswith("sine segments (2)")


def test_a_sine_near_the_fold_is_held_until_its_periodic_orbit_has_settled():
    """F07 (fakes.membranes) at 11.1 Hz, near its fold: the approach to the orbit is slower than any time
    constant at rest. Forward integration of the held |2.5 kV sin| from rest measures it, apart from the
    Floquet estimate the hold comes from (45 updates a period at 500 Hz: every window starts at the same
    phase): the RMS over 22 periods after the rest's hold (12 slowest time constants at rest, the rule before
    session 22) is off the settled RMS by ~0.4 um -- ~25 x its own noise with a 1 um laser --, after
    rig_sine_settle_s's hold by ~1 nm; a frequency away from the fold keeps the rest's hold."""
    rate = 500.0
    f = rate / 45
    settle = rig_settle_times(F07)
    held = rig_sine_settle_s(F07, (0.2, f), settle)
    assert held[0.2] == pytest.approx(settle.sine_settle_s, rel=0.01) and held[f] > 1.5 * settle.sine_settle_s
    t = np.arange(int((2 * held[f] + 2.0) * rate)) / rate
    x0 = np.asarray(static_equilibrium(F07, 0.0).state, float).reshape(3)
    d = simulate_held(F07, np.abs(2500.0 * np.sin(2 * np.pi * f * t)), 1.0 / rate, x0=x0).displacement_m

    def rms_after(hold_s: float) -> float:
        k = int(round(hold_s * f)) * 45
        return float(np.std(d[k:k + 22 * 45]))
    settled = rms_after(2 * held[f])
    assert abs(rms_after(settle.sine_settle_s) - settled) > 2e-7
    assert abs(rms_after(held[f]) - settled) < 1e-8
