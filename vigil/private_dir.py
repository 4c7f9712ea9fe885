"""What vigil keeps under ``/tmp`` lives in a folder private to the user (issue 23):
``<tmp>/vigil-<uid>/`` (``tempfile.gettempdir()``, normally ``/tmp``), mode 0700,
created if absent, refused if it is a link or someone else's; a folder of ours with
looser permissions is tightened to 0700. Another local user can then neither read,
replace nor pre-create what vigil keeps there (the ROS domain locks: a shared lock
folder let anyone hold every domain, or plant a link under vigil's name)."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from stack.cells import ConfigError


def ensure_private(path: Path) -> Path:
    """``path`` as a folder of this user's, mode 0700 (created if absent).

    Raises:
        ConfigError: ``path`` is a link, not a folder, or owned by another user.
    """
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    st = os.lstat(path)
    if stat.S_ISLNK(st.st_mode):
        raise ConfigError("private folder", str(path), "is a symbolic link: refused")
    if not stat.S_ISDIR(st.st_mode):
        raise ConfigError("private folder", str(path), "is not a folder")
    if st.st_uid != os.getuid():
        raise ConfigError(
            "private folder", str(path), f"belongs to uid {st.st_uid}, not to you ({os.getuid()})"
        )
    if stat.S_IMODE(st.st_mode) != 0o700:
        os.chmod(path, 0o700, follow_symlinks=False)
    return path


def private_dir(name: str, base: Path | None = None) -> Path:
    """``<tmp>/vigil-<uid>/<name>``, both folders checked by :func:`ensure_private`."""
    root = Path(base or tempfile.gettempdir()) / f"vigil-{os.getuid()}"
    return ensure_private(ensure_private(root) / name)
