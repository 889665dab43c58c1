"""Uncertainty of the identified model: a confidence band on the frequency response and the peak.

Monte Carlo over the identification's linearised covariance
(:meth:`~dea_ros.identify.metrics.ParameterStatistics.covariance`): parameter vectors are drawn
from the normal distribution of the fit's coordinates (ln k1, ln eta1, ln eta2, eps_r and the
stress combinations sigma_h(1), sigma_h'(1)[, sigma_h''(1), sigma_h'''(1)[, the fourth and fifth derivatives]] of
eq. 10, whichever
the final fit had), mapped to membranes (the stress combinations through the Ogden
representation closest to the identified beta/gamma, as the joint fit writes them). For each
sample the frequency response is one batched harmonic-balance solve over the grid
(:func:`~dea_ros.solvers.newton.solve_native_batch`) started from the identified
model's solutions of a continuation sweep (the T/2 branch a slow upward sweep follows), and its
resonance peak is located on the branch by a short continuation sweep around the identified
peak (:func:`~dea_ros.solvers.sweep.frequency_sweep`, without the Floquet analysis). The
band at each frequency is the central ``confidence`` interval of the samples; the peak gets the
same interval for its frequency and its RMS.

The default 48 samples cost 48 batched solves and 48 short sweeps (~0.2 s each on one core
today); the samples go out in batches, on an :class:`~dea_ros.study.engine.Engine` when one is
given. A sample that is not a valid membrane or whose solve fails is counted and left out
(``n_failed``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model.equilibrium import static_equilibrium
from ..model.parameters import MembraneParameters, ParameterError
from ..solvers.sweep import frequency_sweep
from ..errors import HarmonicBalanceError
from ..solvers.newton import solve_native_batch
from ..solvers.inputs import SinePeriodic
from .experiments import ExperimentSet
from .metrics import ParameterStatistics
from .static_fit import SHAPE_COMBINATION_MATRIX, STRESS_NAMES, OgdenRepresentation

__all__ = ["ResponseBand", "sample_parameters", "response_band", "response_bands", "DEFAULT_SAMPLES",
           "BAND_POINTS"]

#: Monte Carlo samples by default (``dea-ros identify --uncertainty-samples``): the 2.5/97.5 % quantiles of
#: 48 samples bound the band to within ~+-30 % of its width, enough to see where the model is unsure.
DEFAULT_SAMPLES = 48
_FIELDS = {"eps_r": "relative_permittivity", "k1_Pa": "k1_Pa", "eta1_Pa_s": "eta1_Pa_s", "eta2_Pa_s": "eta2_Pa_s"}
_BATCH = 16
#: Frequencies of a confidence band: over the range of a sine data set, and as many again within
#: +-15 % of the model's resonance peak (where the band is widest).
BAND_POINTS = 40


@dataclass
class ResponseBand:
    """The frequency-response band of one excitation (module docstring). SI units."""

    amplitude_V: float
    mass_kg: float
    frequencies_Hz: np.ndarray
    nominal_m: np.ndarray          # d_rms (eq. 21) of the identified model
    lower_m: np.ndarray            # band edges at ``confidence``
    upper_m: np.ndarray
    peak_frequency_Hz: float       # of the identified model
    peak_d_rms_m: float
    peak_frequency_ci_Hz: tuple
    peak_d_rms_ci_m: tuple
    samples: int                   # successful samples
    n_failed: int
    confidence: float
    parameters: tuple              # the fitted parameters that were varied
    seed: int
    sample_peaks_Hz: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    sample_curves_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    offset_V: float = 0.0          # of the excitation u = offset + U sin (0: |U sin| or U sin)

    def contains(self, frequencies_Hz, d_rms_m, slack: float = 0.0) -> np.ndarray:
        """Per frequency: whether ``d_rms_m`` (on this band's frequencies) lies in the band (+- slack x width)."""
        d = np.asarray(d_rms_m, float)
        width = self.upper_m - self.lower_m
        return (d >= self.lower_m - slack * width) & (d <= self.upper_m + slack * width)

    def to_dict(self) -> dict:
        return {"amplitude_V": self.amplitude_V, **({"offset_V": self.offset_V} if self.offset_V else {}),
                "mass_kg": self.mass_kg, "confidence": self.confidence,
                "samples": self.samples, "failed_samples": self.n_failed, "parameters": list(self.parameters),
                "seed": self.seed, "peak_frequency_Hz": self.peak_frequency_Hz,
                "peak_frequency_ci_Hz": list(self.peak_frequency_ci_Hz), "peak_d_rms_m": self.peak_d_rms_m,
                "peak_d_rms_ci_m": list(self.peak_d_rms_ci_m),
                "max_relative_half_width": float(np.nanmax(0.5 * (self.upper_m - self.lower_m)
                                                           / np.where(self.nominal_m > 0, self.nominal_m, np.nan)))
                if self.nominal_m.size else None,
                "frequencies_Hz": [float(x) for x in self.frequencies_Hz],
                "nominal_m": [float(x) for x in self.nominal_m], "lower_m": [float(x) for x in self.lower_m],
                "upper_m": [float(x) for x in self.upper_m]}


def _apply(params: MembraneParameters, names, delta, is_log) -> MembraneParameters:
    """``params`` moved by ``delta`` in the fit's coordinates of ``names``."""
    changes = {}
    bg = np.r_[params.beta_Pa, params.gamma_Pa]
    combos = SHAPE_COMBINATION_MATRIX @ bg
    moved = []
    for name, dx, lg in zip(names, delta, is_log):
        if name in STRESS_NAMES:
            moved.append(STRESS_NAMES.index(name))
            combos[moved[-1]] += dx
        elif name in _FIELDS:
            key = _FIELDS[name]
            value = getattr(params, key)
            changes[key] = float(value * math.exp(dx)) if lg else float(value + dx)
    if moved:
        # four combinations, the rest of the shape held at params' (as the fit held it); six where it fitted them
        n = 6 if max(moved) >= 4 else 4
        rep = OgdenRepresentation(params.prestretch, n, bg, matrix=SHAPE_COMBINATION_MATRIX[:n])
        new = rep.beta_gamma(combos[:n])
        changes["beta_Pa"] = tuple(float(v) for v in new[:3])
        changes["gamma_Pa"] = tuple(float(v) for v in new[3:])
    return params.replace(**changes)


def sample_parameters(params: MembraneParameters, statistics: ParameterStatistics, n: int, seed: int = 0) -> list:
    """``n`` membranes drawn from the fit's linearised covariance around ``params`` (None where a draw is not
    a valid membrane). Raises ValueError when the statistics have no finite covariance."""
    cov = statistics.covariance()
    if cov is None:
        raise ValueError("the identification's covariance is not finite (a parameter is not determined by the "
                         "data): no confidence band")
    names = tuple(statistics.names)
    is_log = statistics.is_log()
    rng = np.random.default_rng(seed)
    # eigen-decomposition (not Cholesky): a nearly singular covariance (strong correlations) still samples
    w, v = np.linalg.eigh(0.5 * (cov + cov.T))
    root = v * np.sqrt(np.clip(w, 0.0, None))
    draws = rng.standard_normal((n, len(names))) @ root.T
    out = []
    for delta in draws:
        try:
            out.append(_apply(params, names, delta, is_log))
        except (ParameterError, ValueError, OverflowError):
            out.append(None)
    return out


def _nominal(p: MembraneParameters, amplitude_V: float, freqs: np.ndarray, n_harmonics: int, offset_V: float = 0.0):
    """The identified model's sweep: (d_rms per frequency, state per frequency, peak frequency, peak d_rms)."""
    sweep = frequency_sweep(p, SinePeriodic(amplitude_V, float(freqs[0]), offset_V), freqs, n_harmonics=n_harmonics,
                            stability=False, branch_switching=False, realised=False)
    d = sweep.realised_d_rms_m
    states = []
    for f, value in zip(freqs, d):   # the solution a slow upward sweep is on (one per frequency)
        pts = [q for q in sweep.points if abs(q.frequency_Hz - f) <= 1e-9 * f]
        best = min(pts, key=lambda q: abs(q.d_rms_m - value))
        states.append(best.solution.state)
    peak = sweep.resonance_peak(False)
    return d, states, float(peak["frequency_Hz"]), float(peak["d_rms_m"])


def _responses(task: dict) -> list:
    """[(d_rms on the grid, peak frequency, peak d_rms) or None] for a batch of membranes (engine task).

    The curve: one batched harmonic-balance solve over the grid per membrane, started from the
    identified model's solutions (so each sample stays on the branch the identified model's upward sweep
    is on); the peak: a continuation sweep over +-``window`` around the identified peak, located on the
    branch (NaN when it sits on the window's edge)."""
    freqs = np.asarray(task["frequencies_Hz"], float)
    amp, n_h, offset = float(task["amplitude_V"]), int(task["n_harmonics"]), float(task.get("offset_V", 0.0))
    f_peak, w = float(task["peak_Hz"]), float(task["window"])
    window = np.linspace(f_peak * (1.0 - w), f_peak * (1.0 + w), 3)   # the steps follow the branch, not the grid
    guesses = [np.asarray(g, float) for g in task["states"]]
    out = []
    for data in task["members"]:
        if data is None:
            out.append(None)
            continue
        try:
            p = MembraneParameters(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items()})
            d0 = float(static_equilibrium(p, 0.0).displacement_m)
            sols = solve_native_batch(p, [SinePeriodic(amp, float(f), offset) for f in freqs], n_h,
                                      x_guesses=guesses)
            curve = [s.displacement_rms(d0) for s in sols]
            sweep = frequency_sweep(p, SinePeriodic(amp, float(window[0]), offset), window, n_harmonics=n_h,
                                    stability=False, branch_switching=False, realised=False)
            peak = sweep.resonance_peak(False)
            pf = float(peak["frequency_Hz"])
            if not window[0] * (1 + 1e-6) < pf < window[-1] * (1 - 1e-6):
                pf, pd = math.nan, math.nan
            else:
                pd = float(peak["d_rms_m"])
        except Exception:  # noqa: BLE001 - a sample without a response is counted, not fatal
            out.append(None)
            continue
        out.append((curve, pf, pd))
    return out


