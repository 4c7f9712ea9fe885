"""The one way every vigil node process starts and stops (ros2/examples talker.py).

Kept apart from the algorithm packages: only node files import it.
"""

from __future__ import annotations

from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def spin_node(
    make_node: Callable[[], Node],
    args: list[str] | None = None,
    on_exit: Callable[[Node], None] | None = None,
) -> None:
    """Init rclpy, spin the node until Ctrl-C or external shutdown, then clean up.

    Args:
        make_node: builds the node (called after rclpy.init).
        args: ROS command-line arguments.
        on_exit: last words while the context is still up (e.g. a zero velocity).
    """
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            if on_exit is not None and rclpy.ok():
                on_exit(node)
            node.destroy_node()
        rclpy.try_shutdown()
