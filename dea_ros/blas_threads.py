"""One BLAS thread per process unless the user's environment says otherwise (issue 22).

The package's linear algebra is small (least-squares Fourier fits of a few thousand samples,
collocation Jacobians of ~100 rows): a BLAS that spreads each call over all cores spin-waits against
the other processes of a busy machine (the rig's nodes, a second job). On the 2-core test machine at
load 3-9 that made the identification of the demo's bag 5-20x slower in CPU (docs/benchmarks.md,
issue 22 session 12). The variables only act when set before numpy is first imported: the command
line (:mod:`dea_ros.cli`) and the nodes (:mod:`dea_ros.nodes`, as ``ros2 run`` starts them) call
:func:`use_one_blas_thread` before anything else; the processes they start inherit it.
"""
import os

__all__ = ["ONE_BLAS_THREAD", "use_one_blas_thread"]

#: The environment variables of the BLAS/OpenMP runtimes numpy and scipy may load, at one thread.
ONE_BLAS_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def use_one_blas_thread() -> None:
    """Set each of :data:`ONE_BLAS_THREAD` that the environment does not set already."""
    for name, value in ONE_BLAS_THREAD.items():
        os.environ.setdefault(name, value)
