"""What a process makes once and keeps: a bounded memo, forgotten all at once when full.

A study's worker runs a thousand episodes of the same task, camera and room; what does
not change between them (the task's model, the camera's tables, the calibration, the
policy's file name) is made on the first and looked up after. A process holds a few
such values, so the memo simply starts again when it is full.

    TABLES = Memo(8)
    table = TABLES.get(key, lambda: make_table(...))
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable
from typing import Any


class Memo:
    """Values by key, at most ``max_entries`` of them."""

    def __init__(self, max_entries: int):
        self.max_entries = max_entries
        self._values: dict[Hashable, Any] = {}

    def get(self, key: Hashable, make: Callable[[], Any]) -> Any:
        """The value of ``key``, made by ``make()`` the first time."""
        if key not in self._values:
            if len(self._values) >= self.max_entries:
                self._values.clear()
            self._values[key] = make()
        return self._values[key]


def file_version(*files: str) -> tuple:
    """What changes when a file is rewritten or replaced (an atomic replace: the inode)."""
    keys = []
    for f in files:
        st = os.stat(f)
        keys.append((str(f), st.st_ino, st.st_mtime_ns, st.st_ctime_ns, st.st_size))
    return tuple(keys)
