"""Dependencies a lab PC can satisfy: every runtime import is declared, with a valid rosdep key.

* package.xml declares every third-party module dea_ros/ imports (at module level or inside a
  function) with a rosdep key: the ROS packages of the Humble and Jazzy distributions, or a key of
  rosdistro's rosdep/python.yaml (checked there for the keys listed in ROSDEP_KEYS below);
* setup.py's install_requires covers the same modules for pip; the optional ones (mousai, uldaq) are
  extras and are imported only inside the functions that need them;
* requirements.txt states the same minimum versions as setup.py.
"""
import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: import name -> rosdep key (ROS packages: their own name; Python libraries: rosdep/python.yaml keys,
#: checked in ros/rosdistro rosdep/python.yaml: python3-numpy, python3-scipy, python3-yaml,
#: python3-matplotlib, python3-serial, and the pip key mcap-ros2-support, whose package brings mcap)
ROSDEP_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "serial": "python3-serial",
    "mcap": "mcap-ros2-support",
    "mcap_ros2": "mcap-ros2-support",
    # mcap's own dependencies, used for compressed chunks
    "zstandard": "mcap-ros2-support",
    "lz4": "mcap-ros2-support",
    # required: the solvers' compiled kernels
    "numba": "python3-numba",
}
#: ROS packages of both distributions (ros/rosdistro humble/ and jazzy/distribution.yaml)
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "builtin_interfaces", "std_msgs", "sensor_msgs", "std_srvs",
                "diagnostic_msgs", "lifecycle_msgs", "rosgraph_msgs", "trajectory_msgs", "ament_index_python",
                "launch", "launch_ros"}
#: pip distribution of each Python import (setup.py install_requires)
PIP_NAMES = {"numpy": "numpy", "scipy": "scipy", "yaml": "PyYAML", "matplotlib": "matplotlib", "serial": "pyserial",
             "mcap": "mcap", "mcap_ros2": "mcap-ros2-support", "zstandard": "mcap", "lz4": "mcap", "numba": "numba"}
#: optional: no rosdep key; extras of setup.py, imported only where needed
OPTIONAL = {"mousai": "mousai", "uldaq": "uldaq", "dask": "dask", "distributed": "distributed",
            "pyarrow": "pyarrow", "tqdm": "tqdm"}


def imports(path: Path):
    """(module, top level?) of every absolute import in a file."""
    tree = ast.parse(path.read_text(), str(path))
    top = {id(n) for n in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name.split(".")[0], id(node) in top, node.lineno
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module.split(".")[0], id(node) in top, node.lineno
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module" and node.args \
                and isinstance(node.args[0], ast.Constant):
            yield str(node.args[0].value).split(".")[0], False, node.lineno


def third_party_imports() -> dict:
    stdlib = set(sys.stdlib_module_names) if hasattr(sys, "stdlib_module_names") else set()
    found = {}
    for path in sorted((ROOT / "dea_ros").rglob("*.py")):
        for module, top, line in imports(path):
            if module in stdlib or module in ("dea_ros", "__future__"):
                continue
            found.setdefault(module, []).append((path.relative_to(ROOT), top, line))
    return found


def package_xml(tag: str) -> set:
    return {e.text.strip() for e in ET.parse(ROOT / "package.xml").getroot().iter(tag)}


def setup_py() -> tuple:
    """install_requires and extras_require of setup.py (read from its AST: nothing is run)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    kw = {k.arg: k.value for k in call.keywords}
    return ast.literal_eval(kw["install_requires"]), ast.literal_eval(kw["extras_require"])


def requirement_name(req: str) -> str:
    return re.split(r"[<>=!\[ ;]", req, maxsplit=1)[0].lower()


@pytest.mark.skipif(not hasattr(sys, "stdlib_module_names"), reason="needs Python >= 3.10")
def test_every_runtime_import_has_a_rosdep_key_in_package_xml():
    exec_depends = package_xml("exec_depend")
    missing = []
    for module, where in third_party_imports().items():
        if module in OPTIONAL:
            continue
        key = module if module in ROS_PACKAGES else ROSDEP_KEYS.get(module)
        if key is None:
            missing.append(f"{module} (imported in {where[0][0]}:{where[0][2]}): no known rosdep key")
        elif key not in exec_depends:
            missing.append(f"{module}: <exec_depend>{key}</exec_depend> missing in package.xml")
    assert not missing, "\n".join(missing)


def test_package_xml_uses_only_checked_rosdep_keys():
    for key in package_xml("exec_depend"):
        assert key in ROS_PACKAGES or key in ROSDEP_KEYS.values(), f"package.xml: unchecked rosdep key {key!r}"


@pytest.mark.skipif(not hasattr(sys, "stdlib_module_names"), reason="needs Python >= 3.10")
def test_setup_py_requires_every_python_import_and_the_optional_ones_are_extras():
    install_requires, extras = setup_py()
    required = {requirement_name(r) for r in install_requires}
    for module in third_party_imports():
        if module in ROS_PACKAGES:
            continue
        if module in OPTIONAL:
            assert OPTIONAL[module] in {requirement_name(r) for reqs in extras.values() for r in reqs}, module
        else:
            assert PIP_NAMES[module].lower() in required, f"setup.py install_requires lacks {PIP_NAMES[module]}"
    assert not any(n.startswith("ros-") for n in required), "ROS packages never come from install_requires"


def test_optional_packages_are_imported_only_where_needed():
    """mousai (method mousai) and uldaq (backend uldaq): never at module level, so the rest works without them."""
    for module, where in third_party_imports().items():
        if module in OPTIONAL:
            top = [f"{path}:{line}" for path, is_top, line in where if is_top]
            assert not top, f"{module} imported at module level in {top}: make it optional"


def test_requirements_txt_matches_setup_py():
    install_requires, _ = setup_py()
    lines = [ln.split("#")[0].strip() for ln in (ROOT / "requirements.txt").read_text().splitlines()]
    assert sorted(filter(None, lines)) == sorted(install_requires)


def test_without_mousai_method_mousai_says_how_to_get_it(monkeypatch):
    """The optional extra missing: a clear error naming the fix, everything else unaffected."""
    from dea_ros.model import preset
    from dea_ros.solvers import HarmonicBalanceError, SinePeriodic, solve_native
    from dea_ros.solvers.steady_state import solve_periodic

    monkeypatch.setitem(sys.modules, "mousai", None)  # import mousai -> ImportError
    a2 = preset("A2")
    with pytest.raises(HarmonicBalanceError, match=r"pip install mousai"):
        solve_periodic(a2, SinePeriodic(2500.0, 5.0), method="mousai", n_harmonics=4)
    assert solve_native(a2, SinePeriodic(2500.0, 5.0), n_harmonics=4).residual < 1e-8
