"""Shared test set-up.

ROS 2 tests talk real DDS. Each pytest process gets its own domain id and stays on
localhost so that concurrent test runs (and any robot on the network) never hear
each other. MuJoCo renders headless through EGL.
"""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


import pytest  # noqa: E402


@pytest.fixture
def ros():
    """rclpy initialised for one test, and an executor to spin its nodes."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    executor = SingleThreadedExecutor()
    yield executor
    executor.shutdown()
    rclpy.shutdown()
