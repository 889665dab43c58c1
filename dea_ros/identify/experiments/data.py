"""The measured experiments as data (SI units): static points, step responses, sine responses, the set.

* :class:`StaticData` -- rest displacements for a mass and a constant voltage (eq. 20);
* :class:`StepData` -- a sampled voltage step response (eq. 23);
* :class:`SineSeries` -- a sampled record under a sine voltage: its RMS over whole periods (eq. 21),
  what it shows (periodic at T/2, period-doubled, quasi-periodic, not settled) and the voltage it
  received as a periodic input;
* :class:`SineData` -- a frequency response: d_rms per frequency (eqs. 21, 24);
* :class:`ExperimentSet` -- everything measured on one membrane, with its geometry (Table I).

Every class checks its columns when it is made (finite, equal lengths, plausible SI values; see
:mod:`.checks`) and raises :class:`~dea_ros.errors.ExperimentError` naming the source and column.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import ExperimentError
from ...model.parameters import PRESET_NAMES, MembraneParameters, ParameterError
from .checks import as_finite_array, check_displacement, check_lengths, check_mass, check_time, check_voltage
from .records import period_weights, periodic_input_from_record, rms_statistics, third_difference_noise

__all__ = ["WAVEFORMS", "GEOMETRY_FIELDS", "StaticData", "StepData", "SineSeries", "SineData", "ExperimentSet"]

#: Waveforms of the sine experiments: U sin(2 pi f t) or |U sin(2 pi f t)| (same u^2).
WAVEFORMS = ("sine", "abs_sine")
GEOMETRY_FIELDS = ("prestretch", "thickness_m", "plate_radius_m", "electrode_width_m")


@dataclass(frozen=True)
class StaticData:
    """Static points (eq. 20): the rest displacement for a mass and a constant voltage."""

    mass_kg: np.ndarray
    voltage_V: np.ndarray
    displacement_m: np.ndarray
    source: str = "static data"
    #: per point, the RMS of its samples about their linear trend over the measurement window (m), where
    #: the samples were recorded (a bag): the laser noise alone when the membrane was at rest; None otherwise
    motion_rms_m: np.ndarray | None = None
    #: per point, the standard uncertainty of its mean displacement (m): the laser noise over the square root
    #: of the samples averaged, where known (a bag, synthetic data); NaN or None where not (a table)
    std_error_m: np.ndarray | None = None

    def __post_init__(self):
        src = self.source
        m = as_finite_array(self.mass_kg, "mass_kg", src)
        u = as_finite_array(self.voltage_V, "voltage_V", src)
        d = as_finite_array(self.displacement_m, "displacement_m", src)
        n = check_lengths(src, mass_kg=m, voltage_V=u, displacement_m=d)
        if n < 1:
            raise ExperimentError(f"{src}: no static points")
        check_mass(m, "mass_kg", src)
        check_voltage(u, "voltage_V", src)
        check_displacement(d, "displacement_m", src)
        for name, arr in (("mass_kg", m), ("voltage_V", u), ("displacement_m", d)):
            object.__setattr__(self, name, arr)
        if self.motion_rms_m is not None:
            motion = np.asarray(self.motion_rms_m, float)
            check_lengths(src, displacement_m=d, motion_rms_m=motion)
            object.__setattr__(self, "motion_rms_m", motion)
        if self.std_error_m is not None:
            std = np.asarray(self.std_error_m, float)
            check_lengths(src, displacement_m=d, std_error_m=std)
            if np.any(std <= 0.0):
                raise ExperimentError(f"{src}: std_error_m (CSV column displacement_std_m) must be > 0 m: the "
                                      "standard uncertainty of each point's mean; leave the column out where unknown")
            object.__setattr__(self, "std_error_m", std)

    @property
    def stated_std_m(self) -> np.ndarray | None:
        """Every point's standard uncertainty (m) when each one states it, else None."""
        std = self.std_error_m
        return None if std is None or not np.all(np.isfinite(std)) else std

    @property
    def n_points(self) -> int:
        return int(self.mass_kg.size)


