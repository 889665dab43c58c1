"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to test/fakes/amplifier_saboteur.py.

test/nodes/test_amplifier_attacks.py runs this script by path; it runs the moved one with the same arguments.
"""
import runpy
from pathlib import Path

if __name__ == "__main__":
    runpy.run_path(str(Path(__file__).parents[1] / "fakes" / "amplifier_saboteur.py"), run_name="__main__")
