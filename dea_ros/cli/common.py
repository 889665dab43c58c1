"""What every ``dea-ros`` command shares: membrane options, input-file checks, JSON output, plots.

Bad input raises :class:`~dea_ros.errors.CliError` with a message naming the option or file and
the fix; :func:`dea_ros.cli.program.main` prints it and exits with code 2.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from ..errors import CliError, DeaRosError
from ..model import load_parameters

__all__ = ["read_input_file", "check_output_file", "add_membrane_args", "load_membrane", "finite",
           "json_default", "print_json", "matplotlib_pyplot"]


def read_input_file(option: str, path, loader):
    """``loader(path)`` with the errors of a bad input file turned into a CliError naming it."""
    try:
        return loader(path)
    except DeaRosError as exc:
        if isinstance(exc.__cause__, (UnicodeDecodeError, OSError)):  # a file it could not read: name the option
            raise CliError(f"{option} {exc}") from None
        raise
    except RecursionError:
        raise CliError(f"{option} {path}: nested too deeply to be a dea_ros input (a YAML of "
                       "thousands of nested brackets?)") from None
    except UnicodeDecodeError:
        raise CliError(f"{option} {path}: not a text file (binary content); give the YAML/CSV file") from None
    except IsADirectoryError:
        raise CliError(f"{option} {path}: is a directory, a file is needed") from None
    except PermissionError:
        raise CliError(f"{option} {path}: permission denied") from None


def check_output_file(option: str, path) -> None:
    """Fail before the work when an output file cannot be written (missing folder, a directory)."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise CliError(f"{option} {path}: is a directory; give a file name")
    if not p.parent.is_dir():
        raise CliError(f"{option} {path}: folder {p.parent} does not exist; create it first")


# ------------------------------------------------------------------ helpers
def add_membrane_args(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--membrane", metavar="NAME", help="preset membrane: LP1, A1 or A2 (default A2)")
    group.add_argument("--params", metavar="FILE", help="parameters YAML (e.g. an identified params.yaml)")
    parser.add_argument("--mass", type=float, metavar="KG", help="override the mass, kg (e.g. 0.003)")


def load_membrane(args):
    option = "--params" if args.params else "--membrane"
    params = read_input_file(option, args.params or args.membrane or "A2", load_parameters)
    if getattr(args, "mass", None) is not None:
        params = params.replace(mass_kg=args.mass)
    return params


def finite(name: str, value: float, positive: bool = False) -> float:
    if value is None or not math.isfinite(value) or (positive and value <= 0):
        raise CliError(f"{name}: must be a {'positive ' if positive else ''}finite number, got {value}")
    return value


def json_default(obj):
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, complex):
        return [obj.real, obj.imag]
    raise TypeError(type(obj).__name__)


def print_json(data) -> None:
    print(json.dumps(data, indent=2, default=json_default, allow_nan=True))


def matplotlib_pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
