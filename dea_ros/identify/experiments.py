"""Experiments as data: static points, step responses and sine responses, with a hand-writable on-disk format.

On-disk format (``dea_ros.experiments/1``)
=========================================
One folder per data set::

    my_membrane/
      manifest.yaml
      static.csv
      step_2200V.csv
      sine_rms.csv
      sine_2Hz.csv          (optional sampled time series)

``manifest.yaml`` (every quantity in SI units; the ``units`` block is checked)::

    format: dea_ros.experiments/1
    membrane: A1                 # name given to the fitted parameters
    parameters: A1               # optional: preset name or a parameters YAML (relative to
                                 #   this folder): geometry, constants, Ogden prior
    geometry:                    # required when 'parameters' is absent; overrides it otherwise
      prestretch: 1.36           #   lambda_p (Table I)
      thickness_m: 2.7e-05       #   z0
      plate_radius_m: 0.0045     #   r
      electrode_width_m: 0.017   #   l0
    mass_kg: 0.003               # biasing mass of the step and sine experiments
    sensor_noise_m: 1.0e-06      # optional: laser noise sigma (otherwise estimated)
    units: {time: s, voltage: V, displacement: m, mass: kg, frequency: Hz}
    experiments:
      - kind: static             # columns mass_kg, voltage_V, displacement_m (one row per point)
        file: static.csv
      - kind: step               # columns time_s, voltage_V, displacement_m (sampled)
        file: step_2200V.csv
        voltage_hold: zoh        # optional: zoh (DAQ output, default) or linear
        mass_kg: 0.003           # optional: overrides the top-level mass for this experiment
      - kind: sine               # columns frequency_Hz, amplitude_V, d_rms_m[, d0_m, d_rms_std_m]
        file: sine_rms.csv       #   d_rms by eq. 21 around the rest position d0 over whole periods
                                 #   (laser noise removed, see rms_statistics); d_rms_std_m its
                                 #   standard uncertainty (statistical weights of the joint fit)
        waveform: sine           # the applied voltage: sine, u = U sin(2 pi f t) (the paper), or
                                 #   abs_sine, u = |U sin(2 pi f t)| (a unipolar amplifier, the rig);
                                 #   U = amplitude_V. Both give the same u^2, all the model sees (eq. 6)
        series:                  # optional sampled records: time_s, voltage_V (the applied u(t)),
          - {frequency_Hz: 2.0, file: sine_2Hz.csv}     # displacement_m, from phase 0 of the sine

CSV files: comma separated, ``#`` starts a comment line, the first other line
is the header. Every column name ends with its unit (``_s``, ``_V``, ``_m``,
``_kg``, ``_Hz``); columns not listed above are ignored. Displacement d is the
downward deflection of the mass from the flat membrane (d = 0 at 0 g, 0 V),
as in the paper (Fig. 1).

Loading validates units (header suffixes, values that look like mm or kV),
lengths, NaN/inf, strictly increasing time and the minimum amount of data;
every :class:`ExperimentError` names the file, the column and, where it
applies, the row (the 1-based line number in the file).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import yaml

from ..model.parameters import PRESET_NAMES, MembraneParameters, ParameterError, load_parameters
from ..errors import ExperimentError

__all__ = [
    "FORMAT",
    "KINDS",
    "WAVEFORMS",
    "GEOMETRY_FIELDS",
    "ExperimentError",
    "StaticData",
    "StepData",
    "SineSeries",
    "SineData",
    "ExperimentSet",
    "load_experiment_set",
    "write_experiment_set",
    "read_csv_columns",
    "write_csv_columns",
]

FORMAT = "dea_ros.experiments/1"
KINDS = ("static", "step", "sine")
#: Waveforms of the sine experiments: U sin(2 pi f t) or |U sin(2 pi f t)| (same u^2).
WAVEFORMS = ("sine", "abs_sine")
GEOMETRY_FIELDS = ("prestretch", "thickness_m", "plate_radius_m", "electrode_width_m")
_SI_UNITS = {"time": "s", "voltage": "V", "displacement": "m", "mass": "kg", "frequency": "Hz"}

#: Columns of each file type: name -> (quantity, plausibility check name).
STATIC_COLUMNS = ("mass_kg", "voltage_V", "displacement_m")
STEP_COLUMNS = ("time_s", "voltage_V", "displacement_m")
SINE_COLUMNS = ("frequency_Hz", "amplitude_V", "d_rms_m")
SINE_OPTIONAL = ("d0_m", "d_rms_std_m")

# Other spellings people use for a unit, with the conversion to SI.
_WRONG_UNITS = {
    "m": {"mm": "divide by 1000", "um": "divide by 1e6", "µm": "divide by 1e6",
          "micron": "divide by 1e6", "cm": "divide by 100", "nm": "divide by 1e9"},
    "V": {"kV": "multiply by 1000", "kv": "multiply by 1000", "mV": "divide by 1000", "v": "write V"},
    "s": {"ms": "divide by 1000", "us": "divide by 1e6", "min": "multiply by 60"},
    "kg": {"g": "divide by 1000", "mg": "divide by 1e6"},
    "Hz": {"kHz": "multiply by 1000", "hz": "write Hz", "rad_s": "divide by 2 pi"},
}


# --------------------------------------------------------------------------- CSV I/O
def _column_error(source: str, name: str, expected: str) -> ExperimentError | None:
    """Diagnose a header that names the right quantity with a wrong or missing unit."""
    base, _, unit = expected.rpartition("_")
    if name == base:
        return ExperimentError(
            f"{source}: column '{name}' has no unit suffix; name it '{expected}' "
            f"(values in {unit})"
        )
    if name.startswith(base + "_"):
        given = name[len(base) + 1:]
        hint = _WRONG_UNITS.get(unit, {}).get(given)
        fix = f"convert the values ({hint}) and " if hint else "convert the values to SI and "
        return ExperimentError(
            f"{source}: column '{name}' is in '{given}', the format expects SI units: "
            f"{fix}rename the column to '{expected}'"
        )
    return None


def read_csv_columns(
    path: str | Path,
    required: Sequence[str],
    optional: Sequence[str] = (),
) -> dict[str, np.ndarray]:
    """Read the named numeric columns of a CSV file with a unit-suffixed header.

    Raises :class:`ExperimentError` naming the file, column and line for a
    missing or wrongly-united column, a row with the wrong number of fields,
    and values that are not finite numbers.
    """
    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise ExperimentError(f"{source}: no such file (listed in the manifest)")
    lines = path.read_text().splitlines()
    header: list[str] | None = None
    header_line = 0
    rows: list[tuple[int, list[str]]] = []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        cells = [c.strip() for c in text.split(",")]
        if header is None:
            header, header_line = cells, number
        else:
            rows.append((number, cells))
    if header is None:
        raise ExperimentError(f"{source}: empty file; expected a header row {','.join(required)}")
    index = {name: k for k, name in enumerate(header)}
    if len(index) != len(header):
        dupes = sorted({h for h in header if header.count(h) > 1})
        raise ExperimentError(f"{source} line {header_line}: duplicate column(s) {dupes}")
    columns: dict[str, np.ndarray] = {}
    for name in list(required) + list(optional):
        if name not in index:
            if name in optional:
                continue
            for given in header:
                err = _column_error(source, given, name)
                if err is not None:
                    raise err
            raise ExperimentError(
                f"{source} line {header_line}: missing column '{name}'; the header must name "
                f"{', '.join(required)} (SI units in the suffix), got {', '.join(header)}"
            )
    if not rows:
        raise ExperimentError(f"{source}: no data rows after the header (line {header_line})")
    wanted = [n for n in list(required) + list(optional) if n in index]
    values = {n: np.empty(len(rows)) for n in wanted}
    for r, (number, cells) in enumerate(rows):
        if len(cells) != len(header):
            raise ExperimentError(
                f"{source} line {number}: {len(cells)} field(s), the header has {len(header)}; "
                "every row needs one value per column (inconsistent lengths)"
            )
        for n in wanted:
            text = cells[index[n]]
            try:
                v = float(text)
            except ValueError:
                raise ExperimentError(
                    f"{source} line {number}, column '{n}': {text!r} is not a number"
                ) from None
            if not math.isfinite(v):
                raise ExperimentError(
                    f"{source} line {number}, column '{n}': {text} is not finite (NaN/inf); "
                    "remove the row or repair the value"
                )
            values[n][r] = v
    columns.update(values)
    columns["_lines"] = np.array([number for number, _ in rows])
    return columns


def write_csv_columns(path: str | Path, columns: Mapping[str, Iterable[float]],
                      comment: str | None = None) -> None:
    """Write equal-length numeric columns with a header (full double precision)."""
    names = list(columns)
    data = [np.asarray(columns[n], dtype=float).reshape(-1) for n in names]
    n = {d.size for d in data}
    if len(n) != 1:
        raise ExperimentError(f"{path}: columns have different lengths {[d.size for d in data]}")
    out = []
    if comment:
        out += [f"# {line}" for line in comment.splitlines()]
    out.append(",".join(names))
    table = np.column_stack(data)
    out += [",".join(repr(float(v)) for v in row) for row in table]
    Path(path).write_text("\n".join(out) + "\n")


# --------------------------------------------------------------------------- checks
def _line_of(lines: np.ndarray | None, k: int) -> str:
    return f"line {int(lines[k])}" if lines is not None and k < lines.size else f"row {k + 1}"


def _as_array(value, name: str, source: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ExperimentError(f"{source}, column '{name}': not numeric") from None
    bad = np.nonzero(~np.isfinite(arr))[0]
    if bad.size:
        raise ExperimentError(
            f"{source}, column '{name}': value {arr[bad[0]]} at row {bad[0] + 1} is not finite "
            "(NaN/inf); remove the row or repair the value"
        )
    return arr


def _check_lengths(source: str, **arrays: np.ndarray) -> int:
    sizes = {k: v.size for k, v in arrays.items()}
    if len(set(sizes.values())) != 1:
        raise ExperimentError(
            f"{source}: columns have inconsistent lengths {sizes}; every column needs one value per sample"
        )
    return next(iter(sizes.values()))


def _check_displacement(d: np.ndarray, name: str, source: str, lines=None) -> None:
    k = int(np.argmax(np.abs(d)))
    if abs(d[k]) > 0.02:
        raise ExperimentError(
            f"{source}, column '{name}', {_line_of(lines, k)}: {d[k]:g} m is beyond any DEA "
            "deflection (the membranes move < 2 mm); values look like millimetres or "
            "micrometres: convert to metres (mm / 1000)"
        )


def _check_voltage(u: np.ndarray, name: str, source: str, lines=None) -> None:
    peak = float(np.max(np.abs(u))) if u.size else 0.0
    if 0.0 < peak < 50.0:
        raise ExperimentError(
            f"{source}, column '{name}': the largest voltage is {peak:g} V; DEAs are driven "
            "with kilovolts, so the values look like kV: convert to volts (2.2 kV -> 2200)"
        )
    k = int(np.argmax(np.abs(u)))
    if peak > 1e5:
        raise ExperimentError(
            f"{source}, column '{name}', {_line_of(lines, k)}: {u[k]:g} V is beyond any DEA amplifier; "
            "volts expected (2.2 kV -> 2200)"
        )


def _check_mass(m: np.ndarray, name: str, source: str, lines=None) -> None:
    if np.any(m < 0):
        k = int(np.nonzero(m < 0)[0][0])
        raise ExperimentError(f"{source}, column '{name}', {_line_of(lines, k)}: negative mass {m[k]:g} kg")
    k = int(np.argmax(m)) if m.size else 0
    if m.size and m[k] > 0.5:
        raise ExperimentError(
            f"{source}, column '{name}', {_line_of(lines, k)}: {m[k]:g} kg is far more than a "
            "membrane carries; values look like grams: convert to kg (3 g -> 0.003)"
        )


def _check_time(t: np.ndarray, name: str, source: str, lines=None) -> None:
    dt = np.diff(t)
    bad = np.nonzero(dt <= 0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        raise ExperimentError(
            f"{source}, column '{name}', {_line_of(lines, k)}: time is not strictly increasing "
            f"({t[k]:.9g} s after {t[k - 1]:.9g} s); sort the samples and drop duplicates"
        )
    if t[-1] - t[0] > 3600.0:
        raise ExperimentError(
            f"{source}, column '{name}': the record spans {t[-1] - t[0]:g} s; the values look "
            "like milliseconds: convert to seconds (ms / 1000)"
        )
    if dt.size and float(np.median(dt)) > 0.02:
        raise ExperimentError(
            f"{source}, column '{name}': median sample interval {float(np.median(dt)):g} s is too "
            "coarse for the 10-20 Hz dynamics (laser at 1 kHz -> 0.001 s); if the values are in "
            "milliseconds convert them to seconds"
        )


# --------------------------------------------------------------------------- data classes
@dataclass(frozen=True)
class StaticData:
    """Static points (eq. 20): the rest displacement for a mass and a constant voltage."""

    mass_kg: np.ndarray
    voltage_V: np.ndarray
    displacement_m: np.ndarray
    source: str = "static data"

    def __post_init__(self):
        src = self.source
        m = _as_array(self.mass_kg, "mass_kg", src)
        u = _as_array(self.voltage_V, "voltage_V", src)
        d = _as_array(self.displacement_m, "displacement_m", src)
        n = _check_lengths(src, mass_kg=m, voltage_V=u, displacement_m=d)
        if n < 1:
            raise ExperimentError(f"{src}: no static points")
        _check_mass(m, "mass_kg", src)
        _check_voltage(u, "voltage_V", src)
        _check_displacement(d, "displacement_m", src)
        for name, arr in (("mass_kg", m), ("voltage_V", u), ("displacement_m", d)):
            object.__setattr__(self, name, arr)

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
        t = _as_array(self.time_s, "time_s", src)
        u = _as_array(self.voltage_V, "voltage_V", src)
        d = _as_array(self.displacement_m, "displacement_m", src)
        n = _check_lengths(src, time_s=t, voltage_V=u, displacement_m=d)
        if n < 20:
            raise ExperimentError(
                f"{src}: {n} samples are too few for a step response (need >= 20; the rig samples at 1 kHz)"
            )
        _check_time(t, "time_s", src)
        _check_voltage(u, "voltage_V", src)
        _check_displacement(d, "displacement_m", src)
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
        t = _as_array(self.time_s, "time_s", src)
        u = _as_array(self.voltage_V, "voltage_V", src)
        d = _as_array(self.displacement_m, "displacement_m", src)
        n = _check_lengths(src, time_s=t, voltage_V=u, displacement_m=d)
        if n < 20:
            raise ExperimentError(f"{src}: {n} samples are too few for a sine record (need >= 20)")
        if self.voltage_hold not in ("zoh", "linear"):
            raise ExperimentError(f"{src}: voltage_hold must be 'zoh' or 'linear', got {self.voltage_hold!r}")
        _check_time(t, "time_s", src)
        _check_voltage(u, "voltage_V", src)
        _check_displacement(d, "displacement_m", src)
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
        """What the record shows, from the data alone: ``periodic`` (period T/2 of u^2),
        ``period-doubled`` (period T: odd harmonics of f) or ``quasi-periodic`` (no period).

        Least-squares Fourier series over the whole periods with harmonics of 2f (period T/2)
        and of f (period T), up to 0.45 of the sampling rate; their residual RMS is compared
        with the laser noise (``noise_m``, else estimated from the record). Period T when the
        odd harmonics are significant (more than 5 sigma of chi-square and an RMS above 3x the
        noise) and the full-period fit leaves no more than 2x the noise; when that fit leaves more,
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
        theta = 2.0 * np.pi * self.frequency_Hz * t

        def fit(harmonics, y=d):
            cols = [np.ones_like(theta)]
            for k in harmonics:
                cols += [np.cos(k * theta), np.sin(k * theta)]
            a = np.column_stack(cols)
            coef, *_ = np.linalg.lstsq(a, y, rcond=None)
            res = y - a @ coef
            fit.residual = res
            return float(res @ res), a.shape[1]

        # how periodic the applied voltage itself is: a command rate incommensurate with f (a DAQ
        # or amplifier updating at 250 Hz) makes u^2, and so the response, not exactly periodic
        u2 = self.voltage_V[keep] ** 2
        u2_spread = float(np.std(u2))
        input_misfit = (math.sqrt(fit(range(1, top + 1), u2)[0] / u2.size) / u2_spread) if u2_spread > 0 else 0.0
        d_spread = max(float(np.std(d)), 1e-15)
        tolerance = 3.0 * input_misfit + 0.02       # non-periodic share the input explains

        rss_half, p_half = fit(range(2, top + 1, 2))
        rss_full, p_full = fit(range(1, top + 1))
        res_full = fit.residual
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
                "noise_m": sigma, "periods": n_periods, "harmonics": top}

    def measured_input(self, harmonics: int = 24, samples: int = 256):
        """The voltage actually applied, as one period for harmonic balance (a SampledPeriodic):
        :func:`periodic_input_from_record` of this record's voltage with its ``voltage_hold``."""
        return periodic_input_from_record(self.time_s, self.voltage_V, self.frequency_Hz, self.voltage_hold,
                                          harmonics, samples, self.source)


