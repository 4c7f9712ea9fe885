"""The exit codes of vigil's node processes (the launcher reads them; no rclpy here).

A node that cannot start exits :data:`EXIT_BAD_CONFIG` with one ``[FATAL]`` line; a node
whose disk is full exits :data:`EXIT_DISK_FULL` (its log may have no room for a line:
the code alone names the cause); the twin bridge exits :data:`EXIT_STALLED` when the
lock-step stalled for good. A signal's death is the launcher's negative code.
"""

EXIT_BAD_CONFIG = 2
EXIT_STALLED = 3
EXIT_DISK_FULL = 4
