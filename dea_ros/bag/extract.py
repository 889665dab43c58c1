"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.identify.bag_experiments."""
from ..identify.bag_experiments import EXPERIMENT_METADATA, BagSignals, BagTopics, experiments_from_bag, read_signals

__all__ = ["BagTopics", "BagSignals", "read_signals", "experiments_from_bag", "EXPERIMENT_METADATA"]
