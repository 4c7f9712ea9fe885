"""Helpers for the tests that talk real ROS 2 (rclpy over DDS).

from rostest import spin_until  # the ``ros`` fixture is in conftest.py
"""

import time


def spin_until(executor, predicate, timeout_s):
    """Spin until ``predicate()`` holds; False after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
        if predicate():
            return True
    return False
