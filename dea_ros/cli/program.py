"""``dea-ros``: command line on top of the core (no ROS needed).

Subcommands: ``equilibrium``, ``simulate``, ``sweep`` (model and solvers);
``synth``, ``identify``, ``plan`` (identification); ``replay``, ``bag`` (MCAP logs, with
ROS 2); ``rig`` (the whole rig on mock hardware). ``dea-ros CMD --help`` for each.
Every command takes ``--membrane NAME`` (LP1, A1, A2) or ``--params FILE``,
prints readable text by default and JSON with ``--json``. Errors exit with code
2 and a message naming the file, field or option and the fix; no traceback (an
unexpected exception is reported as an internal error with exit code 1, its
traceback only with ``DEA_ROS_DEBUG=1``).
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback

from ..errors import DeaRosError

__all__ = ["main", "build_parser", "COMMAND_MODULES"]

#: the modules that add command groups to ``dea-ros`` (each has ``register(subparsers)``); a group
#: whose module cannot be imported here (e.g. ``replay`` without rclpy) is left out of the parser
COMMAND_MODULES = ("dea_ros.cli.model", "dea_ros.cli.sweep", "dea_ros.cli.identify", "dea_ros.cli.plan",
                   "dea_ros.cli.study",
                   "dea_ros.cli.bag", "dea_ros.cli.replay", "dea_ros.cli.rig")


def build_parser() -> argparse.ArgumentParser:
    """The ``dea-ros`` argument parser with every command group that can run here."""
    parser = argparse.ArgumentParser(
        prog="dea-ros",
        description="DEA model, harmonic-balance solver and identification (SI units: V, m, s, kg).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in COMMAND_MODULES:
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        register = getattr(mod, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv=None) -> int:
    """Run ``dea-ros`` with ``argv`` (default: the command line); returns the exit code.

    0 success; 2 bad input or a package error (:class:`~dea_ros.errors.DeaRosError`), with a
    one-line message; 1 an unexpected exception (a bug); 130 interrupted.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (DeaRosError, ValueError) as exc:  # the package's errors and bad values: a message, exit 2
        print(f"dea-ros {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file that cannot be read or written: name it
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"dea-ros {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except RecursionError:
        print(f"dea-ros {args.command}: error: an input file is nested too deeply (a YAML of thousands of "
              "nested brackets?)", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"dea-ros {args.command}: error: out of memory; lower the sizes given (--points, --rate, "
              "--duration, --harmonics)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"dea-ros {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - a bug: no traceback for the user unless asked
        if os.environ.get("DEA_ROS_DEBUG"):
            traceback.print_exc()
        print(f"dea-ros {args.command}: internal error ({type(exc).__name__}: {exc}); this is a bug, please "
              "report it with the command line (DEA_ROS_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