@dataclass(frozen=True)
class StepData:
    """A sampled voltage step response (eq. 23): time (s), voltage (V), displacement (m)."""

    time_s: np.ndarray
    voltage_V: np.ndarray
    displacement_m: np.ndarray
    mass_kg: float
    voltage_hold: str = "zoh"
    source: str = "step data"

    def __post_init__(self):
        src = self.source
        t = as_finite_array(self.time_s, "time_s", src)
        u = as_finite_array(self.voltage_V, "voltage_V", src)
        d = as_finite_array(self.displacement_m, "displacement_m", src)
        n = check_lengths(src, time_s=t, voltage_V=u, displacement_m=d)
        if n < 20:
            raise ExperimentError(
                f"{src}: {n} samples are too few for a step response (need >= 20; the rig samples at 1 kHz)"
            )
        check_time(t, "time_s", src)
        check_voltage(u, "voltage_V", src)
        check_displacement(d, "displacement_m", src)
        if self.voltage_hold not in ("zoh", "linear"):
            raise ExperimentError(f"{src}: voltage_hold must be 'zoh' or 'linear', got {self.voltage_hold!r}")
        if float(np.ptp(u)) < 50.0:
            raise ExperimentError(
                f"{src}, column 'voltage_V': the voltage never changes (range {float(np.ptp(u)):g} V); "
                "a step experiment needs a voltage step"
            )
        if not (isinstance(self.mass_kg, (int, float)) and 0.0 < float(self.mass_kg) <= 0.5):
            raise ExperimentError(f"{src}: mass_kg must be in (0, 0.5] kg, got {self.mass_kg!r}")
        for name, arr in (("time_s", t), ("voltage_V", u), ("displacement_m", d)):
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "mass_kg", float(self.mass_kg))

    @property
    def n_samples(self) -> int:
        return int(self.time_s.size)

    @property
    def step_index(self) -> int:
        """Index of the first sample at the new voltage (the largest voltage jump)."""
        return int(np.argmax(np.abs(np.diff(self.voltage_V)))) + 1

    @property
    def step_time_s(self) -> float:
        return float(self.time_s[self.step_index])

    @property
    def initial_V(self) -> float:
        return float(self.voltage_V[0])

    @property
    def final_V(self) -> float:
        return float(self.voltage_V[-1])

    @property
    def sample_period_s(self) -> float:
        return float(np.median(np.diff(self.time_s)))


def _fourier_residual(phase: np.ndarray, harmonics, y: np.ndarray) -> tuple:
    """(residual sum of squares, number of coefficients, residual) of the least-squares Fourier series
    of ``y`` with a mean and the ``harmonics`` k (cos and sin of k x ``phase``)."""
    cols = [np.ones_like(phase)]
    for k in harmonics:
        cols += [np.cos(k * phase), np.sin(k * phase)]
    a = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    return float(res @ res), a.shape[1], res


