"""TRANSITIONAL re-export (issue 24 phase 2 removes this): moved to dea_ros.bag.mcap_* (see the imports)."""

from .mcap_compression import COMPRESSIONS
from .mcap_contents import McapScan
from .mcap_records import MCAP_MAGIC, has_valid_footer
from .mcap_scan import scan_mcap
from .mcap_writer import McapChunkedWriter

__all__ = ["MCAP_MAGIC", "COMPRESSIONS", "McapChunkedWriter", "McapScan", "scan_mcap", "has_valid_footer"]
