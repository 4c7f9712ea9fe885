"""The run folder's rules, one function for ``vigil run`` and ``vigil launch``.

A run writes only into a folder it made: never over what a user keeps elsewhere.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from stack.cells import ConfigError
from stack.config import write_text

RUN_MARK = ".vigil-run"  # written first into every run folder vigil makes
MAX_NUMBERED = 1000


def fresh_run_dir(run_dir: Path, run_id: str) -> Path:
    """The folder this run (``vigil run``, ``vigil launch``) writes into; nothing that
    exists is ever deleted.

    An absent or empty ``run_dir`` is used as it is. A non-empty folder that an
    earlier ``vigil run`` made (it holds :data:`RUN_MARK`) is kept: the run goes to the
    first free ``<run_dir>-2``, ``-3``, ... beside it. Any other non-empty folder (or a
    file) is refused.

    Raises:
        ConfigError: ``run_dir`` is a file, or a non-empty folder vigil did not make.
    """
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError("--out", str(run_dir), "is a file, not a folder")
    if run_dir.is_dir() and any(run_dir.iterdir()):
        if not (run_dir / RUN_MARK).is_file():
            raise ConfigError(
                "--out", str(run_dir), "is a non-empty folder that vigil did not make"
            )
        for n in range(2, MAX_NUMBERED):
            candidate = run_dir.with_name(f"{run_dir.name}-{n}")
            if not candidate.exists():
                run_dir = candidate
                break
        else:
            raise ConfigError("--out", str(run_dir), f"{MAX_NUMBERED} numbered runs exist")
    run_dir.mkdir(parents=True, exist_ok=True)
    write_text(run_dir / RUN_MARK, json.dumps({"run_id": run_id, "pid": os.getpid()}) + "\n")
    return run_dir
