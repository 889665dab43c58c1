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

One BLAS thread per process unless the user's environment says otherwise (``OPENBLAS_NUM_THREADS``,
``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``; set here, before numpy is first imported, and inherited by
the rig's node processes): the identification's linear algebra is small (least-squares Fourier fits
of a few thousand samples, collocation Jacobians of ~100 rows), and a BLAS spreading each call over
all cores spin-waits against the other processes of a busy machine. On the 2-core test machine at
load 3-9 that made ``dea-ros identify`` of the demo's bag 5-20x slower (docs/benchmarks.md, issue 22
session 12); the results differ only in floating-point round-off.
"""
import os

for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from .program import COMMAND_MODULES, build_parser, main  # noqa: E402 - after the BLAS threads are set

__all__ = ["main", "build_parser", "COMMAND_MODULES"]