@dataclass(frozen=True)
class SineSeries:
    """A sampled record under a sine voltage (optional companion of :class:`SineData`)."""

    frequency_Hz: float
    time_s: np.ndarray
    voltage_V: np.ndarray
    displacement_m: np.ndarray
    source: str = "sine series"
    #: what the voltage samples are: "linear" (samples of a continuous waveform, the default) or
    #: "zoh" (a zero-order hold: each value applied from its sample until the next one, as the
    #: amplifier output recorded in a bag); it decides :meth:`measured_input`
    voltage_hold: str = "linear"

    def __post_init__(self):
        src = self.source
        t = as_finite_array(self.time_s, "time_s", src)
        u = as_finite_array(self.voltage_V, "voltage_V", src)
        d = as_finite_array(self.displacement_m, "displacement_m", src)
        n = check_lengths(src, time_s=t, voltage_V=u, displacement_m=d)
        if n < 20:
            raise ExperimentError(f"{src}: {n} samples are too few for a sine record (need >= 20)")
        if self.voltage_hold not in ("zoh", "linear"):
            raise ExperimentError(f"{src}: voltage_hold must be 'zoh' or 'linear', got {self.voltage_hold!r}")
        check_time(t, "time_s", src)
        check_voltage(u, "voltage_V", src)
        check_displacement(d, "displacement_m", src)
        f = float(self.frequency_Hz)
        if not (math.isfinite(f) and f > 0):
            raise ExperimentError(f"{src}: frequency_Hz must be > 0, got {self.frequency_Hz!r}")
        for name, arr in (("time_s", t), ("voltage_V", u), ("displacement_m", d)):
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "frequency_Hz", f)

    def whole_periods(self) -> np.ndarray:
        """Boolean mask of the samples within the whole periods used by :meth:`period_weights`."""
        w, _n, _wrap = period_weights(self.time_s, self.frequency_Hz, self.source)
        return w > 0

    def period_weights(self):
        """(weights, number of periods, wrapped) of :func:`period_weights` for this record."""
        return period_weights(self.time_s, self.frequency_Hz, self.source)

    def displacement_rms(self, d0_m: float, noise_m: float | None = None, d0_std_m: float = 0.0) -> float:
        """RMS of d - d0 over whole periods (eq. 21), with interpolated period boundaries.

        The mean square is the integral over n whole periods of the linear interpolant of
        (d - d0)^2 (weights of :func:`period_weights`), so a period that is not a whole number
        of samples adds no bias. With ``noise_m`` (laser noise sigma) the noise contribution
        sigma^2 + d0_std^2 is removed from the mean square: unbiased.
        """
        return rms_statistics(self, d0_m, noise_m, d0_std_m)[0]

    def displacement_rms_std(self, d0_m: float, noise_m: float, d0_std_m: float = 0.0) -> float:
        """Standard uncertainty of :meth:`displacement_rms` for white laser noise ``noise_m`` and an
        uncertainty ``d0_std_m`` of the rest position (linearised)."""
        return rms_statistics(self, d0_m, noise_m, d0_std_m)[1]

    def settling_m(self, d0_m: float, noise_m: float, d0_std_m: float = 0.0) -> tuple:
        """(d_rms of the second half - first half of the whole periods, its standard uncertainty
        from the noise): a record that has not settled (a transient still decaying) shows a
        difference well beyond its uncertainty. (0, 0) for fewer than two periods."""
        n = int(math.floor(float(self.time_s[-1] - self.time_s[0]) * self.frequency_Hz + 1e-9))
        if n < 2:
            return 0.0, 0.0
        t = self.time_s - self.time_s[0]
        half = (n // 2) / self.frequency_Hz
        parts = []
        for keep in (t <= half + 1e-9, (t >= half - 1e-9) & (t <= 2 * half + 1e-9)):
            if np.count_nonzero(keep) < 20:
                return 0.0, 0.0
            piece = SineSeries(self.frequency_Hz, t[keep], self.voltage_V[keep], self.displacement_m[keep],
                               self.source, self.voltage_hold)
            parts.append(rms_statistics(piece, d0_m, noise_m, 0.0))
        (a, ea), (b, eb) = parts
        return b - a, math.hypot(ea or 0.0, eb or 0.0)

    def noise_m(self) -> float | None:
        """Laser noise sigma estimated from the record's third differences (see :func:`estimate_noise_m`)."""
        return third_difference_noise(self.displacement_m)

    def classify(self, noise_m: float | None = None) -> dict:
        """What the record shows, from the data alone: ``periodic`` (the period P of u^2: T/2 for |U sin|
        and U sin, T for an offset sine offset + U sin, whose u^2 has a component at f),
        ``period-doubled`` (period 2P: odd harmonics of 1/(2P)) or ``quasi-periodic`` (no period).

        Least-squares Fourier series over the whole periods with harmonics of 1/P and of 1/(2P),
        up to 0.45 of the sampling rate; their residual RMS is compared with the laser noise
        (``noise_m``, else estimated from the record). The forcing's period P from the applied voltage:
        T when u^2's harmonics of f that T/2 does not have carry more than a quarter of its spread
        (``forcing_period``). Period 2P when the odd harmonics of 1/(2P) are significant (more than 5
        sigma of chi-square and an RMS above 3x the noise) and the full fit leaves no more than 2x the
        noise; when that fit leaves more,
        ``not settled`` if the misfit sits in the first half of the record (a transient that has not
        died out: the record began too soon after the frequency change), else quasi-periodic;
        period T/2 otherwise. Misfits within what the applied voltage's own departure from
        periodicity explains (3x its relative misfit + 2 % of the response spread: commands at a
        rate incommensurate with f) do not count.
        """
        w, n_periods, _wrap = self.period_weights()
        keep = w > 0
        t = self.time_s[keep] - self.time_s[0]
        d = self.displacement_m[keep]
        sigma = noise_m if noise_m is not None else self.noise_m()
        sigma = max(float(sigma or 0.0), 1e-12 * max(float(np.ptp(d)), 1e-9))
        fs = 1.0 / float(np.median(np.diff(self.time_s)))
        top = max(2, min(60, int(0.45 * fs / self.frequency_Hz)))
        phase = 2.0 * np.pi * self.frequency_Hz * t     # harmonics k of f; with the period 2T below, of f/2

        # how periodic the applied voltage itself is: a command rate incommensurate with f (a DAQ
        # or amplifier updating at 250 Hz) makes u^2, and so the response, not exactly periodic
        u2 = self.voltage_V[keep] ** 2
        u2_spread = float(np.std(u2))
        rss_u2_half = _fourier_residual(phase, range(2, top + 1, 2), u2)[0]
        rss_u2 = _fourier_residual(phase, range(1, top + 1), u2)[0]
        input_misfit = (math.sqrt(rss_u2 / u2.size) / u2_spread) if u2_spread > 0 else 0.0
        # an offset sine: u^2 has period T (its harmonics of f carry it), the response's period is T
        forcing_T = u2_spread > 0 and math.sqrt(max(rss_u2_half - rss_u2, 0.0) / u2.size) > 0.25 * u2_spread
        if forcing_T:
            phase = phase / 2.0
            top *= 2
        d_spread = max(float(np.std(d)), 1e-15)
        tolerance = 3.0 * input_misfit + 0.02       # non-periodic share the input explains

        rss_half, p_half, _res = _fourier_residual(phase, range(2, top + 1, 2), d)
        rss_full, p_full, res_full = _fourier_residual(phase, range(1, top + 1), d)
        n = d.size
        r_half = math.sqrt(rss_half / max(n - p_half, 1))
        r_full = math.sqrt(rss_full / max(n - p_full, 1))
        extra = p_full - p_half
        chi2_gain = (rss_half - rss_full) / sigma**2
        odd_rms = math.sqrt(max(rss_half - rss_full, 0.0) / n)
        # where the non-periodic part is: a transient that has not died out (the record started too soon
        # after the frequency change) leaves it at the start; a torus (quasi-periodic) everywhere
        halves = np.array_split(res_full, 2)
        r_first, r_second = (float(np.sqrt(np.mean(h * h))) for h in halves)
        beyond_input = r_full > tolerance * d_spread
        if r_full > 2.0 * sigma and beyond_input and r_first > 2.0 * max(r_second, sigma):
            kind = "not settled"
        elif r_full > 2.0 * sigma and beyond_input:
            kind = "quasi-periodic"
        elif (chi2_gain > extra + 5.0 * math.sqrt(2.0 * extra) and odd_rms > 3.0 * sigma
              and odd_rms > tolerance * d_spread):
            # odd harmonics well above the noise (aliased even harmonics near the Nyquist
            # frequency stay at the noise level)
            kind = "period-doubled"
        else:
            kind = "periodic"
        return {"kind": kind, "residual_T2_m": r_half, "residual_T_m": r_full, "odd_rms_m": odd_rms,
                "residual_first_half_m": r_first, "residual_second_half_m": r_second,
                "input_nonperiodic_fraction": input_misfit, "response_spread_m": d_spread,
                "noise_m": sigma, "periods": n_periods, "harmonics": top,
                "forcing_period": "T" if forcing_T else "T/2"}

    def measured_input(self, harmonics: int = 24, samples: int = 256):
        """The voltage actually applied, as one period for harmonic balance (a SampledPeriodic):
        :func:`periodic_input_from_record` of this record's voltage with its ``voltage_hold``."""
        return periodic_input_from_record(self.time_s, self.voltage_V, self.frequency_Hz, self.voltage_hold,
                                          harmonics, samples, self.source)


@dataclass(frozen=True)
class SineData:
    """Frequency response (eq. 21): RMS displacement around the rest position d0 per frequency."""

    frequency_Hz: np.ndarray
    amplitude_V: np.ndarray
    d_rms_m: np.ndarray
    mass_kg: float
    d0_m: np.ndarray | None = None
    series: tuple = ()
    source: str = "sine data"
    #: optional periodic inputs (one per frequency, e.g. ``SineSeries.measured_input()``): the fit
    #: and the evaluation then use the applied waveform instead of the nominal sine
    inputs: tuple = ()
    d_rms_std_m: np.ndarray | None = None
    #: the applied voltage: "sine" (U sin wt) or "abs_sine" (|U sin wt|); see WAVEFORMS
    waveform: str = "sine"

    def __post_init__(self):
        src = self.source
        f = as_finite_array(self.frequency_Hz, "frequency_Hz", src)
        a = as_finite_array(self.amplitude_V, "amplitude_V", src)
        r = as_finite_array(self.d_rms_m, "d_rms_m", src)
        arrays = {"frequency_Hz": f, "amplitude_V": a, "d_rms_m": r}
        if self.d0_m is not None:
            arrays["d0_m"] = as_finite_array(self.d0_m, "d0_m", src)
        if self.d_rms_std_m is not None:
            arrays["d_rms_std_m"] = as_finite_array(self.d_rms_std_m, "d_rms_std_m", src)
        n = check_lengths(src, **arrays)
        if n < 1:
            raise ExperimentError(f"{src}: no frequencies")
        if np.any(f <= 0):
            k = int(np.nonzero(f <= 0)[0][0])
            raise ExperimentError(f"{src}, column 'frequency_Hz', row {k + 1}: must be > 0, got {f[k]:g}")
        if np.any(a <= 0):
            k = int(np.nonzero(a <= 0)[0][0])
            raise ExperimentError(f"{src}, column 'amplitude_V', row {k + 1}: must be > 0, got {a[k]:g}")
        if np.any(r < 0):
            k = int(np.nonzero(r < 0)[0][0])
            raise ExperimentError(f"{src}, column 'd_rms_m', row {k + 1}: an RMS is >= 0, got {r[k]:g}")
        check_voltage(a, "amplitude_V", src)
        check_displacement(r, "d_rms_m", src)
        if "d0_m" in arrays:
            check_displacement(arrays["d0_m"], "d0_m", src)
        if "d_rms_std_m" in arrays:
            std = arrays["d_rms_std_m"]
            if np.any(std <= 0):
                k = int(np.nonzero(std <= 0)[0][0])
                raise ExperimentError(f"{src}, column 'd_rms_std_m', row {k + 1}: a standard uncertainty is > 0, "
                                      f"got {std[k]:g}")
            check_displacement(std, "d_rms_std_m", src)
        dup = np.nonzero(np.diff(np.sort(f)) <= 1e-9 * np.max(f))[0]
        if dup.size:
            raise ExperimentError(f"{src}, column 'frequency_Hz': frequency {np.sort(f)[dup[0]]:g} Hz appears twice")
        if not (isinstance(self.mass_kg, (int, float)) and 0.0 < float(self.mass_kg) <= 0.5):
            raise ExperimentError(f"{src}: mass_kg must be in (0, 0.5] kg, got {self.mass_kg!r}")
        for name, arr in arrays.items():
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "mass_kg", float(self.mass_kg))
        object.__setattr__(self, "series", tuple(self.series))
        object.__setattr__(self, "inputs", tuple(self.inputs))
        if self.inputs and len(self.inputs) != n:
            raise ExperimentError(f"{src}: {len(self.inputs)} inputs for {n} frequencies")
        if self.waveform not in WAVEFORMS:
            raise ExperimentError(f"{src}: waveform must be one of {WAVEFORMS} (U sin wt or |U sin wt|), "
                                  f"got {self.waveform!r}")

    @property
    def n_frequencies(self) -> int:
        return int(self.frequency_Hz.size)

    def rest_d0(self, k: int) -> float | None:
        """The measured rest position d0 (m) record ``k``'s RMS is about (eq. 21), None when not stated
        (the fit then takes the model's rest position)."""
        return None if self.d0_m is None else float(self.d0_m[k])

    def offset_V(self, k: int) -> float:
        """The offset of record ``k``'s applied voltage u = offset + U sin (V): the mean over a period of its
        measured input, to 1 % of U (a held voltage's mean is off by ~0.1 %: records of one nominal offset
        share one sweep of the model); 0 for |U sin| and U sin (their u^2 has period T/2) and without a
        measured input (a table's records are U sin or |U sin|)."""
        if self.waveform != "sine" or not self.inputs:
            return 0.0
        u = np.asarray(self.inputs[k].at_phase(np.linspace(0.0, 2.0 * np.pi, 256, endpoint=False)), float)
        grid = max(0.01 * float(self.amplitude_V[k]), 1e-3)
        return float(round(float(np.mean(u)) / grid) * grid)

    def waveform_groups(self) -> list:
        """[(amplitude V, offset V, record indices)]: the records one sweep of the model covers (the same
        excitation but its frequency), by amplitude, then offset."""
        offsets = np.array([self.offset_V(k) for k in range(self.frequency_Hz.size)])
        pairs = sorted({(float(a), float(o)) for a, o in zip(self.amplitude_V, offsets)})
        return [(a, o, np.nonzero((self.amplitude_V == a) & (offsets == o))[0]) for a, o in pairs]


