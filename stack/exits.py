"""The exit codes of vigil's node processes (the launcher reads them; no rclpy here).

A node that cannot start exits :data:`EXIT_BAD_CONFIG` with one ``[FATAL]`` line; a node
whose disk is full exits :data:`EXIT_DISK_FULL` (its log may have no room for a line:
the code alone names the cause); the twin bridge exits :data:`EXIT_STALLED` when the
lock-step stalled for good. A signal's death is the launcher's negative code; a node
whose ROS teardown hangs after its last words is ended by its own alarm
(:data:`TEARDOWN_SIGNAL`, :func:`stack.ros_main.spin_node`).
"""

EXIT_BAD_CONFIG = 2
EXIT_STALLED = 3
EXIT_DISK_FULL = 4

# the signal of a node's own teardown alarm: its default action ends the process even when
# the middleware holds the interpreter (a Python handler could not run)
TEARDOWN_SIGNAL = 14  # SIGALRM
TEARDOWN_S = 8.0  # the alarm's delay, from the start of the teardown
