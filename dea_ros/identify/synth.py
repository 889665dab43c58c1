"""Synthetic experiment sets: what the rig would record for a known parameter set, with laser noise.

:func:`synthesize` reproduces the paper's protocol (sections IV-B and IV-C):

* static points: masses 0-5 g in 1 g steps at 0 V (the paper uses 0 and 3 g; a lab with a set
  of screws would use a few more), and 2.0-2.5 kV in 0.1 kV steps with the dynamic mass
  (3 g). Each static point is the mean of ``static_samples`` laser samples (default 100,
  0.1 s at 1 kHz), so its noise is sigma / sqrt(static_samples).
* a 2.2 kV voltage step sampled at 1 kHz: ``step_time_s`` (0.2 s) of baseline at 0 V, then
  ``step_duration_s`` (4 s) after the step. The voltage column is the commanded voltage
  (zero-order hold, as the DAQ outputs it).
* sines of 2.5 kV amplitude across 0.2-40 Hz: the periodic steady state, sampled at 1 kHz over
  a whole number of periods (at least ``sine_record_s``), noise added to every sample, and the
  RMS of eq. 21 computed from the noisy samples around the rest position d0 measured (also
  with noise) as the mean of ``baseline_samples`` samples at 0 V. The standard uncertainty of
  each RMS value (sample noise and baseline error, linearised) is written as d_rms_std_m.
  Sampled records are written for ``series_frequencies_Hz`` (the paper's 2 and 12.5 Hz
  validation records).

Accuracy: the responses come from the accurate adaptive integrator (DOP853), never from the
solvers the fit uses (collocation for the step, harmonic balance for the sines): the step by
:func:`~dea_ros.solvers.integrate.simulate` (rtol 1e-10). For the sines, to avoid integrating
through the slow viscoelastic transient (eta1/k1 up to ~24 s), the periodic orbit is found by
single shooting on DOP853 (rtol 1e-10; Newton on the one-period flow map with the monodromy
matrix from the variational equations), started from a harmonic-balance guess; its Floquet
multipliers are checked. It agrees with brute-force integration to steady state to < 0.01 nm.
Where the orbit is unstable (folds, the parametric resonance near twice the resonance) or
shooting fails, the response is integrated from rest until it is periodic over two excitation
periods (so a period-doubled response, as the rig would show, converges too): slow, but only
there.

The true parameters are written to ``truth.yaml`` next to the manifest, which does not
reference it: identification never reads it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters
from ..solvers.harmonic_balance import HarmonicBalanceError, solve_native
from ..solvers.inputs import PeriodicInput, SinePeriodic, StepVoltage
from ..model.dynamics import DEAModel
from ..solvers.integrate import simulate, state_scale
from scipy.integrate import solve_ivp
from ..solvers.steady_state import SteadyStateError, integrate_to_steady_state
from .experiments import (
    GEOMETRY_FIELDS,
    ExperimentSet,
    SineData,
    SineSeries,
    StaticData,
    StepData,
    write_experiment_set,
)

__all__ = [
    "synthesize",
    "synthesize_experiments",
    "DEFAULT_STATIC_MASSES_KG",
    "DEFAULT_STATIC_VOLTAGES_V",
    "DEFAULT_SINE_FREQUENCIES_HZ",
    "DEFAULT_SERIES_FREQUENCIES_HZ",
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


@dataclass
class _Orbit:
    """A periodic orbit from the accurate integrator: dense output over one period."""

    period_s: float
    dense: Callable
    multipliers: np.ndarray

    def evaluate(self, t_s) -> np.ndarray:
        return self.dense(np.mod(np.asarray(t_s, float), self.period_s))


def _shooting(params: MembraneParameters, amplitude_V: float, frequency_Hz: float, x0: np.ndarray,
              rtol: float = 1e-10, tol: float = 1e-10, max_iter: int = 8) -> _Orbit:
    """Periodic orbit by single shooting on the accurate integrator (DOP853).

    Newton on P(x0) = x0, P the one-period flow map, with the monodromy matrix from the
    variational equations (analytic df/dx) integrated alongside. Converged when the
    scaled mismatch |P(x0) - x0| is below ``tol``; the Floquet multipliers are the
    eigenvalues of the monodromy matrix.
    """
    model = DEAModel.from_parameters(params)
    period = 1.0 / frequency_Hz
    omega = 2.0 * np.pi * frequency_Hz
    scale = state_scale(params)
    atol = np.r_[1e-12 * scale, np.full(9, 1e-12)]

    def fun(t, y):
        u = amplitude_V * np.sin(omega * t)
        x = y[:3]
        f = model.rhs(x, u)
        a = model.jacobian(x, u)
        return np.r_[f, (a @ y[3:].reshape(3, 3)).reshape(-1)]

    x = np.asarray(x0, float).copy()
    for _ in range(max_iter):
        sol = solve_ivp(fun, (0.0, period), np.r_[x, np.eye(3).reshape(-1)], method="DOP853",
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise SteadyStateError(f"shooting integration failed at {frequency_Hz:g} Hz: {sol.message}")
        end = sol.y[:3, -1]
        mono = sol.y[3:, -1].reshape(3, 3)
        mismatch = end - x
        if np.max(np.abs(mismatch / scale)) < tol:
            break
        x = x - np.linalg.solve(mono - np.eye(3), mismatch)
    else:
        raise SteadyStateError(f"shooting did not converge at {frequency_Hz:g} Hz "
                               f"(mismatch {np.max(np.abs(mismatch / scale)):.3g} scaled)")
    dense = solve_ivp(lambda t, y: model.rhs(y, amplitude_V * np.sin(omega * t)), (0.0, period), x,
                      method="DOP853", rtol=rtol, atol=1e-12 * scale, dense_output=True).sol
    return _Orbit(period, dense, np.linalg.eigvals(mono))


def _steady_state(params: MembraneParameters, amplitude_V: float, frequency_Hz: float, hb_guess):
    """Accurate periodic steady state (see the module docstring).

    Returns (orbit, periods, hb_state): the orbit has period ``periods`` / f.
    """
    sine = SinePeriodic(amplitude_V, frequency_Hz)
    hb_state = None
    try:
        hb = solve_native(params, sine, n_harmonics=12, x_guess=hb_guess, stability=False)
        hb_state = hb.state
        orbit = _shooting(params, amplitude_V, frequency_Hz, hb.evaluate(0.0)[:, 0])
        if np.max(np.abs(orbit.multipliers)) < 1.0:
            return orbit, 1, hb_state
    except (HarmonicBalanceError, SteadyStateError):
        pass
    # Unstable or unknown orbit: brute-force integration from rest over two excitation periods
    # (a period-doubled response converges too).
    inp = _SineOverPeriods(amplitude_V, frequency_Hz, 2)
    sol = integrate_to_steady_state(params, inp, tol=1e-8, rtol=1e-10, samples_per_period=1025,
                                    max_time_s=1200.0)
    return sol, 2, hb_state


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
) -> ExperimentSet:
    """The experiment set (in memory) the rig would record for ``params`` with laser noise ``noise_m``.

    See the module docstring for the protocol. ``noise_m`` is the standard
    deviation of the Gaussian laser noise on every displacement sample (m).
    """
    if not (math.isfinite(noise_m) and noise_m >= 0.0):
        raise ValueError(f"noise_m: must be >= 0 (metres), got {noise_m}")
    if noise_m > 1e-4:
        raise ValueError(f"noise_m: {noise_m} m is larger than the deflections; metres expected (1 um -> 1e-6)")
    rng = np.random.default_rng(seed)
    mass = params.mass_kg
    # ---- static points (eq. 20)
    masses, volts, disp = [], [], []
    for m in static_masses_kg:
        masses.append(float(m))
        volts.append(0.0)
        disp.append(float(static_equilibrium(params, 0.0, mass_kg=float(m)).displacement_m))
    eq_v = static_equilibrium(params, np.asarray(static_voltages_V, float))
    for u, d in zip(static_voltages_V, np.atleast_1d(eq_v.displacement_m)):
        masses.append(float(mass))
        volts.append(float(u))
        disp.append(float(d))
    disp = np.asarray(disp) + rng.normal(0.0, noise_m / math.sqrt(static_samples), len(disp))
    static = StaticData(np.asarray(masses), np.asarray(volts), disp, source="synthetic static")
    if progress:
        progress({"stage": "synth", "what": "static", "points": static.n_points})
    # ---- step (eq. 23)
    t_end = step_time_s + step_duration_s
    n = int(round(t_end * sample_rate_Hz)) + 1
    t = np.arange(n) / sample_rate_Hz
    step_signal = StepVoltage(step_voltage_V, step_time_s=step_time_s)
    response = simulate(params, step_signal, t[-1], t_eval=t, rtol=1e-10, atol_scale=1e-10)
    step = StepData(t, np.asarray(step_signal(t), float),
                    response.displacement_m + rng.normal(0.0, noise_m, n),
                    mass_kg=mass, voltage_hold="zoh", source="synthetic step")
    if progress:
        progress({"stage": "synth", "what": "step", "samples": n})
    # ---- sines (eqs. 21, 24)
    d_rest = float(static_equilibrium(params, 0.0).displacement_m)
    freqs = np.sort(np.asarray(sine_frequencies_Hz, float))
    series_set = {round(float(f), 9) for f in series_frequencies_Hz}
    rms, d0s, stds, series = [], [], [], []
    guess = None
    for f in freqs:
        sol, periods, guess_new = _steady_state(params, sine_amplitude_V, float(f), guess)
        guess = guess_new if guess_new is not None else None
        period = periods / f
        n_periods = max(1, math.ceil(sine_record_s / period))
        n_samples = int(math.floor(n_periods * period * sample_rate_Hz + 1e-9))
        ts = np.arange(n_samples) / sample_rate_Hz
        d_true = sol.evaluate(ts)[0]
        d_noisy = d_true + rng.normal(0.0, noise_m, n_samples)
        d0 = d_rest + float(np.mean(rng.normal(0.0, noise_m, baseline_samples)))
        dev = d_noisy - d0
        rms.append(float(np.sqrt(np.mean(dev**2))))                        # eq. 21
        d0s.append(d0)
        # standard uncertainty of that RMS: sample noise averaged over n_samples, and the
        # baseline error of d0 (linearised: var(rms^2) / (2 rms)^2)
        stds.append(float(noise_m * math.sqrt(1.0 / n_samples + (np.mean(dev) / rms[-1]) ** 2 / baseline_samples))
                    if noise_m > 0 else 1e-12)
        if round(float(f), 9) in series_set:
            series.append(SineSeries(float(f), ts, sine_amplitude_V * np.sin(2 * np.pi * f * ts), d_noisy,
                                     source=f"synthetic sine {f:g} Hz"))
        if progress:
            progress({"stage": "synth", "what": "sine", "frequency_Hz": float(f), "periods": periods,
                      "rms_um": rms[-1] * 1e6})
    sines = [SineData(freqs, np.full(freqs.size, float(sine_amplitude_V)), np.asarray(rms), mass_kg=mass,
                      d0_m=np.asarray(d0s), series=tuple(series), source="synthetic sines",
                      d_rms_std_m=np.asarray(stds))] if freqs.size else []
    return ExperimentSet(
        membrane=params.name,
        geometry={k: getattr(params, k) for k in GEOMETRY_FIELDS},
        mass_kg=mass,
        static=[static],
        steps=[step],
        sines=sines,
        sensor_noise_m=float(noise_m) if noise_m > 0 else None,
        notes=(f"synthetic data from dea_ros.identify.synth: membrane {params.name}, laser noise "
               f"{noise_m:g} m, seed {seed}; true parameters in truth.yaml (not read by identify)"),
    )


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
