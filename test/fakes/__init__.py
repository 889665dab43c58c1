"""Test doubles, out of the product.

* ``faulty_ild1320.py``: the ILD1320 emulator with fault injection (garbage, corrupted frames,
  silence, wrong replies, ignored commands, byte faults) and the record of emitted samples;
* ``faulty_mock_sensor.py``: the serial-free mock sensor with a lost connection on request;
* ``fake_uldaq.py``: a stand-in for the ``uldaq`` package with the real boards' capabilities;
* ``amplifier_saboteur.py``: a process running amplifier_node next to a node that breaks it
  (run by path: :data:`AMPLIFIER_SABOTEUR`).
* ``membranes.py``: membranes unlike the presets that several test modules use (test data).

``load_fake(name)`` gives a fresh module object each call, so module-level state of a fake (the
fake uldaq's call log, its board) never leaks from one test into the next.
"""
import importlib.util
from pathlib import Path
from types import ModuleType

__all__ = ["FAKES_DIR", "AMPLIFIER_SABOTEUR", "load_fake"]

FAKES_DIR = Path(__file__).resolve().parent
#: the saboteur script, started as its own process by the attack tests
AMPLIFIER_SABOTEUR = FAKES_DIR / "amplifier_saboteur.py"


def load_fake(name: str) -> ModuleType:
    """A fresh instance of the test double ``test/fakes/<name>.py``."""
    spec = importlib.util.spec_from_file_location(name, FAKES_DIR / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
