"""What machine a benchmark ran on (every benchmark prints it with its results)."""
from __future__ import annotations

import os
import platform
from pathlib import Path

__all__ = ["machine_info", "machine"]


def machine_info() -> dict:
    import numpy
    import scipy

    cpu = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"nproc": os.cpu_count(), "cpu": cpu, "python": platform.python_version(),
            "numpy": numpy.__version__, "scipy": scipy.__version__, "platform": platform.platform()}


def machine() -> str:
    m = machine_info()
    return f"{m['cpu']}, {m['nproc']} cores, Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}"
