"""The numpy reference of the solver kernels (``reference/``) importable from the tests of this folder."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
