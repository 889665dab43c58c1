"""``python -m dea_ros.cli``: the same as the ``dea-ros`` command."""
import sys

from .program import main

sys.exit(main())
