"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.cli.rig."""
from .cli.rig import RigProcesses, register

__all__ = ["RigProcesses", "register"]