def periodic_input_from_record(time_s, voltage_V, frequency_Hz: float, hold: str = "linear",
                               harmonics: int = 24, samples: int = 256, source: str = "sine record"):
    """The voltage actually applied during a record, as one period for harmonic balance
    (a SampledPeriodic, phase 0 at the first sample).

    The model sees u^2 only (eq. 6): the harmonics 0..``harmonics`` of the excitation frequency
    of u^2 over whole periods of the record (the period average of what the membrane received,
    with command jitter and slew limiting included), then u = sqrt(u^2) sampled at ``samples``
    phases. How u^2 between the samples is known depends on ``hold``: ``zoh`` (a held staircase,
    as an amplifier fed by a DAQ or a command topic at a finite rate applies it; each value from
    its time stamp until the next): the Fourier integrals of the piecewise-constant u^2 are
    exact, so the hold's sinc(2 f / f_hold) attenuation of the 2f component and its half-step
    delay are in the input; ``linear`` (samples of a continuous waveform): least-squares
    projection of the samples.
    """
    from ..solvers.inputs import SampledPeriodic

    t = np.asarray(time_s, float) - float(time_s[0])
    u = np.asarray(voltage_V, float)
    f = float(frequency_Hz)
    dt = float(np.median(np.diff(t)))
    # only harmonics below the Nyquist frequency of the samples (above it the projection aliases,
    # and a staircase has its images of the hold rate there)
    harmonics = max(2, min(int(harmonics), int(0.45 / (dt * f))))
    k = np.arange(1, harmonics + 1)
    if hold == "zoh":
        n = int(math.floor((t[-1] + dt) * f + 1e-9))   # the last value holds one sample interval
        if n < 1:
            raise ExperimentError(f"{source}: shorter than one period at {f:g} Hz")
        length = n / f
        a = np.minimum(t, length)
        b = np.minimum(np.r_[t[1:], t[-1] + dt], length)
        kw = (2.0 * np.pi * f * k)[:, None]
        u2 = u * u
        coeffs = np.r_[float(u2 @ (b - a)) / length,
                       2.0 / length * ((np.sin(kw * b) - np.sin(kw * a)) / kw) @ u2,
                       2.0 / length * ((np.cos(kw * a) - np.cos(kw * b)) / kw) @ u2]
        keep = t < length
    else:
        keep = period_weights(t, f, source)[0] > 0
        theta = 2.0 * np.pi * f * t[keep]
        basis = np.column_stack([np.ones_like(theta), np.cos(np.outer(theta, k)), np.sin(np.outer(theta, k))])
        coeffs, *_ = np.linalg.lstsq(basis, u[keep] ** 2, rcond=None)
    phase = 2.0 * np.pi * np.arange(samples) / samples
    grid = np.column_stack([np.ones_like(phase), np.cos(np.outer(phase, k)), np.sin(np.outer(phase, k))])
    period = np.sqrt(np.clip(grid @ coeffs, 0.0, None))
    peak = float(np.max(np.abs(u[keep])))
    if np.max(period) > 1.05 * peak + 1.0:
        raise ExperimentError(
            f"{source}: the applied voltage at {f:g} Hz cannot be represented with {harmonics} harmonics "
            f"(projection peaks at {np.max(period):.0f} V, data at {peak:.0f} V); record more samples per period")
    return SampledPeriodic(period, f)


