"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.hardware.laser.ild1320_serial.

SampleClock: moved to dea_ros.hardware.laser.sample_clock.
"""
from .laser.ild1320_serial import ILD1320Sensor, describe_ild1320
from .laser.sample_clock import SampleClock

__all__ = ["SampleClock", "ILD1320Sensor", "describe_ild1320"]
