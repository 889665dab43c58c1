"""CSV files of the experiment format: numeric columns named with their SI unit.

Comma separated, ``#`` starts a comment line, the first other line is the header; every column
name ends with its unit (``_s``, ``_V``, ``_m``, ``_kg``, ``_Hz``). A header naming the right
quantity in another unit (``displacement_mm``) or without one is diagnosed with the conversion
to SI. Written with full double precision (``repr`` of every value), so a set written and read
back is bit-identical.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from ...errors import ExperimentError

__all__ = ["read_csv_columns", "write_csv_columns"]

#: Other spellings people use for a unit, with the conversion to SI.
_WRONG_UNITS = {
    "m": {"mm": "divide by 1000", "um": "divide by 1e6", "µm": "divide by 1e6",
          "micron": "divide by 1e6", "cm": "divide by 100", "nm": "divide by 1e9"},
    "V": {"kV": "multiply by 1000", "kv": "multiply by 1000", "mV": "divide by 1000", "v": "write V"},
    "s": {"ms": "divide by 1000", "us": "divide by 1e6", "min": "multiply by 60"},
    "kg": {"g": "divide by 1000", "mg": "divide by 1e6"},
    "Hz": {"kHz": "multiply by 1000", "hz": "write Hz", "rad_s": "divide by 2 pi"},
}


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
