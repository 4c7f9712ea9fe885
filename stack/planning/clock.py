"""When did this command start, and which clock do its time limits read?

A ``--time-limit`` of 60 s means 60 s from the moment the process started
(interpreter start-up, imports and reading the model included), not from the moment
the solver was called. By default the clock is wall time (``time.perf_counter``):
Linux records the process's start in /proc; elsewhere the first call of
:func:`process_start` stands in for it. With :func:`use_cpu_time` the limits read
the process's CPU time instead (``time.process_time``, which starts at 0 with the
process): the measure SARSOP's reference figures use, and one that does not shrink
when other processes share the cores.
"""

from __future__ import annotations

import os
import time

_FALLBACK: list[float] = []
_CPU: list[bool] = [False]


def use_cpu_time(on: bool = True) -> None:
    """Make :func:`now` (and so every time limit of the solvers) read CPU time."""
    _CPU[0] = on


def cpu_time() -> bool:
    return _CPU[0]


def now() -> float:
    """The solvers' clock: wall time, or this process's CPU time (:func:`use_cpu_time`)."""
    return time.process_time() if _CPU[0] else time.perf_counter()


def process_start() -> float:
    """The :func:`now` reading at which this process started."""
    if _CPU[0]:
        return 0.0
    now_s = time.perf_counter()
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])  # field 22 of proc(5): starttime, clock ticks
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        age = uptime - start_ticks / os.sysconf("SC_CLK_TCK")
        if 0.0 <= age < 3600.0:
            return now_s - age
    except (OSError, ValueError, IndexError):
        pass
    if not _FALLBACK:
        _FALLBACK.append(now_s)
    return _FALLBACK[0]