@dataclass
class ExperimentSet:
    """Everything measured on one membrane, plus its geometry (Table I)."""

    membrane: str
    geometry: dict
    mass_kg: float
    static: list = field(default_factory=list)
    steps: list = field(default_factory=list)
    sines: list = field(default_factory=list)
    base_parameters: MembraneParameters | None = None
    base_reference: str | None = None
    sensor_noise_m: float | None = None
    folder: Path | None = None
    notes: str = ""

    def __post_init__(self):
        if not isinstance(self.membrane, str) or not self.membrane.strip():
            raise ExperimentError("manifest field 'membrane': must be a non-empty name")
        missing = [k for k in GEOMETRY_FIELDS if k not in self.geometry]
        if missing:
            raise ExperimentError(
                f"manifest: geometry field(s) {missing} missing; give them under 'geometry:' "
                f"or reference a parameters file / preset {PRESET_NAMES} with 'parameters:'"
            )
        if not (isinstance(self.mass_kg, (int, float)) and 0.0 < float(self.mass_kg) <= 0.5):
            raise ExperimentError(
                f"manifest field 'mass_kg': must be in (0, 0.5] kg, got {self.mass_kg!r} (3 g -> 0.003)"
            )
        if self.sensor_noise_m is not None and not (0.0 < float(self.sensor_noise_m) < 1e-3):
            raise ExperimentError(
                f"manifest field 'sensor_noise_m': must be in (0, 1e-3) m, got {self.sensor_noise_m!r}"
            )
        if not (self.static or self.steps or self.sines):
            raise ExperimentError("manifest field 'experiments': no experiments listed")
        try:
            self.template_parameters()
        except ParameterError as exc:
            raise ExperimentError(f"manifest geometry: {exc}") from None

    def template_parameters(self) -> MembraneParameters:
        """Parameters with the manifest's geometry and constants; fitted fields are placeholders
        (the base file's values when one is referenced)."""
        if self.base_parameters is not None:
            base = self.base_parameters
        else:
            base = MembraneParameters(
                name=self.membrane, prestretch=1.0, thickness_m=1e-5, plate_radius_m=1e-3,
                electrode_width_m=1e-2, mass_kg=self.mass_kg, relative_permittivity=3.0,
                k1_Pa=1e7, eta1_Pa_s=1e7, eta2_Pa_s=1e4, beta_Pa=(1e5, 0.0, 0.0),
                gamma_Pa=(0.0, 0.0, 0.0),
            )
        return base.replace(name=self.membrane, mass_kg=float(self.mass_kg),
                            **{k: float(self.geometry[k]) for k in GEOMETRY_FIELDS})

    def all_static(self) -> StaticData | None:
        """All static points merged into one table (None when there are none)."""
        if not self.static:
            return None

        def merged(name):
            if all(getattr(s, name) is None for s in self.static):
                return None
            return np.concatenate([getattr(s, name) if getattr(s, name) is not None else np.full(s.n_points, np.nan)
                                   for s in self.static])

        return StaticData(
            np.concatenate([s.mass_kg for s in self.static]),
            np.concatenate([s.voltage_V for s in self.static]),
            np.concatenate([s.displacement_m for s in self.static]),
            source=", ".join(s.source for s in self.static),
            motion_rms_m=merged("motion_rms_m"),
            std_error_m=merged("std_error_m"),
        )

    def summary(self) -> str:
        parts = [f"membrane {self.membrane}"]
        if self.static:
            parts.append(f"{sum(s.n_points for s in self.static)} static points")
        if self.steps:
            parts.append(f"{len(self.steps)} step response(s)")
        if self.sines:
            parts.append(f"{sum(s.n_frequencies for s in self.sines)} sine frequencies")
        return ", ".join(parts)