def _interpolant_weights(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """Weights w with sum(w f) = integral over [a, b] of the linear interpolant of (t, f)."""
    w = np.zeros(t.size)
    left, right = t[:-1], t[1:]
    c = np.clip(a, left, right)
    e = np.clip(b, left, right)
    h = right - left
    use = e > c
    w[:-1] += np.where(use, ((right - c) ** 2 - (right - e) ** 2) / (2.0 * h), 0.0)
    w[1:] += np.where(use, ((e - left) ** 2 - (c - left) ** 2) / (2.0 * h), 0.0)
    return w


def period_weights(time_s, frequency_Hz: float, source: str = "sine record", max_gap_samples: float = 3.0):
    """Weights (s) of the samples for the integral over the largest whole number n of periods
    T = 1/f from the first sample: (weights, n, wrapped).

    The window [t0, t0 + n T] is integrated on the linear interpolant of the samples; its end
    falls between two samples in general (interpolated boundary). When the record stops short of
    t0 + n T by at most ``max_gap_samples`` sample intervals (a record of floor(n T f_s) samples,
    or one sample fewer), the periodic steady state supplies the missing end: the integral over
    [t_last, t0 + n T] equals the one over [t_last - T, t0 + (n-1) T], inside the record, so a
    record one sample short does not lose a whole period (``wrapped``). The trapezoidal end
    corrections of the pieces cancel by periodicity: the mean square of a periodic record is
    accurate to ~1e-6 whatever the number of samples per period.
    Raises :class:`ExperimentError` for a record shorter than one period.
    """
    t = np.asarray(time_s, float) - float(time_s[0])
    dt = float(np.median(np.diff(t)))
    period = 1.0 / float(frequency_Hz)
    n = int(math.floor((t[-1] + max_gap_samples * dt * (1.0 + 1e-9)) / period + 1e-12))
    if n < 1:
        raise ExperimentError(f"{source}: shorter than one period at {frequency_Hz:g} Hz")
    end = n * period
    if end <= t[-1]:
        return _interpolant_weights(t, 0.0, end), n, False
    w = _interpolant_weights(t, 0.0, t[-1])
    if t[-1] - period >= 0.0:
        w += _interpolant_weights(t, t[-1] - period, end - period)
    else:  # a single period: close it with the periodic trapezoid d(t0 + T) = d(t0)
        gap = end - t[-1]
        w[-1] += 0.5 * gap
        w[0] += 0.5 * gap
    return w, n, True


def rms_statistics(series: "SineSeries", d0_m: float, noise_m: float | None = None,
                   d0_std_m: float = 0.0) -> tuple:
    """(d_rms, its standard uncertainty or None) of a sampled record over whole periods (eq. 21).

    See :meth:`SineSeries.displacement_rms`. Uncertainty (``noise_m`` given): white noise on
    every sample and the uncertainty of d0, propagated linearly through the weighted mean square.
    """
    w, _n, _wrap = period_weights(series.time_s, series.frequency_Hz, series.source)
    total = float(np.sum(w))
    dev = series.displacement_m - float(d0_m)
    ms = float(w @ (dev * dev)) / total
    if noise_m is not None:
        ms -= float(noise_m) ** 2 + float(d0_std_m) ** 2
    rms = math.sqrt(max(ms, 0.0))
    if noise_m is None or rms <= 0:
        return rms, None
    grad = w * dev / (total * rms)
    mean_dev = float(w @ dev) / total
    var = float(noise_m) ** 2 * float(grad @ grad) + (mean_dev / rms) ** 2 * float(d0_std_m) ** 2
    return rms, math.sqrt(var)


def third_difference_noise(d, min_samples: int = 20) -> float | None:
    """White-noise sigma of samples d from their third differences (variance 20 sigma^2; robust
    spread): slow motion (ringing, creep, a sine well below the sample rate) hardly enters.
    None for fewer than ``min_samples`` samples."""
    d = np.asarray(d, float)
    if d.size < min_samples:
        return None
    d3 = np.diff(d, 3)
    mad = float(np.median(np.abs(d3 - np.median(d3))))
    return 1.4826 * mad / math.sqrt(20.0)


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
        f = _as_array(self.frequency_Hz, "frequency_Hz", src)
        a = _as_array(self.amplitude_V, "amplitude_V", src)
        r = _as_array(self.d_rms_m, "d_rms_m", src)
        arrays = {"frequency_Hz": f, "amplitude_V": a, "d_rms_m": r}
        if self.d0_m is not None:
            arrays["d0_m"] = _as_array(self.d0_m, "d0_m", src)
        if self.d_rms_std_m is not None:
            arrays["d_rms_std_m"] = _as_array(self.d_rms_std_m, "d_rms_std_m", src)
        n = _check_lengths(src, **arrays)
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
        _check_voltage(a, "amplitude_V", src)
        _check_displacement(r, "d_rms_m", src)
        if "d0_m" in arrays:
            _check_displacement(arrays["d0_m"], "d0_m", src)
        if "d_rms_std_m" in arrays:
            std = arrays["d_rms_std_m"]
            if np.any(std <= 0):
                k = int(np.nonzero(std <= 0)[0][0])
                raise ExperimentError(f"{src}, column 'd_rms_std_m', row {k + 1}: a standard uncertainty is > 0, "
                                      f"got {std[k]:g}")
            _check_displacement(std, "d_rms_std_m", src)
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
        return StaticData(
            np.concatenate([s.mass_kg for s in self.static]),
            np.concatenate([s.voltage_V for s in self.static]),
            np.concatenate([s.displacement_m for s in self.static]),
            source=", ".join(s.source for s in self.static),
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


# --------------------------------------------------------------------------- manifest
def _manifest_error(path: Path, msg: str) -> ExperimentError:
    return ExperimentError(f"{path}: {msg}")


def _resolve_parameters(folder: Path, ref: str, manifest: Path) -> MembraneParameters:
    candidate = folder / ref
    try:
        if candidate.is_file():
            return MembraneParameters.from_yaml(candidate)
        if ref.strip().upper() in PRESET_NAMES:
            return load_parameters(ref)
    except ParameterError as exc:
        raise _manifest_error(manifest, f"field 'parameters': {exc}") from None
    raise _manifest_error(
        manifest,
        f"field 'parameters': {ref!r} is neither a file in {folder} nor a preset {PRESET_NAMES}",
    )


def load_experiment_set(folder: str | Path) -> ExperimentSet:
    """Load and validate an experiment folder (see the module docstring for the format)."""
    folder = Path(folder)
    manifest = folder / "manifest.yaml"
    if folder.is_file() and folder.name.endswith((".yaml", ".yml")):
        manifest, folder = folder, folder.parent
    if not manifest.is_file():
        raise ExperimentError(
            f"{folder}: no manifest.yaml; an experiment folder holds manifest.yaml and CSV files "
            "(see dea_ros.identify.experiments)"
        )
    try:
        data = yaml.safe_load(manifest.read_text())
    except yaml.YAMLError as exc:
        raise _manifest_error(manifest, f"not valid YAML ({exc})") from None
    if not isinstance(data, Mapping):
        raise _manifest_error(manifest, "expected a mapping (format, membrane, mass_kg, experiments, ...)")
    known = {"format", "membrane", "parameters", "geometry", "mass_kg", "sensor_noise_m", "units",
             "experiments", "notes"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise _manifest_error(manifest, f"unknown field(s) {unknown}; allowed: {sorted(known)}")
    fmt = data.get("format", FORMAT)
    if fmt != FORMAT:
        raise _manifest_error(manifest, f"field 'format': {fmt!r} is not supported (expected {FORMAT!r})")
    units = data.get("units", {}) or {}
    if not isinstance(units, Mapping):
        raise _manifest_error(manifest, "field 'units': expected a mapping such as {time: s, voltage: V}")
    for quantity, unit in units.items():
        if quantity not in _SI_UNITS:
            raise _manifest_error(manifest, f"field 'units.{quantity}': unknown quantity; known {sorted(_SI_UNITS)}")
        if str(unit) != _SI_UNITS[quantity]:
            raise _manifest_error(
                manifest,
                f"field 'units.{quantity}': '{unit}' is not supported; the format is SI "
                f"({quantity} in {_SI_UNITS[quantity]}): convert the CSV values and state "
                f"'{_SI_UNITS[quantity]}'",
            )
    membrane = data.get("membrane")
    if not isinstance(membrane, str) or not membrane.strip():
        raise _manifest_error(manifest, "field 'membrane': a name is required (e.g. A1)")
    base = None
    ref = data.get("parameters")
    if ref is not None:
        base = _resolve_parameters(folder, str(ref), manifest)
    geometry: dict[str, Any] = {}
    if base is not None:
        geometry.update({k: getattr(base, k) for k in GEOMETRY_FIELDS})
    extra_geometry = data.get("geometry") or {}
    if not isinstance(extra_geometry, Mapping):
        raise _manifest_error(manifest, "field 'geometry': expected a mapping of " + ", ".join(GEOMETRY_FIELDS))
    bad = sorted(set(extra_geometry) - set(GEOMETRY_FIELDS))
    if bad:
        raise _manifest_error(manifest, f"field 'geometry': unknown key(s) {bad}; allowed {list(GEOMETRY_FIELDS)}")
    for k, v in extra_geometry.items():
        try:
            geometry[k] = float(v)
        except (TypeError, ValueError):
            raise _manifest_error(manifest, f"field 'geometry.{k}': must be a number, got {v!r}") from None
    if "mass_kg" not in data:
        raise _manifest_error(manifest, "field 'mass_kg': the biasing mass (kg) is required (3 g -> 0.003)")
    mass = data["mass_kg"]
    if isinstance(mass, bool) or not isinstance(mass, (int, float)):
        raise _manifest_error(manifest, f"field 'mass_kg': must be a number in kg, got {mass!r}")
    noise = data.get("sensor_noise_m")
    entries = data.get("experiments")
    if not isinstance(entries, list) or not entries:
        raise _manifest_error(manifest, "field 'experiments': a non-empty list of {kind, file} is required")
    static, steps, sines = [], [], []
    for k, entry in enumerate(entries):
        where = f"experiments[{k}]"
        if not isinstance(entry, Mapping) or "kind" not in entry or "file" not in entry:
            raise _manifest_error(manifest, f"{where}: needs 'kind' ({'/'.join(KINDS)}) and 'file'")
        kind = entry["kind"]
        if kind not in KINDS:
            raise _manifest_error(manifest, f"{where}.kind: {kind!r} is not one of {KINDS}")
        path = folder / str(entry["file"])
        exp_mass = entry.get("mass_kg", mass)
        try:
            if kind == "static":
                cols = read_csv_columns(path, STATIC_COLUMNS)
                lines = cols["_lines"]
                _check_mass(cols["mass_kg"], "mass_kg", str(path), lines)
                _check_voltage(cols["voltage_V"], "voltage_V", str(path), lines)
                _check_displacement(cols["displacement_m"], "displacement_m", str(path), lines)
                static.append(StaticData(cols["mass_kg"], cols["voltage_V"], cols["displacement_m"], str(path)))
            elif kind == "step":
                cols = read_csv_columns(path, STEP_COLUMNS)
                lines = cols["_lines"]
                _check_time(cols["time_s"], "time_s", str(path), lines)
                _check_displacement(cols["displacement_m"], "displacement_m", str(path), lines)
                steps.append(StepData(cols["time_s"], cols["voltage_V"], cols["displacement_m"],
                                      mass_kg=exp_mass, voltage_hold=entry.get("voltage_hold", "zoh"),
                                      source=str(path)))
            else:
                cols = read_csv_columns(path, SINE_COLUMNS, SINE_OPTIONAL)
                series = []
                for j, item in enumerate(entry.get("series", []) or []):
                    if not isinstance(item, Mapping) or "file" not in item or "frequency_Hz" not in item:
                        raise _manifest_error(manifest, f"{where}.series[{j}]: needs 'frequency_Hz' and 'file'")
                    spath = folder / str(item["file"])
                    scols = read_csv_columns(spath, STEP_COLUMNS)
                    _check_time(scols["time_s"], "time_s", str(spath), scols["_lines"])
                    series.append(SineSeries(float(item["frequency_Hz"]), scols["time_s"], scols["voltage_V"],
                                             scols["displacement_m"], source=str(spath)))
                waveform = entry.get("waveform", "sine")
                if waveform not in WAVEFORMS:
                    raise _manifest_error(manifest, f"{where}.waveform: {waveform!r} is not one of {WAVEFORMS} "
                                                    "(sine: U sin(2 pi f t); abs_sine: |U sin(2 pi f t)|)")
                sines.append(SineData(cols["frequency_Hz"], cols["amplitude_V"], cols["d_rms_m"],
                                      mass_kg=exp_mass, d0_m=cols.get("d0_m"), series=tuple(series),
                                      source=str(path), d_rms_std_m=cols.get("d_rms_std_m"),
                                      waveform=waveform))
        except ParameterError as exc:  # pragma: no cover - defensive
            raise ExperimentError(f"{path}: {exc}") from None
    return ExperimentSet(
        membrane=membrane.strip(), geometry=geometry, mass_kg=float(mass), static=static,
        steps=steps, sines=sines, base_parameters=base,
        base_reference=None if ref is None else str(ref),
        sensor_noise_m=None if noise is None else float(noise), folder=folder,
        notes=str(data.get("notes", "") or ""),
    )


def write_experiment_set(experiments: ExperimentSet, folder: str | Path) -> Path:
    """Write an experiment set as a folder (manifest.yaml + CSV files); return the manifest path.

    A base parameters object is written next to the manifest as ``base_parameters.yaml``
    (unless it was referenced by preset name).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest: dict[str, Any] = {"format": FORMAT, "membrane": experiments.membrane}
    if experiments.base_parameters is not None:
        ref = experiments.base_reference
        if ref is not None and ref.strip().upper() in PRESET_NAMES:
            manifest["parameters"] = ref.strip().upper()
        else:
            experiments.base_parameters.to_yaml(folder / "base_parameters.yaml",
                                                header="base parameters of the experiment set")
            manifest["parameters"] = "base_parameters.yaml"
    manifest["geometry"] = {k: float(experiments.geometry[k]) for k in GEOMETRY_FIELDS}
    manifest["mass_kg"] = float(experiments.mass_kg)
    if experiments.sensor_noise_m is not None:
        manifest["sensor_noise_m"] = float(experiments.sensor_noise_m)
    manifest["units"] = dict(_SI_UNITS)
    entries = []
    for k, s in enumerate(experiments.static):
        name = "static.csv" if len(experiments.static) == 1 else f"static_{k}.csv"
        write_csv_columns(folder / name, {"mass_kg": s.mass_kg, "voltage_V": s.voltage_V,
                                          "displacement_m": s.displacement_m},
                          comment="static points: rest displacement for a mass and a constant voltage (eq. 20)")
        entries.append({"kind": "static", "file": name})
    for k, s in enumerate(experiments.steps):
        name = f"step_{k}_{abs(s.final_V - s.initial_V):.0f}V.csv"
        write_csv_columns(folder / name, {"time_s": s.time_s, "voltage_V": s.voltage_V,
                                          "displacement_m": s.displacement_m},
                          comment=f"voltage step {s.initial_V:g} V -> {s.final_V:g} V, mass {s.mass_kg:g} kg")
        entry = {"kind": "step", "file": name, "voltage_hold": s.voltage_hold}
        if s.mass_kg != experiments.mass_kg:
            entry["mass_kg"] = s.mass_kg
        entries.append(entry)
    for k, s in enumerate(experiments.sines):
        name = "sine_rms.csv" if len(experiments.sines) == 1 else f"sine_rms_{k}.csv"
        cols = {"frequency_Hz": s.frequency_Hz, "amplitude_V": s.amplitude_V, "d_rms_m": s.d_rms_m}
        if s.d0_m is not None:
            cols["d0_m"] = s.d0_m
        if s.d_rms_std_m is not None:
            cols["d_rms_std_m"] = s.d_rms_std_m
        write_csv_columns(folder / name, cols,
                          comment="frequency response: RMS of d - d0 over whole periods (eq. 21, interpolated "
                                  "period boundaries, laser noise removed); d_rms_std_m: its standard uncertainty "
                                  "(optional); excitation u = "
                                  f"{'|U sin(2 pi f t)|' if s.waveform == 'abs_sine' else 'U sin(2 pi f t)'}"
                                  ", U = amplitude_V")
        entry: dict[str, Any] = {"kind": "sine", "file": name, "waveform": s.waveform}
        if s.mass_kg != experiments.mass_kg:
            entry["mass_kg"] = s.mass_kg
        series = []
        for j, ser in enumerate(s.series):
            sname = f"sine_{k}_{j}_{ser.frequency_Hz:g}Hz.csv"
            write_csv_columns(folder / sname, {"time_s": ser.time_s, "voltage_V": ser.voltage_V,
                                               "displacement_m": ser.displacement_m},
                              comment=f"sine record at {ser.frequency_Hz:g} Hz")
            series.append({"frequency_Hz": float(ser.frequency_Hz), "file": sname})
        if series:
            entry["series"] = series
        entries.append(entry)
    manifest["experiments"] = entries
    if experiments.notes:
        manifest["notes"] = experiments.notes
    header = (
        "# dea_ros experiment set (format dea_ros.experiments/1): SI units everywhere.\n"
        "# See dea_ros/identify/experiments.py for the format. d = downward deflection of the mass.\n"
    )
    path = folder / "manifest.yaml"
    path.write_text(header + yaml.safe_dump(manifest, sort_keys=False))
    experiments.folder = folder
    return path


# --------------------------------------------------------------------------- data quality
def estimate_noise_m(step: StepData, min_samples: int = 20) -> float | None:
    """Laser noise sigma (m) of a sampled record, from its third differences.

    For white noise, the third difference has variance 20 sigma^2; the 10-20 Hz motion
    sampled at 1 kHz contributes (omega h)^3 ~ 1e-3 of its amplitude, so the estimate is
    insensitive to the response itself. A robust spread (1.4826 x median absolute deviation)
    ignores the few samples around the voltage step. None for fewer than ``min_samples`` samples.
    """
    return third_difference_noise(step.displacement_m, min_samples)


def rest_warning(step: StepData, noise_m: float | None) -> str | None:
    """A warning when the record does not start at rest before the step (the model assumes it does).

    The pre-step samples (detrended) should only show laser noise; a spread above 3 sigma
    (or 0.5 % of the step response) means the membrane was still moving (a previous segment
    ringing or creeping) and the fit will be biased.
    """
    k0 = step.step_index
    base = step.displacement_m[:k0]
    if base.size < 10 or noise_m is None:
        return None
    t = step.time_s[:k0]
    trend = np.polyval(np.polyfit(t - t[0], base, 1), t - t[0])
    spread = float(np.std(base - trend))
    if spread > 3.0 * noise_m:
        return (
            f"{step.source}: the record does not start at rest: before the step the displacement varies by "
            f"{spread * 1e6:.3g} um RMS (noise {noise_m * 1e6:.3g} um). The model starts from the static "
            "equilibrium, so the fit is biased: let the membrane settle before the step (several "
            "eta1/k1 and the ringing) or start the record later"
        )
    return None


def step_settling_warning(step: StepData, noise_m: float | None) -> str | None:
    """A warning when the step response is still oscillating or drifting at the end of the record.

    Compares the spread of the last 20 % of the post-step record (at least 0.1 s)
    with the first window after the step; a response that keeps more than a
    quarter of its initial oscillation (and more than 3 noise sigmas) has not
    settled, and a drift over the last window extrapolating to more than 10 %
    of the step size over the record is flagged too.
    """
    t, d = step.time_s, step.displacement_m
    k0 = step.step_index
    post_t, post_d = t[k0:], d[k0:]
    if post_t.size < 20:
        return (f"{step.source}: only {post_t.size} samples after the step at {step.step_time_s:g} s; "
                "the step response cannot be judged (record a few seconds after the step)")
    duration = post_t[-1] - post_t[0]
    window = max(0.2 * duration, 0.1)
    first = post_d[post_t <= post_t[0] + window]
    last_mask = post_t >= post_t[-1] - window
    last_t, last_d = post_t[last_mask], post_d[last_mask]
    coef = np.polyfit(last_t - last_t[0], last_d, 1)
    spread_last = float(np.std(last_d - np.polyval(coef, last_t - last_t[0])))
    spread_first = float(np.std(first))
    noise = noise_m if noise_m is not None else 0.0
    baseline = d[:k0]
    step_size = abs(float(np.mean(last_d)) - float(np.mean(baseline if baseline.size else d[:1])))
    if spread_last > 0.25 * spread_first and spread_last > 3.0 * noise:
        return (
            f"{step.source}: the step response has not settled: the last {window:.2g} s still oscillate "
            f"with {spread_last * 1e6:.3g} um RMS ({100 * spread_last / max(spread_first, 1e-30):.0f} % of the "
            "first window after the step). Record longer after the step; the fit may be poor or the rig "
            "unstable (check for a growing oscillation)"
        )
    drift = abs(coef[0]) * duration
    if step_size > 0 and drift > 0.1 * step_size and drift > 3.0 * noise:
        return (
            f"{step.source}: the step response still drifts at the end of the record "
            f"({abs(coef[0]) * 1e6:.3g} um/s over the last {window:.2g} s, {100 * drift / step_size:.0f} % of "
            "the step size over the record): the slow relaxation (eta1) and the final value are poorly "
            "determined; record longer after the step"
        )
    return None


def data_warnings(experiments: ExperimentSet) -> list[str]:
    """Data-quality warnings that do not prevent a fit (unsettled steps, missing data kinds)."""
    out = []
    noise = experiments.sensor_noise_m
    for step in experiments.steps:
        est = estimate_noise_m(step)
        sigma = noise if noise is not None else est
        for w in (rest_warning(step, sigma), step_settling_warning(step, sigma)):
            if w:
                out.append(w)
    if not experiments.static:
        out.append("no static experiment: the static parameters (beta, gamma, eps_r) come from the base "
                   "parameters file unchanged")
    if not experiments.steps and not experiments.sines:
        out.append("no step or sine experiment: k1, eta1, eta2 are not identified")
    return out


__all__ += ["estimate_noise_m", "step_settling_warning", "rest_warning", "data_warnings", "period_weights",
            "rms_statistics", "periodic_input_from_record", "third_difference_noise"]
