r"""Running nodes: one node per process (``ros2 run``), or several on one executor (the rig).

Both paths install SIGINT/SIGTERM/SIGHUP/SIGQUIT handling (Ctrl-C, kill, a closed SSH
session, Ctrl-\) that lets a node's ``shutdown_safely()`` (the amplifier ramps its voltage
to 0 V) run before rclpy goes down, and SIGUSR1 as a diagnostic: ``kill -USR1 <pid>`` prints
the stack of every thread of the node to stderr (:mod:`faulthandler`) and the node goes on --
for a node that hangs, before it is killed. A teardown after ``shutdown_safely()`` (destroying
the nodes, rclpy's shutdown, the interpreter's exit) that takes longer than
:data:`TEARDOWN_REPORT_S` prints the same stacks by itself.
"""
from __future__ import annotations

import faulthandler
import os
import signal
import sys

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor

__all__ = ["run_node", "run_nodes", "TEARDOWN_REPORT_S"]

#: A teardown still running after this long prints every thread's stack to stderr (it is not stopped), s.
TEARDOWN_REPORT_S = 8.0


def _safe_shutdown(nodes) -> None:
    for node in nodes:
        hook = getattr(node, "shutdown_safely", None)
        if hook is not None:
            try:
                hook()
            except Exception as exc:  # noqa: BLE001 - keep shutting the others down
                print(f"{node.get_name()}: shutdown_safely failed: {exc}", file=sys.stderr)


def _executor(threads: int):
    """The executor: rclpy's C++ EventsExecutor when ``DEA_ROS_EXECUTOR=events`` and this rclpy has it (Kilted
    and newer; the simulated rig of ``dea-ros rig demo`` asks for it: a callback costs a fraction of the
    Python executor's), else the single-threaded (or, with ``threads`` > 1, the multi-threaded) executor."""
    if os.environ.get("DEA_ROS_EXECUTOR", "") == "events" and threads == 1:
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # Humble, Jazzy: the Python executor
            pass
        else:
            return EventsExecutor()
    return MultiThreadedExecutor(threads) if threads > 1 else SingleThreadedExecutor()


def run_nodes(factories, args=None, threads: int = 1) -> None:
    """Create the nodes (callables returning a Node) and spin them until SIGINT/SIGTERM."""
    rclpy.init(args=args)
    nodes = []
    stop = {"requested": False}

    def on_signal(signum, _frame):
        stop["requested"] = True

    catchable = [getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT") if hasattr(signal, name)]
    old = {s: signal.signal(s, on_signal) for s in catchable}
    if hasattr(signal, "SIGUSR1"):
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    executor = _executor(threads)
    try:
        for factory in factories:
            node = factory()
            nodes.append(node)
            executor.add_node(node)
        while rclpy.ok() and not stop["requested"]:
            executor.spin_once(timeout_sec=0.1)
            if any(getattr(n, "finished", False) for n in nodes):
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        _safe_shutdown(nodes)           # the nodes' own stop (0 V, the bag closed): as long as it needs
        faulthandler.dump_traceback_later(TEARDOWN_REPORT_S)
        for s, h in old.items():
            signal.signal(s, h)
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        faulthandler.cancel_dump_traceback_later()


def run_node(factory, args=None) -> None:
    """``ros2 run dea_ros <node>`` entry point body."""
    run_nodes([factory], args=args if args is not None else sys.argv)
    faulthandler.dump_traceback_later(TEARDOWN_REPORT_S)   # the process exits next (threads joined, atexit)
