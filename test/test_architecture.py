"""The package's shape, enforced: one error family.

Every exception class dea_ros defines derives from :class:`dea_ros.errors.DeaRosError` (and every
warning from :class:`dea_ros.errors.DeaRosWarning`), so a caller can catch "an error of this
package"; the command line turns any of them into a message and exit code 2.
"""
import importlib
import inspect
import pkgutil

import pytest

import dea_ros
from dea_ros.cli import program
from dea_ros.errors import ContinuationError, DeaRosError, DeaRosWarning


def package_modules():
    """Every importable module of dea_ros (modules needing rclpy are skipped where it is missing)."""
    found = []
    for info in pkgutil.walk_packages(dea_ros.__path__, "dea_ros."):
        if info.name.endswith(".__main__"):  # runs a program when imported
            continue
        try:
            found.append(importlib.import_module(info.name))
        except ImportError as exc:  # rclpy, uldaq, ... not installed here
            optional = ("rclpy", "std_msgs", "sensor_msgs", "uldaq", "serial", "trajectory_msgs", "diagnostic_msgs",
                        "rosidl")
            if not any(name in str(exc) for name in optional):
                raise
    return found


def test_every_exception_class_of_the_package_is_a_dea_ros_error():
    offenders = []
    checked = 0
    for module in package_modules():
        for name, obj in vars(module).items():
            if not inspect.isclass(obj) or obj.__module__ != module.__name__:
                continue
            if issubclass(obj, Warning):
                checked += 1
                if not issubclass(obj, DeaRosWarning):
                    offenders.append(f"{module.__name__}.{name} (a warning outside DeaRosWarning)")
            elif issubclass(obj, BaseException):
                checked += 1
                if not issubclass(obj, DeaRosError):
                    offenders.append(f"{module.__name__}.{name}")
    assert checked >= 25, f"only {checked} error classes found: is the walk broken?"
    assert not offenders, f"error classes outside the DeaRosError family: {offenders}"


def test_every_error_class_is_defined_in_dea_ros_errors():
    elsewhere = []
    for module in package_modules():
        for name, obj in vars(module).items():
            if inspect.isclass(obj) and issubclass(obj, (BaseException, Warning)) \
                    and obj.__module__.startswith("dea_ros") and obj.__module__ != "dea_ros.errors":
                elsewhere.append(f"{obj.__module__}.{name}")
    assert not elsewhere, f"error classes outside dea_ros/errors.py: {sorted(set(elsewhere))}"


@pytest.mark.parametrize("builtin", [ValueError, RuntimeError])
def test_the_family_keeps_the_builtin_bases_callers_catch(builtin):
    from dea_ros import errors

    classes = [getattr(errors, n) for n in errors.__all__]
    assert any(issubclass(c, builtin) for c in classes)
    assert issubclass(errors.ParameterError, ValueError) and issubclass(errors.HarmonicBalanceError, RuntimeError)


def test_the_cli_turns_any_package_error_into_exit_2(monkeypatch, capsys):
    def failing(args):
        raise ContinuationError("the branch could not be followed (step size underflow)")

    parser = program.build_parser()
    original = parser.parse_args

    def parse_args(argv=None):
        args = original(argv)
        args.func = failing
        return args

    monkeypatch.setattr(program, "build_parser", lambda: parser)
    monkeypatch.setattr(parser, "parse_args", parse_args)
    assert program.main(["equilibrium", "--membrane", "A2", "--voltage", "0"]) == 2
    err = capsys.readouterr().err
    assert "dea-ros equilibrium: error: the branch could not be followed" in err
    assert "Traceback" not in err
