"""The suite's shared set-up: the test doubles of ``test/fakes`` are importable as ``fakes``.

The suite runs with ``--import-mode=importlib`` (test folders are not packages), so the folder of
this file goes on ``sys.path`` once, here, for ``from fakes import load_fake``.
"""
import sys
from pathlib import Path

TEST_DIR = str(Path(__file__).resolve().parent)
if TEST_DIR not in sys.path:
    sys.path.insert(0, TEST_DIR)
