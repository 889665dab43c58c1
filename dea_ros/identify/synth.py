"""Synthetic experiment sets: what the rig would record for a known parameter set, with laser noise.

:func:`synthesize` reproduces the paper's protocol (sections IV-B and IV-C):

* static points: masses 0-5 g in 1 g steps at 0 V (the paper uses 0 and 3 g; a lab with a set
  of screws would use a few more), and 2.0-2.5 kV in 0.1 kV steps with the dynamic mass
  (3 g). Each static point is the mean of ``static_samples`` laser samples (default 100,
  0.1 s at 1 kHz), so its noise is sigma / sqrt(static_samples).
* a 2.2 kV voltage step sampled at 1 kHz: ``step_time_s`` (0.2 s) of baseline at 0 V, then
  ``step_duration_s`` (4 s) after the step. The voltage column is the commanded voltage
  (zero-order hold, as the DAQ outputs it).
* sines of 2.5 kV amplitude across 0.2-40 Hz, visited in ascending order as a slow upward sweep
  on the rig: at each frequency the response the rig settles on, sampled at 1 kHz over the
  whole excitation periods covering at least ``sine_record_s`` (floor(n T f_s) samples), noise
  added to every sample. The RMS of eq. 21 (and its standard uncertainty, written as
  d_rms_std_m) is computed from the noisy samples exactly as for a measured record
  (:func:`~dea_ros.identify.experiments.rms_statistics`: whole periods with interpolated
  boundaries, laser noise removed) around the rest position d0 measured (also with noise) as
  the mean of ``baseline_samples`` samples at 0 V. Sampled records are written for
  ``series_frequencies_Hz`` (the paper's 2 and 12.5 Hz validation records; "all" for every
  frequency). ``waveform``: the applied voltage, ``"sine"`` (U sin wt, the paper) or
  ``"abs_sine"`` (|U sin wt|, what the rig's unipolar amplifier applies; same u^2).

Accuracy: every response comes from the accurate adaptive integrator (DOP853), never from the
solvers the fit uses (collocation for the step, harmonic balance for the sines): the step by
:func:`~dea_ros.solvers.integrate.simulate` (rtol 1e-10). For the sines, to avoid integrating
through the slow viscoelastic transient, the periodic orbit (of period T: the T/2 orbit or a
period-doubled one) is found by single shooting on DOP853
(:func:`~dea_ros.solvers.steady_state.shoot_periodic_orbit`, rtol 1e-10), started from the
orbit a harmonic-balance sweep of the true parameters says the rig settles on (the upward-sweep
branch: period-doubled in a period-doubling band); its Floquet multipliers are checked (stable).
It agrees with brute-force integration to steady state to < 0.01 nm. Where no periodic orbit is
stable (a torus band) the motion is integrated (100 periods to settle, then the record with
DOP853) and recorded as it is: quasi-periodic. If shooting fails, brute-force integration from
rest over two excitation periods is used (slow, but only there).

The true parameters are written to ``truth.yaml`` next to the manifest, which does not
reference it: identification never reads it.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers.sweep import frequency_sweep
from ..solvers.inputs import PeriodicInput, SinePeriodic, SineVoltage, StepVoltage
from ..solvers.integrate import simulate
from ..solvers.realised import SETTLE_PERIODS, realised_response
from ..solvers.steady_state import SteadyStateError, integrate_to_steady_state, shoot_periodic_orbit
from .experiments import (
    GEOMETRY_FIELDS,
    WAVEFORMS,
    ExperimentSet,
    SineData,
    SineSeries,
    StaticData,
    StepData,
    rms_statistics,
    write_experiment_set,
)

__all__ = [
    "synthesize",
    "synthesize_experiments",
    "DEFAULT_STATIC_MASSES_KG",
    "DEFAULT_STATIC_VOLTAGES_V",
    "DEFAULT_SINE_FREQUENCIES_HZ",
    "DEFAULT_SERIES_FREQUENCIES_HZ",
    "LaserReadings",
    "static_points",
]

DEFAULT_STATIC_MASSES_KG = (0.0, 0.001, 0.002, 0.003, 0.004, 0.005)
DEFAULT_STATIC_VOLTAGES_V = (2000.0, 2100.0, 2200.0, 2300.0, 2400.0, 2500.0)
DEFAULT_SINE_FREQUENCIES_HZ = (
    0.2, 0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 7.5, 8.0, 8.3, 8.6, 8.9, 9.2, 9.5, 9.8, 10.1,
    10.5, 11.2, 12.5, 14.0, 16.0, 25.0, 30.0, 40.0,
)
DEFAULT_SERIES_FREQUENCIES_HZ = (2.0, 12.5)


@dataclass(frozen=True)
class _SineOverPeriods(PeriodicInput):
    """A sine seen as periodic over ``periods`` excitation periods (for period-doubled responses)."""

    amplitude_V: float
    sine_frequency_Hz: float
    periods: int

    @property
    def frequency_Hz(self) -> float:  # type: ignore[override]
        return self.sine_frequency_Hz / self.periods

    def at_phase(self, theta):
        return self.amplitude_V * np.sin(self.periods * np.asarray(theta, float))

    def with_frequency(self, frequency_Hz: float):
        return _SineOverPeriods(self.amplitude_V, frequency_Hz * self.periods, self.periods)

    def u2_half_periodic(self, samples: int = 64) -> bool:
        return False


def _record(params: MembraneParameters, amplitude_V: float, frequency_Hz: float, response, seed_solution,
            ts: np.ndarray) -> tuple[np.ndarray, str]:
    """True displacement at the sample times ``ts`` (from 0 at phase 0 of the sine) and its kind."""
    sine = SinePeriodic(amplitude_V, frequency_Hz)
    if response.kind != "quasi-periodic" and seed_solution is not None:
        try:
            orbit = shoot_periodic_orbit(params, sine, seed_solution.evaluate(0.0)[:, 0])
            if orbit.stable:
                return orbit.evaluate(ts)[0], ("period-doubled" if orbit.odd_harmonic_ratio() > 1e-3
                                               else "periodic")
        except SteadyStateError:
            pass
    if seed_solution is not None:  # no stable periodic orbit: settle on the attractor, then record
        d0 = float(static_equilibrium(params, 0.0).displacement_m)
        x0 = seed_solution.evaluate(0.0)[:, 0] * np.array([1.001, 1.0, 1.0])
        settled = realised_response(params, sine, x0, d0, settle_periods=SETTLE_PERIODS, window_periods=1)
        period = 1.0 / frequency_Hz
        t_rec = settled.window_s[1]  # the integration ends a whole number of periods after phase 0
        start = float(np.ceil(t_rec / period - 1e-9)) * period
        resp = simulate(params, SineVoltage(amplitude_V, frequency_Hz), start + ts[-1] + 1e-9, t_eval=start + ts,
                        x0=settled.final_state, t_start_s=t_rec, rtol=1e-10, atol_scale=1e-10)
        return resp.displacement_m, "quasi-periodic"
    inp = _SineOverPeriods(amplitude_V, frequency_Hz, 2)
    sol = integrate_to_steady_state(params, inp, tol=1e-8, rtol=1e-10, samples_per_period=1025,
                                    max_time_s=1200.0)
    return sol.evaluate(ts)[0], "integrated from rest"


@functools.lru_cache(maxsize=8)
def _clean_step(params: MembraneParameters, step_voltage_V: float, step_time_s: float, step_duration_s: float,
                sample_rate_Hz: float):
    """(t, u, d) of the noise-free step record by adaptive integration (memoised: seeds share it)."""
    t_end = step_time_s + step_duration_s
    n = int(round(t_end * sample_rate_Hz)) + 1
    t = np.arange(n) / sample_rate_Hz
    signal = StepVoltage(step_voltage_V, step_time_s=step_time_s)
    response = simulate(params, signal, t[-1], t_eval=t, rtol=1e-10, atol_scale=1e-10)
    return t, np.asarray(signal(t), float), response.displacement_m


@functools.lru_cache(maxsize=8)
def _clean_sines(params: MembraneParameters, amplitude_V: float, frequencies_Hz: tuple, record_s: float,
                 sample_rate_Hz: float, offsets_s: tuple) -> list:
    """[(f, t, d, kind)] noise-free records of an upward sweep (module docstring; memoised); record k
    starts ``offsets_s[k]`` after phase 0 of its sine."""
    freqs = np.asarray(frequencies_Hz, float)
    sweep = frequency_sweep(params, SinePeriodic(amplitude_V, 1.0), freqs, n_harmonics=12)
    out = []
    for f, resp, offset in zip(freqs, sweep.responses, offsets_s):
        pts = [p for b in sweep.branches for p in b.points
               if abs(p.frequency_Hz - f) <= 1e-9 * f and (b.name == resp.branch or resp.branch == "integration")]
        seed_pt = None
        if pts:
            seed_pt = min(pts, key=lambda p: abs(p.d_rms_m - resp.d_rms_m)) if resp.branch != "integration" else \
                min(pts, key=lambda p: p.max_multiplier)
        period = 1.0 / f
        n_periods = max(1, math.ceil(record_s / period))
        n_samples = int(math.floor(n_periods * period * sample_rate_Hz + 1e-9))
        ts = offset + np.arange(n_samples) / sample_rate_Hz
        d_true, kind = _record(params, amplitude_V, float(f), resp,
                               seed_pt.solution if seed_pt is not None else None, ts)
        out.append((float(f), ts, d_true, kind))
    return out


def synthesize_experiments(
    params: MembraneParameters,
    noise_m: float,
    seed: int = 0,
    static_masses_kg: Sequence[float] = DEFAULT_STATIC_MASSES_KG,
    static_voltages_V: Sequence[float] = DEFAULT_STATIC_VOLTAGES_V,
    static_samples: int = 100,
    step_voltage_V: float = 2200.0,
    step_time_s: float = 0.2,
    step_duration_s: float = 4.0,
    sample_rate_Hz: float = 1000.0,
    sine_amplitude_V: float = 2500.0,
    sine_frequencies_Hz: Sequence[float] = DEFAULT_SINE_FREQUENCIES_HZ,
    series_frequencies_Hz: Sequence[float] = DEFAULT_SERIES_FREQUENCIES_HZ,
    sine_record_s: float = 2.0,
    baseline_samples: int = 1000,
    progress: Callable[[dict], None] | None = None,
    waveform: str = "sine",
    quantisation_m: float = 0.0,
    random_start_phase: bool = False,
) -> ExperimentSet:
    """The experiment set (in memory) the rig would record for ``params`` with laser noise ``noise_m``.

    See the module docstring for the protocol. ``noise_m`` is the standard
    deviation of the Gaussian laser noise on every displacement sample (m); ``quantisation_m``
    the laser's digital resolution (m; every sample, static points and rest positions included,
    is rounded to it after the noise: ``sim.plant.LASER_QUANTISATION_M`` for the ILD1320-10; 0:
    none). ``random_start_phase``: every sine record starts at a random phase of the excitation
    (its time axis stays that of the sine, u = U sin(2 pi f t)); otherwise at phase 0.
    """
    if not (math.isfinite(noise_m) and noise_m >= 0.0):
        raise ValueError(f"noise_m: must be >= 0 (metres), got {noise_m}")
    if noise_m > 1e-4:
        raise ValueError(f"noise_m: {noise_m} m is larger than the deflections; metres expected (1 um -> 1e-6)")
    rng = np.random.default_rng(seed)
    laser = LaserReadings(float(noise_m), float(quantisation_m), rng)
    static = static_points(params, laser, static_masses_kg, static_voltages_V, static_samples)
    if progress:
        progress({"stage": "synth", "what": "static", "points": static.n_points})
    # ---- step (eq. 23)
    t, u_step, d_step = _clean_step(params, float(step_voltage_V), float(step_time_s), float(step_duration_s),
                                    float(sample_rate_Hz))
    step = StepData(t, u_step, laser.read(d_step),
                    mass_kg=params.mass_kg, voltage_hold="zoh", source="synthetic step")
    if progress:
        progress({"stage": "synth", "what": "step", "samples": t.size})
    freqs = np.sort(np.asarray(sine_frequencies_Hz, float))
    if isinstance(series_frequencies_Hz, str):
        if series_frequencies_Hz != "all":
            raise ValueError(f"series_frequencies_Hz: a list of Hz or 'all', got {series_frequencies_Hz!r}")
        series_set = {round(float(f), 9) for f in freqs}
    else:
        series_set = {round(float(f), 9) for f in series_frequencies_Hz}
    if waveform not in WAVEFORMS:
        raise ValueError(f"waveform: one of {WAVEFORMS}, got {waveform!r}")
    offsets = tuple(rng.uniform(0.0, 1.0, freqs.size) / freqs) if random_start_phase else (0.0,) * freqs.size
    sines, kinds = _sines(params, laser, freqs, offsets, float(sine_amplitude_V), series_set, float(sine_record_s),
                          float(sample_rate_Hz), baseline_samples, waveform, progress)
    notes = (f"synthetic data from dea_ros.identify.synth: membrane {params.name}, laser noise "
             f"{noise_m:g} m, quantisation {quantisation_m:g} m, seed {seed}, waveform {waveform}"
             + (", random start phases" if random_start_phase else "")
             + "; true parameters in truth.yaml (not read by identify)")
    odd = [f"{f:g} Hz {k}" for f, k in zip(freqs, kinds) if k != "periodic"]
    if odd:
        notes += "; responses that are not periodic at T/2: " + ", ".join(odd)
    return ExperimentSet(
        membrane=params.name,
        geometry={k: getattr(params, k) for k in GEOMETRY_FIELDS},
        mass_kg=params.mass_kg,
        static=[static],
        steps=[step],
        sines=sines,
        sensor_noise_m=float(noise_m) if noise_m > 0 else None,
        notes=notes,
    )


class LaserReadings:
    """What the laser reads: Gaussian noise, then the digital resolution (m)."""

    def __init__(self, noise_m: float, quantisation_m: float, rng):
        self.noise_m, self.quantisation_m, self.rng = noise_m, quantisation_m, rng

    def read(self, d_m) -> np.ndarray:
        d = np.asarray(d_m, float) + self.rng.normal(0.0, self.noise_m, np.shape(d_m))
        return np.round(d / self.quantisation_m) * self.quantisation_m if self.quantisation_m > 0 else d

    def mean_of(self, d_m: float, samples: int) -> float:
        """The mean of ``samples`` readings of the constant ``d_m``."""
        if self.quantisation_m > 0:
            return float(np.mean(self.read(np.full(samples, d_m))))
        return float(d_m + self.rng.normal(0.0, self.noise_m / math.sqrt(samples)))


def static_points(params: MembraneParameters, laser: LaserReadings, masses_kg, voltages_V,
                  samples: int) -> StaticData:
    """Static points (eq. 20): every mass at 0 V, every voltage at the dynamic mass; means of ``samples``."""
    masses, volts, disp = [], [], []
    for m in masses_kg:
        masses.append(float(m))
        volts.append(0.0)
        disp.append(float(static_equilibrium(params, 0.0, mass_kg=float(m)).displacement_m))
    eq_d = static_equilibrium(params, np.asarray(voltages_V, float)).displacement_m if len(voltages_V) else ()
    for u, d in zip(voltages_V, np.atleast_1d(eq_d)):
        masses.append(float(params.mass_kg))
        volts.append(float(u))
        disp.append(float(d))
    disp = np.array([laser.mean_of(d, samples) for d in disp])
    per_sample = math.hypot(laser.noise_m, laser.quantisation_m / math.sqrt(12.0))
    std = np.full(disp.size, per_sample / math.sqrt(samples)) if per_sample > 0 else None
    return StaticData(np.asarray(masses), np.asarray(volts), disp, source="synthetic static", std_error_m=std)


def _sines(params: MembraneParameters, laser: LaserReadings, freqs: np.ndarray, offsets: tuple, amplitude_V: float,
           series_set: set, record_s: float, sample_rate_Hz: float, baseline_samples: int, waveform: str,
           progress) -> tuple:
    """([SineData] of an upward sweep on the rig (eqs. 21, 24), the response kind per frequency)."""
    d_rest = float(static_equilibrium(params, 0.0).displacement_m)
    rms, d0s, stds, series, kinds = [], [], [], [], []
    noise_m = laser.noise_m
    clean = _clean_sines(params, amplitude_V, tuple(float(f) for f in freqs), record_s,
                         sample_rate_Hz, offsets) if freqs.size else []
    for f, ts, d_true, kind in clean:
        d_noisy = laser.read(d_true)
        d0 = float(np.mean(laser.read(np.full(baseline_samples, d_rest))))   # the mean of the baseline samples
        u = amplitude_V * np.sin(2 * np.pi * f * ts)
        if waveform == "abs_sine":
            u = np.abs(u)
        record = SineSeries(float(f), ts, u, d_noisy, source=f"synthetic sine {f:g} Hz")
        # eq. 21 about the measured baseline d0, which the record states and the fit takes the model's RMS
        # about too (FrequencyPoint.rest_d0_m): d0's error cancels, its uncertainty is not counted
        value, std = rms_statistics(record, d0, noise_m if noise_m > 0 else None)
        rms.append(value)
        d0s.append(d0)
        stds.append(std if std is not None else 1e-12)
        kinds.append(kind)
        if round(float(f), 9) in series_set:
            series.append(record)
        if progress:
            progress({"stage": "synth", "what": "sine", "frequency_Hz": float(f), "kind": kind,
                      "rms_um": rms[-1] * 1e6})
    sines = [SineData(freqs, np.full(freqs.size, amplitude_V), np.asarray(rms), mass_kg=params.mass_kg,
                      d0_m=np.asarray(d0s), series=tuple(series), source="synthetic sines",
                      d_rms_std_m=np.asarray(stds), waveform=waveform)] if freqs.size else []
    return sines, kinds


def synthesize(
    params: MembraneParameters,
    noise_m: float,
    out_dir: str | Path,
    seed: int = 0,
    **options,
) -> ExperimentSet:
    """Generate a synthetic experiment set and write it to ``out_dir`` (manifest, CSVs, truth.yaml).

    ``options`` are those of :func:`synthesize_experiments`. Returns the set as loaded in memory.
    """
    exp = synthesize_experiments(params, noise_m, seed=seed, **options)
    out = Path(out_dir)
    write_experiment_set(exp, out)
    params.to_yaml(out / "truth.yaml",
                   header=f"true parameters of the synthetic data set (noise {noise_m:g} m, seed {seed}); "
                          "not referenced by manifest.yaml")
    return exp
