"""The ``dea-ros`` command line, on top of the core (no ROS needed but for ``replay``).

* :mod:`.program`: the parser of every command group and the exit codes (0 done, 1 a bug, 2 bad input
  or a :class:`~dea_ros.errors.DeaRosError`, 130 interrupted);
* :mod:`.common`: what every command shares (membrane options, input-file checks, JSON, plots);
* :mod:`.model`: ``equilibrium`` (eq. 20) and ``simulate`` (forward integration);
* :mod:`.sweep`: ``sweep`` (frequency response by harmonic balance);
* :mod:`.rig`: ``rig up`` / ``rig demo`` (the rig's nodes as processes, as ``ros2 run`` starts them);
* :mod:`.rig_check`: ``rig check`` (configuration vs connected devices).

Each command module has ``register(subparsers)``; a command loads the core modules it needs when
it runs, so ``dea-ros --help`` stays quick.
"""
from .program import COMMAND_MODULES, build_parser, main

__all__ = ["main", "build_parser", "COMMAND_MODULES"]
