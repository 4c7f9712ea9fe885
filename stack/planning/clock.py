"""When did this command start? For a time limit that covers the whole command.

A ``--time-limit`` of 60 s means 60 s of wall time from the moment the process
started (interpreter start-up, imports and reading the model included), not from
the moment the solver was called. Linux records the start in /proc; elsewhere the
first call of :func:`process_start` stands in for it.
"""

from __future__ import annotations

import os
import time

_FALLBACK: list[float] = []


def process_start() -> float:
    """The ``time.perf_counter()`` reading at which this process started."""
    now = time.perf_counter()
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])  # field 22 of proc(5): starttime, clock ticks
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        age = uptime - start_ticks / os.sysconf("SC_CLK_TCK")
        if 0.0 <= age < 3600.0:
            return now - age
    except (OSError, ValueError, IndexError):
        pass
    if not _FALLBACK:
        _FALLBACK.append(now)
    return _FALLBACK[0]
