"""Exception and warning types of :mod:`dea_ros.bag`."""

__all__ = ["BagError", "BagWarning", "BagTruncatedWarning"]


class BagError(Exception):
    """A bag cannot be written or read as requested.

    The message always names the file or directory concerned, what is wrong with it and, where
    there is one, the fix (e.g. "run dea_ros.bag.recover_bag(<dir>)").
    """


class BagWarning(UserWarning):
    """A bag was readable but not as expected (e.g. ``metadata.yaml`` missing, fell back to MCAP)."""


class BagTruncatedWarning(BagWarning):
    """An MCAP file ends early (writer killed); only the complete prefix was read."""
