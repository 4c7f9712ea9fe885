"""The run folder's rules, one function for ``vigil run`` and ``vigil launch``.

A run writes only into a folder it made: never over what a user keeps elsewhere.
"""

from __future__ import annotations

import json
import os
import stat
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

    The folder must be the user's own and not writable by every user (checked on the
    folder the name leads to): whoever else can write into it can plant a link under
    a name the run writes, or swap a subfolder (``bag/``, ``logs/``) for a link to a
    folder of the user's, between any check and the write. vigil's writers refuse a
    link at the file's own name (``stack.files.open_write``); only a folder no one
    else can write keeps the names above it. A folder it makes is mode 0755.

    Raises:
        ConfigError: ``run_dir`` is a file, a non-empty folder vigil did not make, a
            folder of another user's or writable by every user.
    """
    run_dir = Path(run_dir)
    if os.path.islink(run_dir) and not run_dir.exists():
        raise ConfigError("--out", str(run_dir), "is a symbolic link to nothing")
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError("--out", str(run_dir), "is a file, not a folder")
    if run_dir.is_dir() and any(run_dir.iterdir()):
        if not (run_dir / RUN_MARK).is_file():
            raise ConfigError(
                "--out", str(run_dir), "is a non-empty folder that vigil did not make"
            )
        for n in range(2, MAX_NUMBERED):
            candidate = run_dir.with_name(f"{run_dir.name}-{n}")
            if not os.path.lexists(candidate):
                run_dir = candidate
                break
        else:
            raise ConfigError("--out", str(run_dir), f"{MAX_NUMBERED} numbered runs exist")
    run_dir.mkdir(mode=0o755, parents=True, exist_ok=True)
    check_own_folder(run_dir)
    write_text(run_dir / RUN_MARK, json.dumps({"run_id": run_id, "pid": os.getpid()}) + "\n")
    return run_dir


def check_own_folder(run_dir: Path, key: str = "--out") -> None:
    """Refuse (ConfigError naming ``key``) a folder that is another user's or writable
    by every user (the folder a link at ``run_dir`` leads to is the one checked)."""
    st = os.stat(run_dir)
    if st.st_uid != os.getuid():
        raise ConfigError(
            key,
            str(run_dir),
            f"belongs to uid {st.st_uid}, not to you (uid {os.getuid()}): its owner could "
            "redirect what the run writes",
        )
    if st.st_mode & stat.S_IWOTH:
        raise ConfigError(
            key,
            str(run_dir),
            "is writable by every user (anyone could plant links in it): "
            "`chmod o-w` it or choose another folder",
        )
