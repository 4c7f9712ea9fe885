"""Solved task policies kept on disk, keyed by what determines them.

The key is the SHA-256 of the task file's bytes and the solver settings, so an
edited task or other settings never reuse a stale policy; the policy itself also
records its model's hash (:meth:`POMDP.fingerprint`), which a loader checks.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

from stack.config import read_bytes_capped
from stack.planning.solve import TASK_CONFIG, SolverConfig, format_progress, solve_task
from stack.planning.task import load_task


def cache_key(task_path: str | Path, config: SolverConfig) -> str:
    h = hashlib.sha256(read_bytes_capped(task_path))
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
    path = Path(cache_dir) / f"{task_path.stem}-{cache_key(task_path, config)}.npz"
    if path.exists():
        return path
    say(f"[policy] solving {task_path.name} ({config.algorithm}), once")
    policy = solve_task(
        load_task(task_path), config, lambda s: say("[policy] " + format_progress(s))
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    return policy.save(path)
