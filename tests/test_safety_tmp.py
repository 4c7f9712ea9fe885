"""What vigil keeps under /tmp lives in a folder private to the user (issue 23):
mode 0700, created if absent, refused if it is a link or someone else's."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from stack.cells import ConfigError
from vigil.private_dir import ensure_private, private_dir

REPO = Path(__file__).resolve().parents[1]


def test_the_private_folder_is_made_0700_and_reused(tmp_path):
    path = private_dir("ros-domains", base=tmp_path)
    assert path == tmp_path / f"vigil-{os.getuid()}" / "ros-domains"
    for p in (path, path.parent):
        st = os.lstat(p)
        assert stat.S_IMODE(st.st_mode) == 0o700 and st.st_uid == os.getuid()
    assert private_dir("ros-domains", base=tmp_path) == path


def test_a_looser_folder_of_ours_is_tightened(tmp_path):
    (tmp_path / "f").mkdir(mode=0o777)
    os.chmod(tmp_path / "f", 0o777)
    ensure_private(tmp_path / "f")
    assert stat.S_IMODE(os.lstat(tmp_path / "f").st_mode) == 0o700


def test_a_link_planted_under_the_name_is_refused(tmp_path):
    """Another user pre-creates /tmp/vigil-<uid> as a link to a folder of theirs."""
    (tmp_path / "theirs").mkdir()
    (tmp_path / f"vigil-{os.getuid()}").symlink_to(tmp_path / "theirs")
    with pytest.raises(ConfigError, match="symbolic link"):
        private_dir("ros-domains", base=tmp_path)
    assert not any((tmp_path / "theirs").iterdir())


def test_a_folder_of_another_user_is_refused(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root to give a folder away")
    folder = tmp_path / f"vigil-{os.getuid()}"
    folder.mkdir(mode=0o777)
    os.chown(folder, 12345, 12345)
    with pytest.raises(ConfigError, match="belongs to uid 12345"):
        private_dir("ros-domains", base=tmp_path)


def test_the_domain_locks_live_in_the_private_folder(tmp_path, monkeypatch):
    """Before: /tmp/vigil-ros-domains, made with the umask's mode, lock files 0666."""
    import tempfile

    from vigil import ros_domain

    monkeypatch.delenv("VIGIL_LOCK_DIR", raising=False)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    claim = ros_domain.claim_domain(domains=range(200, 202))
    try:
        lock = tmp_path / f"vigil-{os.getuid()}" / "ros-domains" / f"{claim.domain_id}.lock"
        assert lock.is_file() and stat.S_IMODE(lock.stat().st_mode) == 0o600
        assert stat.S_IMODE(lock.parent.stat().st_mode) == 0o700
    finally:
        claim.release()


def test_nothing_else_is_kept_under_tmp():
    """No other /tmp path, tempfile or gettempdir in vigil/, stack/, twin/."""
    hits = []
    for pkg in ("vigil", "stack", "twin"):
        for path in (REPO / pkg).rglob("*.py"):
            text = path.read_text()
            for word in ('"/tmp', "'/tmp", "tempfile", "gettempdir", "mkdtemp"):
                if word in text and path.name != "private_dir.py":
                    hits.append(f"{path.relative_to(REPO)}: {word}")
    assert not hits, hits
