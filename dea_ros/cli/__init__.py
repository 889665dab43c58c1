"""The ``dea-ros`` command line, on top of the core (no ROS needed but for ``replay``).

* :mod:`.program`: the parser of every command group and the exit codes (0 done, 1 a bug, 2 bad input
  or a :class:`~dea_ros.errors.DeaRosError`, 130 interrupted);
* :mod:`.common`: what every command shares (membrane options, input-file checks, JSON, plots);
* :mod:`.model`: ``equilibrium`` (eq. 20) and ``simulate`` (forward integration);
* :mod:`.sweep`: ``sweep`` (frequency response by harmonic balance);
* :mod:`.identify`: ``synth`` and ``identify`` (one input or many, on the study's engines);
* :mod:`.study`: ``study`` (design studies) and the engine options shared with ``identify``;
* :mod:`.bag`: ``bag info|recover|convert``;
* :mod:`.replay`: ``replay`` (loads the ROS node when it runs: the rest works without ROS 2);
* :mod:`.rig`: ``rig up`` / ``rig demo`` (the rig's nodes as processes, as ``ros2 run`` starts them);
* :mod:`.rig_check`: ``rig check`` (configuration vs connected devices).

Each command module has ``register(subparsers)``.

One BLAS thread per process unless the environment says otherwise (:mod:`dea_ros.blas_threads`),
set before numpy is first imported and inherited by the rig's node processes.
"""
from ..blas_threads import use_one_blas_thread

use_one_blas_thread()

from .program import COMMAND_MODULES, build_parser, main  # noqa: E402 - after the BLAS threads are set

__all__ = ["main", "build_parser", "COMMAND_MODULES"]
