"""Exception and warning types of :mod:`dea_ros.bag`."""

from ..errors import BagError, BagTruncatedWarning, BagWarning

__all__ = ["BagError", "BagWarning", "BagTruncatedWarning"]
