"""The package's shape, enforced (issue 24).

* One error family: every exception class dea_ros defines derives from
  :class:`dea_ros.errors.DeaRosError` (every warning from :class:`dea_ros.errors.DeaRosWarning`),
  so a caller can catch "an error of this package"; the command line turns any of them into a
  message and exit code 2.
* Layers you can see in the tree: imports point down the graph :data:`ALLOWED_IMPORTS` (no
  package imports a package above it), rclpy and the ROS messages only in ``nodes/``.
* One concept per file and readable functions: no function over 80 lines, no file over 700, no
  private name imported from another module, no package import hidden inside a function (outside
  the command line, which loads a command's modules when it runs; optional dependencies may be
  imported where they are used).
"""
import ast
import importlib
import inspect
import pkgutil
import sys
from pathlib import Path

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
        except ImportError as exc:  # rclpy, the ROS messages, uldaq, ... not installed here
            if not any(name in str(exc) for name in ROS_MODULES | {"uldaq", "serial", "rosidl"}):
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


# ---------------------------------------------------------------------------------------- layers
PACKAGE_DIR = Path(dea_ros.__file__).resolve().parent
#: subpackage -> the subpackages it may import ("" is dea_ros/__init__: the version)
ALLOWED_IMPORTS = {
    "errors": set(),
    "blas_threads": set(),
    "": set(),
    "model": {"errors"},
    "solvers": {"errors", "model"},
    "hardware": {"errors", "model"},
    "bag": {"errors", ""},
    "sim": {"errors", "model", "solvers", "hardware"},
    "identify": {"errors", "model", "solvers", "bag"},
    "study": {"errors", "blas_threads", "model", "solvers"},
    "control": {"errors", "model", "solvers", "hardware", "sim"},
    "nodes": {"errors", "blas_threads", "", "model", "solvers", "hardware", "bag", "sim", "identify", "study",
              "control"},
    "cli": {"errors", "blas_threads", "", "model", "solvers", "hardware", "bag", "sim", "identify", "study",
            "control", "nodes"},
}
ROS_MODULES = {"rclpy", "std_msgs", "sensor_msgs", "trajectory_msgs", "diagnostic_msgs", "lifecycle_msgs",
               "rosgraph_msgs", "rcl_interfaces", "std_srvs", "builtin_interfaces", "rosidl_runtime_py"}
#: third-party modules a module may import where it uses them (optional, or heavy and rarely needed)
OPTIONAL_MODULES = {"numba", "dask", "distributed", "pyarrow", "pandas", "tqdm", "uldaq", "serial", "mousai",
                    "matplotlib", "zstandard", "lz4", "ament_index_python"} | ROS_MODULES


def source_files():
    return sorted(p for p in PACKAGE_DIR.rglob("*.py") if "__pycache__" not in p.parts)


def subpackage(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR).with_suffix("")
    return "" if rel.parts == ("__init__",) else rel.parts[0]


def imported_modules(path: Path, tree: ast.AST):
    """(node, absolute module name) of every import in the file, relative ones resolved."""
    package = ["dea_ros"] + list(path.relative_to(PACKAGE_DIR).parent.parts)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                yield node, ".".join(base + ([node.module] if node.module else []))
            else:
                yield node, node.module or ""
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node, alias.name


def enclosing_function(tree: ast.AST, target: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if any(child is target for child in ast.walk(node)):
                return node
    return None


@pytest.fixture(scope="module")
def parsed():
    return [(path, ast.parse(path.read_text())) for path in source_files()]


def test_imports_point_down_the_layers(parsed):
    wrong = []
    for path, tree in parsed:
        here = subpackage(path)
        for node, module in imported_modules(path, tree):
            parts = module.split(".")
            if parts[0] != "dea_ros":
                continue
            there = parts[1] if len(parts) > 1 else ""
            if there not in ALLOWED_IMPORTS:  # a module directly in dea_ros/ other than errors
                there = parts[1]
            if there != here and there not in ALLOWED_IMPORTS.get(here, set()):
                wrong.append(f"{path.relative_to(PACKAGE_DIR)}:{node.lineno}: {here or 'dea_ros'} imports {module}")
    assert not wrong, "imports against the layers (ALLOWED_IMPORTS):\n" + "\n".join(wrong)


def test_every_module_belongs_to_a_layer():
    unknown = {subpackage(p) for p in source_files()} - set(ALLOWED_IMPORTS)
    assert not unknown, f"modules outside the layers of ALLOWED_IMPORTS: {sorted(unknown)}"


def test_ros_is_imported_only_by_the_nodes(parsed):
    wrong = [f"{path.relative_to(PACKAGE_DIR)}:{node.lineno}: {module}" for path, tree in parsed
             for node, module in imported_modules(path, tree)
             if module.split(".")[0] in ROS_MODULES and subpackage(path) != "nodes"]
    assert not wrong, f"ROS imported outside dea_ros/nodes: {wrong}"


def test_no_private_name_is_imported_from_another_module(parsed):
    wrong = [f"{path.relative_to(PACKAGE_DIR)}:{node.lineno}: {alias.name} from {module}" for path, tree in parsed
             for node, module in imported_modules(path, tree) if isinstance(node, ast.ImportFrom)
             for alias in node.names if alias.name.startswith("_") and not alias.name.startswith("__")]
    assert not wrong, f"private names imported across modules: {wrong}"


def test_package_imports_are_at_the_top_of_modules(parsed):
    hidden = []
    for path, tree in parsed:
        if subpackage(path) == "cli":
            continue
        for node, module in imported_modules(path, tree):
            top = module.split(".")[0]
            if top in OPTIONAL_MODULES or top in sys.stdlib_module_names:
                continue
            function = enclosing_function(tree, node)
            if function is not None:
                hidden.append(f"{path.relative_to(PACKAGE_DIR)}:{node.lineno} in {function.name}(): {module}")
    assert not hidden, "imports hidden inside functions:\n" + "\n".join(hidden)


def test_functions_and_files_stay_readable(parsed):
    long_functions = [f"{path.relative_to(PACKAGE_DIR)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1})"
                      for path, tree in parsed for node in ast.walk(tree)
                      if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                      and node.end_lineno - node.lineno + 1 > 80]
    long_files = [f"{path.relative_to(PACKAGE_DIR)} ({len(path.read_text().splitlines())})" for path, _ in parsed
                  if len(path.read_text().splitlines()) > 700]
    assert not long_functions, f"functions over 80 lines: {long_functions}"
    assert not long_files, f"files over 700 lines: {long_files}"
