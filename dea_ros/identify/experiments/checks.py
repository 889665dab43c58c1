"""Plausibility checks of measured columns: finite numbers, equal lengths, SI units, increasing time.

Every check raises :class:`~dea_ros.errors.ExperimentError` naming the source (file), the column
and, where it applies, the line of the file (``lines``: the 1-based line number of each row, as
:func:`~dea_ros.identify.experiments.csv_io.read_csv_columns` returns them) or the row. The limits
are those of a DEA rig: deflections below 2 cm, kilovolts (not kV), grams converted to kg,
seconds (not ms) at a sampling rate resolving the 10-20 Hz dynamics.
"""
from __future__ import annotations

import numpy as np

from ...errors import ExperimentError

__all__ = ["as_finite_array", "check_lengths", "check_displacement", "check_voltage", "check_mass", "check_time"]


def _line_of(lines: np.ndarray | None, k: int) -> str:
    return f"line {int(lines[k])}" if lines is not None and k < lines.size else f"row {k + 1}"


def as_finite_array(value, name: str, source: str) -> np.ndarray:
    """``value`` as a flat float array; every value finite (else the row is named)."""
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


def check_lengths(source: str, **arrays: np.ndarray) -> int:
    """The common length of the named columns (all of them the same, else an error)."""
    sizes = {k: v.size for k, v in arrays.items()}
    if len(set(sizes.values())) != 1:
        raise ExperimentError(
            f"{source}: columns have inconsistent lengths {sizes}; every column needs one value per sample"
        )
    return next(iter(sizes.values()))


def check_displacement(d: np.ndarray, name: str, source: str, lines=None) -> None:
    """Displacements in metres: none beyond 2 cm (values in mm or um are named)."""
    k = int(np.argmax(np.abs(d)))
    if abs(d[k]) > 0.02:
        raise ExperimentError(
            f"{source}, column '{name}', {_line_of(lines, k)}: {d[k]:g} m is beyond any DEA "
            "deflection (the membranes move < 2 mm); values look like millimetres or "
            "micrometres: convert to metres (mm / 1000)"
        )


def check_voltage(u: np.ndarray, name: str, source: str, lines=None) -> None:
    """Voltages in volts: a peak below 50 V looks like kV, one above 100 kV is no amplifier's."""
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


def check_mass(m: np.ndarray, name: str, source: str, lines=None) -> None:
    """Masses in kg: none negative, none above 0.5 kg (grams are named)."""
    if np.any(m < 0):
        k = int(np.nonzero(m < 0)[0][0])
        raise ExperimentError(f"{source}, column '{name}', {_line_of(lines, k)}: negative mass {m[k]:g} kg")
    k = int(np.argmax(m)) if m.size else 0
    if m.size and m[k] > 0.5:
        raise ExperimentError(
            f"{source}, column '{name}', {_line_of(lines, k)}: {m[k]:g} kg is far more than a "
            "membrane carries; values look like grams: convert to kg (3 g -> 0.003)"
        )


def check_time(t: np.ndarray, name: str, source: str, lines=None) -> None:
    """Sample times in seconds: strictly increasing, under an hour, sampled finer than 20 ms."""
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
