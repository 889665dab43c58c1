"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to test/fakes/fake_uldaq.py.

Loaded by path by test/nodes/test_amplifier_node.py and test/test_rig_check.py; test/ is no package,
so this loads the moved module by path too.
"""
import importlib.util
from pathlib import Path

_spec = importlib.util.spec_from_file_location("fake_uldaq", Path(__file__).parents[1] / "fakes" / "fake_uldaq.py")
_moved = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_moved)
globals().update({name: getattr(_moved, name) for name in _moved.__all__})

__all__ = list(_moved.__all__)
