"""Solved task policies kept on disk, keyed by what determines them.

The key is the SHA-256 of the task's POMDP (:meth:`POMDP.fingerprint`: T, O, R, the
discount and b0), its name and the solver settings: an edit that changes the model or
the settings never reuses a stale policy, and one that does not (a task file's
run-time ``anticipation`` block, comments, another file with the same task) solves
nothing again. The policy also records its model's hash, which a loader checks.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from stack.memo import Memo, file_version
from stack.planning.runtime import task_of
from stack.planning.solve import TASK_CONFIG, SolverConfig, format_progress, solve_task


def cache_key(task, config: SolverConfig) -> str:
    """The cache key of a :class:`~stack.planning.task.Task`'s policy."""
    from stack.planning.model import build_model

    h = hashlib.sha256(build_model(task).flat().fingerprint().encode())
    h.update(task.name.encode())  # the policy's meta names it
    h.update(json.dumps(asdict(config), sort_keys=True).encode())
    return h.hexdigest()[:16]


def cached_task_policy(
    task_path: str | Path,
    cache_dir: str | Path,
    config: SolverConfig = TASK_CONFIG,
    say: Callable[[str], None] = print,
) -> Path:
    """The path of the task's policy, solving it (once) if the cache has none.

    The file is written under a temporary name and moved into place, so a process
    that reads the cache never sees half a policy.
    """
    task_path = Path(task_path)
    task = task_of(str(task_path))  # read once per version of the file
    # the key costs a model build: once per version of the file and settings too
    name = _NAMES.get(
        (file_version(str(task_path.resolve())), repr(config)),
        lambda: f"{_safe(task.name)}-{cache_key(task, config)}.npz",
    )
    path = Path(cache_dir) / name
    if path.exists():
        return path
    say(f"[policy] solving {task_path.name} ({config.algorithm}), once")
    policy = solve_task(task, config, lambda s: say("[policy] " + format_progress(s)))
    path.parent.mkdir(parents=True, exist_ok=True)
    return policy.save(path)


_NAMES = Memo(16)  # (task file's version, settings) -> the policy's file name


def _safe(name: str) -> str:
    """A task name as part of a file name."""
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)[:60] or "task"
