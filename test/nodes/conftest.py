"""Node tests: real rclpy. Each test session uses its own ROS domain so parallel runs do not mix."""
import os

import pytest

os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")

rclpy = pytest.importorskip("rclpy")


@pytest.fixture
def ros_context():
    """A fresh rclpy context per test (init/shutdown)."""
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    if ctx.ok():
        rclpy.shutdown(context=ctx)


def _spin_until(executor, predicate, timeout_s=10.0):
    import time

    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        executor.spin_once(timeout_sec=0.01)
        if predicate():
            return True
    return False


@pytest.fixture
def spin_until():
    """spin_until(executor, predicate, timeout_s=10) -> bool: spin until the predicate holds."""
    return _spin_until
