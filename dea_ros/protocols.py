"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.identify.protocols."""
from .identify.protocols import Protocol, ProtocolError, Segment, load_protocol, protocol_path

__all__ = ["Protocol", "Segment", "ProtocolError", "load_protocol", "protocol_path"]
