"""A node's parameters declared in one call (the block every node used to repeat).

Kept apart from the algorithm packages: only node files import it::

    v = declare(self, config_file="", rate_hz=20.0, lockstep=False)
    topics = declare_topics(self, cmd_vel=topic.CMD_VEL, result=topic.NAV_RESULT)
    ... v.rate_hz ... topics["cmd_vel"] ...

A value comes back with its default's type (rclpy already refuses a parameter file
that gives another type), so a node needs no ``float(...)`` around it.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from rclpy.node import Node


def _typed(default: Any, value: Any) -> Any:
    for kind in (bool, int, float, str):  # bool before int: True is an int too
        if isinstance(default, kind):
            return kind(value)
    return value


def declare(node: Node, **defaults: Any) -> SimpleNamespace:
    """Declare each keyword as a parameter of ``node`` with that default.

    Returns:
        The parameters' values (from the parameter file or command line, else the
        defaults) as attributes named like the keywords.
    """
    return SimpleNamespace(
        **{
            name: _typed(default, node.declare_parameter(name, default).value)
            for name, default in defaults.items()
        }
    )


def declare_topics(node: Node, **defaults: str) -> dict[str, str]:
    """Declare a ``<name>_topic`` parameter for each keyword (defaults: :mod:`stack.topics`).

    Returns:
        name -> the topic to use (a deployment may remap any of them).
    """
    return {
        name: str(node.declare_parameter(f"{name}_topic", default).value)
        for name, default in defaults.items()
    }
