"""Study results on disk: per-chunk files (resumable) and the columnar results file.

Every finished chunk is written at once to ``OUT/chunks/chunk_NNNNNN.json`` (written to a
temporary name, then renamed: a chunk file is complete or absent). The results file is always
assembled from the chunk files in design order, so an interrupted and resumed study writes the
same file as an uninterrupted one. Formats: Parquet (``pyarrow``, optional) or CSV (floats in
``repr`` form: exact round trip); lists (folds, bands) are JSON text in both.
"""
from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np

from .evaluate import COLUMNS

__all__ = ["write_chunk", "read_chunk", "chunk_path", "write_results", "read_results", "parquet_available",
           "parquet_problem", "column_types"]


def parquet_problem() -> str | None:
    """Why Parquet cannot be written here (None: it can). pyarrow must import *and* take numpy arrays:
    a pyarrow built for NumPy 2 imports under NumPy 1.x (Jazzy's apt numpy 1.26) and fails only at its
    first array ("pyarrow requires NumPy 2.0 or newer")."""
    try:
        import pyarrow as pa
        import pyarrow.parquet  # noqa: F401

        pa.array(np.zeros(2))
    except Exception as exc:  # noqa: BLE001 - any failure means: use CSV
        return f"{type(exc).__name__}: {exc}"
    return None


def parquet_available() -> bool:
    """Parquet results can be written (:func:`parquet_problem` found nothing)."""
    return parquet_problem() is None


def column_types(names) -> dict:
    """Column name -> Python type (design: int, varied parameters: float, then :data:`COLUMNS`)."""
    types = {"design": int}
    types.update({n: float for n in names})
    types.update(dict(COLUMNS))
    return types


def chunk_path(out_dir, k: int) -> Path:
    return Path(out_dir) / "chunks" / f"chunk_{k:06d}.json"


def write_chunk(out_dir, k: int, rows: list) -> Path:
    path = chunk_path(out_dir, k)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(rows, allow_nan=True))
    os.replace(tmp, path)
    return path


def read_chunk(out_dir, k: int):
    """The rows of chunk ``k``, or None when it is absent or unreadable (then it is recomputed)."""
    path = chunk_path(out_dir, k)
    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return rows if isinstance(rows, list) else None


def _csv_cell(value, typ) -> str:
    if typ is float:
        x = float(value)
        return "nan" if math.isnan(x) else repr(x)
    if typ is bool:
        return "true" if value else "false"
    return str(value)


def write_results(rows: list, columns: list, path, fmt: str) -> Path:
    """Write ``rows`` (dicts) with ``columns`` as Parquet or CSV (``fmt``)."""
    path = Path(path)
    types = column_types([c for c in columns if c not in dict(COLUMNS) and c != "design"])
    tmp = path.with_name(path.name + ".tmp")
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        arrow = {int: pa.int64(), float: pa.float64(), bool: pa.bool_(), str: pa.string()}
        schema = pa.schema([(c, arrow[types[c]]) for c in columns])
        data = {c: [types[c](r[c]) for r in rows] for c in columns}
        pq.write_table(pa.Table.from_pydict(data, schema=schema), str(tmp))
    else:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(columns)
            for r in rows:
                w.writerow([_csv_cell(r[c], types[c]) for c in columns])
    os.replace(tmp, path)
    return path


def read_results(path) -> dict:
    """Column name -> numpy array (numbers, bools) or list (text) of a results file (Parquet or CSV)."""
    path = Path(path)
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq

        table = pq.read_table(str(path))
        out = {}
        for name in table.column_names:
            values = table.column(name).to_pylist()
            out[name] = values if values and isinstance(values[0], str) else np.array(values)
        return out
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        rows = list(reader)
    types = column_types([c for c in header if c not in dict(COLUMNS) and c != "design"])
    out = {}
    for j, name in enumerate(header):
        col = [r[j] for r in rows]
        typ = types.get(name, str)
        if typ is float:
            out[name] = np.array([float(x) for x in col])
        elif typ is int:
            out[name] = np.array([int(x) for x in col])
        elif typ is bool:
            out[name] = np.array([x == "true" for x in col])
        else:
            out[name] = col
    return out
