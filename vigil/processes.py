"""What a node process is: the launcher's unit, built by :mod:`vigil.system`."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class ProcessSpec:
    """One node process.

    Attributes:
        name: the node's name (also the log file's).
        module: the Python module with ``main()``.
        params_file: the ROS parameters file (``--ros-args --params-file``).
        restart: start it again when it exits while the system runs.
        env: extra environment variables.
        command: run this instead of the module (any program).
        nice: added to its niceness (lower CPU priority): in real-time mode the nodes
            yield the cores to the twin, which stands for the physical world.
    """

    name: str
    module: str
    params_file: Path | None = None
    restart: bool = True
    env: dict[str, str] = field(default_factory=dict)
    command: list[str] | None = None
    nice: int = 0

    def argv(self) -> list[str]:
        if self.command is not None:
            return list(self.command)
        args = [sys.executable, "-u", "-m", self.module]
        if self.params_file is not None:
            args += ["--ros-args", "--params-file", str(self.params_file)]
        return args