def response_band(params: MembraneParameters, statistics: ParameterStatistics, amplitude_V: float,
                  frequencies_Hz, n_samples: int = DEFAULT_SAMPLES, seed: int = 0, confidence: float = 0.95,
                  n_harmonics: int = 8, mass_kg: float | None = None, engine=None,
                  window: float = 0.3, offset_V: float = 0.0) -> ResponseBand:
    """The confidence band of the frequency response and of the resonance peak (module docstring), of
    u = ``offset_V`` + ``amplitude_V`` sin (|U sin| without the offset: the same u^2).

    ``engine``: an open :class:`~dea_ros.study.engine.Engine` to spread the batches of samples on
    (default: this process). ``window``: each sample's peak is searched within +-window (relative) of the
    identified model's peak (a sample whose peak lies beyond counts as failed for the peak only)."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: must be in (0, 1), got {confidence}")
    if n_samples < 2:
        raise ValueError(f"n_samples: at least 2, got {n_samples}")
    p0 = params if mass_kg is None else params.replace(mass_kg=float(mass_kg))
    freqs = np.unique(np.asarray(frequencies_Hz, float))
    members = sample_parameters(p0, statistics, n_samples, seed)
    nom_d, states, nom_f, nom_peak = _nominal(p0, float(amplitude_V), freqs, n_harmonics, float(offset_V))
    plain = [None if m is None else m.to_dict() for m in members]
    common = {"frequencies_Hz": freqs.tolist(), "amplitude_V": float(amplitude_V), "n_harmonics": n_harmonics,
              "states": [st.tolist() for st in states], "peak_Hz": nom_f, "window": window,
              "offset_V": float(offset_V)}
    tasks = [(k, dict(common, members=plain[s:s + _BATCH])) for k, s in enumerate(range(0, len(plain), _BATCH))]
    results = {}
    if engine is None:
        for k, task in tasks:
            results[k] = _responses(task)
    else:
        for k, res, exc in engine.map_unordered(_responses, tasks):
            results[k] = res if exc is None else [None] * len(tasks[k][1]["members"])
    flat = [r for k in sorted(results) for r in results[k]]
    samples = [r for r in flat if r is not None]
    curves = np.array([s[0] for s in samples], float).reshape(len(samples), freqs.size)
    peaks_f = np.array([s[1] for s in samples], float)
    peaks_d = np.array([s[2] for s in samples], float)
    q = (0.5 - confidence / 2.0, 0.5 + confidence / 2.0)
    with np.errstate(invalid="ignore"):
        if samples:
            lower, upper = np.nanquantile(curves, q[0], axis=0), np.nanquantile(curves, q[1], axis=0)
        else:
            lower = upper = np.full(freqs.size, np.nan)

    def ci(x):
        x = x[np.isfinite(x)]
        return (float(np.quantile(x, q[0])), float(np.quantile(x, q[1]))) if x.size else (math.nan, math.nan)

    return ResponseBand(
        amplitude_V=float(amplitude_V), mass_kg=float(p0.mass_kg), frequencies_Hz=freqs,
        nominal_m=np.asarray(nom_d, float), lower_m=np.asarray(lower, float), upper_m=np.asarray(upper, float),
        peak_frequency_Hz=nom_f, peak_d_rms_m=nom_peak, peak_frequency_ci_Hz=ci(peaks_f),
        peak_d_rms_ci_m=ci(peaks_d), samples=len(samples), n_failed=n_samples - len(samples),
        confidence=confidence, parameters=tuple(statistics.names), seed=seed, sample_peaks_Hz=peaks_f,
        sample_curves_m=curves, offset_V=float(offset_V))


def response_bands(params: MembraneParameters, statistics: ParameterStatistics | None, experiments: ExperimentSet,
                   n_samples: int, n_harmonics: int = 8, engine=None, peaks: dict | None = None) -> tuple:
    """(bands, warnings): a :func:`response_band` per sine data set and waveform (amplitude, offset) of
    ``experiments``, on :data:`BAND_POINTS` frequencies over its range and as many within +-15 % of the model's
    peak (``peaks``: (source, amplitude V, offset V) -> the model's peak frequency in Hz); a warning where none
    can be drawn."""
    peaks = peaks or {}
    bands, warnings = [], []
    if statistics is None:
        return bands, ["no confidence band of the frequency response: no dynamic fit statistics"]
    for sine in experiments.sines:
        for a, offset, sel in sine.waveform_groups():
            f = sine.frequency_Hz[sel]
            grid = np.linspace(f.min(), f.max(), BAND_POINTS)
            fp = peaks.get((sine.source, a, offset))
            if fp is not None and np.isfinite(fp):
                near = np.linspace(0.85 * fp, 1.15 * fp, BAND_POINTS)
                grid = np.union1d(grid, near[(near >= f.min()) & (near <= f.max())])
            try:
                bands.append(response_band(params, statistics, a, grid, n_samples=n_samples,
                                           n_harmonics=n_harmonics, mass_kg=sine.mass_kg, engine=engine,
                                           offset_V=offset))
            except (ValueError, HarmonicBalanceError, RuntimeError) as exc:
                warnings.append(f"{sine.source}: no confidence band of the frequency response at {a:g} V ({exc})")
    return bands, warnings
