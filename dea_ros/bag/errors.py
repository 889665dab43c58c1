"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.errors."""

from ..errors import BagError, BagTruncatedWarning, BagWarning

__all__ = ["BagError", "BagWarning", "BagTruncatedWarning"]
