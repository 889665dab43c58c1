"""Synthetic experiments as the rig records them: one held-voltage run from rest, cut like a bag.

:mod:`.synth` builds each record on its own (the sines from the converged periodic orbit, the step from
rest); this module produces what the rig (or the mock) produces: the protocol's voltage schedule
(:meth:`~dea_ros.identify.protocols.Protocol.schedule`: static staircase, rest, step, the sine
frequencies each with its ``settle_s`` and ``measure_s``, every segment continuing from the state the
previous one left) sampled and held at the amplifier's update rate (the command of each update held
until the next, as the amplifier's DAQ holds it), integrated from rest by
:func:`~dea_ros.solvers.integrate.simulate_held` (adaptive Dormand-Prince 5(4) on every hold, relative
tolerance 1e-10). The convergence is checked on every run: the same schedule at half the tolerances,
the largest difference of the displacement (``tolerance_check_m``) must stay below 1e-3 of the laser
noise (1 nm for 1 um); otherwise the tolerance is tightened x10, twice, then
:class:`~dea_ros.errors.IntegrationError` (near a fold a record can depend on the integration error).
Each sine starts at a random phase of its excitation (its segment's voltage shifted by a uniform
fraction of a period, so the measured whole periods start there too). The laser samples the displacement
at every update with Gaussian noise and its quantisation
(:class:`~dea_ros.identify.synth.LaserReadings`; the ILD1320's in the bench and the tests). The signals
and the identifier's metadata record (:func:`~dea_ros.identify.bag_experiments.experiment_record`) go
through the extraction a bag's data takes
(:func:`~dea_ros.identify.bag_experiments.experiments_from_signals`): the fit sees what it would see
from the bag identifier_node records. An adaptive protocol's two passes (:func:`passes_experiments`) go the
same way, each pass's schedule in its own metadata record with its own t0.

Settle times (:func:`rig_settle_times`) follow from the membrane: the slowest time constant of the model
linearised at rest (0 V and the sine's mean u^2: the creep mode, and the ringing of the mass, 1/(zeta
omega)); a level of the staircase, the rest before the step and each sine are held ``factor`` (12) of it
(e^-12 ~ 6e-6 of the transient left: a creep of ~300 um then misses equilibrium by ~2 nm, a tenth of the
noise of a static point's mean; 7 left 0.1-0.3 um, several times it), at least the protocol defaults (3 s,
2 s, 5 s). Near a resonance or a fold the approach to the periodic response is slower than any time
constant at rest (a Floquet multiplier near 1): each sine frequency is held ``factor`` of the slowest time
constant of the stable periodic orbits there where that is the longer (:func:`rig_sine_settle_s`; before
session 22 the rest's alone, and the peak records of slow-creep membranes were measured still settling).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import IntegrationError
from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..model.settling import slowest_time_constant_s
from ..solvers.inputs import SinePeriodic
from ..solvers.integrate import simulate_held
from ..solvers.sweep import orbit_time_constants
from .bag_experiments import BagSignals, experiment_record, experiments_from_signals, pass_metadata_name
from .experiments import GEOMETRY_FIELDS
from .protocols import Protocol, segment_at
from .synth import LaserReadings, static_points

__all__ = ["RigSettleTimes", "RigRecording", "RecordedPass", "rig_settle_times", "rig_sine_settle_s", "rig_protocol",
           "record_protocol", "rig_experiments", "passes_experiments"]

T0_NS = 1_700_000_000_000_000_000   # the protocol's start on the (synthetic) epoch clock, ns


@dataclass(frozen=True)
class RigSettleTimes:
    """Holds chosen from the membrane (s): module docstring."""

    slowest_time_constant_s: float   # of the model linearised at rest, over 0 V and the sine's mean u^2
    static_hold_s: float
    rest_s: float
    sine_settle_s: float             # at least, every frequency (rig_sine_settle_s)
    factor: float = 12.0             # holds in time constants


@dataclass
class RigRecording:
    """One held-voltage run: update instants (s from the protocol start), held voltage (V, from each instant
    on), the true and the measured displacement (m), the schedule and the convergence check (m)."""

    time_s: np.ndarray
    voltage_V: np.ndarray
    displacement_true_m: np.ndarray
    displacement_measured_m: np.ndarray
    segments: list
    start_shift_s: dict          # sine segment index -> time shift of its voltage (the random start phase)
    tolerance_check_m: float     # max |d(rtol) - d(rtol / 2)|
    wall_s: float


def rig_settle_times(params: MembraneParameters, amplitude_V: float = 2500.0, factor: float = 12.0,
                     static_factor: float = 12.0) -> RigSettleTimes:
    """The holds of :func:`rig_protocol` for ``params`` (module docstring)."""
    tau = max(slowest_time_constant_s(params, 0.0), slowest_time_constant_s(params, amplitude_V / math.sqrt(2)))
    return RigSettleTimes(tau, max(3.0, static_factor * tau), max(2.0, factor * tau), max(5.0, factor * tau),
                          factor)


def rig_sine_settle_s(params: MembraneParameters, frequencies_Hz: Sequence[float], settle: RigSettleTimes,
                      amplitude_V: float = 2500.0) -> dict:
    """{frequency (Hz): settle (s)}: ``settle.sine_settle_s``, or ``settle.factor`` x the slowest time constant
    of the stable periodic orbits of the ``amplitude_V`` sine there where that is longer (module docstring;
    where none is stable, the rest's hold: such a record does not settle on an orbit)."""
    freqs = [float(f) for f in frequencies_Hz]
    orbit = orbit_time_constants(params, SinePeriodic(amplitude_V, 1.0), freqs, stable_only=True) if freqs else {}
    taus = {f: orbit.get(round(f, 3), 0.0) for f in freqs}
    return {f: max(settle.sine_settle_s, settle.factor * tau) if math.isfinite(tau) else settle.sine_settle_s
            for f, tau in taus.items()}       # inf: no stable orbit there (the rest's hold)


def rig_protocol(params: MembraneParameters, frequencies_Hz: Sequence[float], settle: RigSettleTimes | None = None,
                 amplitude_V: float = 2500.0, staircase_V: Sequence[float] = (0, 2000, 2100, 2200, 2300, 2400, 2500),
                 step_V: float = 2200.0, step_hold_s: float = 4.0, sine_measure_s: float = 2.0,
                 orbit_holds: bool = True) -> Protocol:
    """The identification protocol a user would run on ``params`` (paper's experiments, the module's settle
    times): staircase (1 s measured per level), rest, a step from 0 V, |U sin| at ``frequencies_Hz`` ascending
    (``sine_measure_s`` measured, two periods at least). ``orbit_holds=False``: every sine held
    ``settle.sine_settle_s`` (the rule before session 22: a record near a fold may be measured settling)."""
    s = settle or rig_settle_times(params, amplitude_V)
    freqs = sorted(float(f) for f in frequencies_Hz)
    # a frequency with fewer than 1.5 periods in sine_measure_s gets two periods (its own segment): one period
    # is cut below a period by the extraction's guard at the window's end
    slow = [f for f in freqs if f * sine_measure_s < 1.5]
    settle_s = (rig_sine_settle_s(params, freqs, s, amplitude_V) if orbit_holds
                else dict.fromkeys(freqs, s.sine_settle_s))
    sines: list = []
    for f in freqs:             # ascending; consecutive frequencies with the same hold share a segment
        measure = 2.0 / min(slow) if f in slow else float(sine_measure_s)
        if sines and (sines[-1]["settle_s"], sines[-1]["measure_s"]) == (settle_s[f], measure):
            sines[-1]["frequencies_Hz"].append(f)
        else:
            sines.append({"kind": "sine", "amplitude_V": float(amplitude_V), "frequencies_Hz": [f],
                          "settle_s": settle_s[f], "measure_s": measure})
    return Protocol.from_dict({"name": "rig_synth", "membrane": params.name, "mass_kg": params.mass_kg, "segments": [
        {"kind": "static", "voltages_V": [float(v) for v in staircase_V], "hold_s": s.static_hold_s, "measure_s": 1.0},
        {"kind": "rest", "hold_s": s.rest_s},
        {"kind": "step", "initial_V": 0.0, "final_V": float(step_V), "pre_s": 0.5, "hold_s": float(step_hold_s)},
        *sines, {"kind": "rest", "hold_s": 0.5}]}, source="rig_synth")


def _held_voltages(segments: list, tv: np.ndarray, shifts: dict) -> np.ndarray:
    out = np.zeros(tv.size)
    k = 0
    for i, t in enumerate(tv):
        k = segment_at(segments, t, k)
        if k < len(segments):
            out[i] = segments[k].voltage_at(t + shifts.get(k, 0.0))
    return out


def record_protocol(params: MembraneParameters, protocol: Protocol, seed: int = 0, noise_m: float = 1e-6,
                    quantisation_m: float = 0.0, update_rate_Hz: float = 500.0,
                    random_start_phase: bool = True, rtol: float = 1e-10) -> RigRecording:
    """The run of ``protocol`` on the membrane ``params`` from rest (module docstring). ``quantisation_m``: the
    laser's resolution (m; ``sim.plant.LASER_QUANTISATION_M`` for the ILD1320-10, 0: none)."""
    rng = np.random.default_rng(seed)
    segments = protocol.schedule()
    period = 1.0 / float(update_rate_Hz)
    tv = np.arange(int(math.floor(segments[-1].end_s * update_rate_Hz + 1e-9))) * period
    shifts = {s.index: float(rng.uniform(0.0, 1.0)) / s.info["frequency_Hz"] for s in segments
              if s.kind == "sine"} if random_start_phase else {}
    uv = _held_voltages(segments, tv, shifts)
    x0 = np.asarray(static_equilibrium(params, 0.0).state, float).reshape(3)     # at rest, 0 V
    wall = 0.0
    for tol in (rtol, rtol / 10, rtol / 100):     # tightened until halving it moves d by < 1e-3 of the noise
        run = simulate_held(params, uv, period, x0=x0, rtol=tol, atol_scale=tol)
        half = simulate_held(params, uv, period, x0=x0, rtol=tol / 2, atol_scale=tol / 2)
        wall += run.wall_time_s + half.wall_time_s
        check = float(np.max(np.abs(run.displacement_m - half.displacement_m)))
        if check <= 1e-3 * max(noise_m, 1e-6):
            break
    else:
        raise IntegrationError(f"held-voltage run not converged: at rtol {tol:g} halving the tolerance moves d by "
                               f"{check:.3g} m")
    d_true = run.displacement_m[:-1]
    laser = LaserReadings(float(noise_m), float(quantisation_m), rng)
    return RigRecording(tv, uv, d_true, laser.read(d_true), segments, shifts, check, wall)


@dataclass(frozen=True)
class RecordedPass:
    """One pass of a rig run for :func:`passes_experiments`: its protocol, its recording (times from its own
    start), its start after the first pass's (s; the time at 0 V between them is not recorded) and what its
    metadata record adds (a planned pass's plan, :meth:`~.adaptive.SecondPass.record_extra`)."""

    protocol: Protocol
    recording: RigRecording
    start_s: float = 0.0
    extra: dict | None = None


def rig_experiments(params: MembraneParameters, protocol: Protocol, seed: int = 0, noise_m: float = 1e-6,
                    quantisation_m: float = 0.0, update_rate_Hz: float = 500.0,
                    other_masses_kg: Sequence[float] = (), static_samples: int = 100,
                    random_start_phase: bool = True) -> tuple:
    """(ExperimentSet, RigRecording): the run of :func:`record_protocol` cut by the bag extraction, the
    membrane's geometry attached (no base parameters: identification starts as for a manifest). Static points
    at ``other_masses_kg`` (0 V, equilibrium + the mean of ``static_samples`` laser readings: a mass swap, not
    part of the held run) are added to the staircase's."""
    rec = record_protocol(params, protocol, seed, noise_m, quantisation_m, update_rate_Hz, random_start_phase)
    exp = passes_experiments(params, [RecordedPass(protocol, rec)], seed, noise_m, quantisation_m, update_rate_Hz,
                             other_masses_kg, static_samples)
    return exp, rec


def passes_experiments(params: MembraneParameters, passes: Sequence[RecordedPass], seed: int = 0,
                       noise_m: float = 1e-6, quantisation_m: float = 0.0, update_rate_Hz: float = 500.0,
                       other_masses_kg: Sequence[float] = (), static_samples: int = 100):
    """The ExperimentSet of one or more recorded passes (an adaptive protocol's two) as the bag extraction
    cuts them -- each pass's schedule in its own metadata record with its own t0, as identifier_node writes
    them -- with :func:`rig_experiments`' geometry and the static points at ``other_masses_kg`` (their noise
    drawn from ``seed``)."""
    times, volts, disp, meta = [], [], [], {}
    for number, one in enumerate(passes, 1):
        rec = one.recording
        t0_ns = T0_NS + int(round(one.start_s * 1e9))
        times.append(rec.time_s + t0_ns * 1e-9)
        volts.append(rec.voltage_V)
        disp.append(rec.displacement_measured_m)
        meta[pass_metadata_name(number)] = experiment_record(one.protocol, rec.segments, t0_ns, len(rec.segments),
                                                             False, float(update_rate_Hz), params.name, number,
                                                             one.extra)
    t = np.concatenate(times)
    signals = BagSignals(t, np.concatenate(volts), t.copy(), np.concatenate(disp), meta)
    exp = experiments_from_signals(signals, f"rig_synth[{params.name}, seed {seed}]", membrane="A2")
    static = list(exp.static)
    others = [m for m in other_masses_kg if abs(m - params.mass_kg) > 1e-9]
    if others:
        rng = np.random.default_rng([seed, 1])
        static.append(static_points(params, LaserReadings(float(noise_m), float(quantisation_m), rng), others, (),
                                    static_samples))
    return dataclasses.replace(exp, membrane=params.name, geometry={k: getattr(params, k) for k in GEOMETRY_FIELDS},
                               static=static, base_parameters=None, base_reference=None)
