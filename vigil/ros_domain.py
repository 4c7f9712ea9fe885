"""A private ROS domain per run: two runs on one machine never hear each other.

:func:`claim_domain` takes the first free ROS domain id of :data:`DOMAINS` by holding an
exclusive ``flock`` on ``<lock dir>/<id>.lock`` for the life of the returned
:class:`DomainClaim`. The kernel drops the lock when the process dies however it dies,
so a crashed run never leaks its domain, and nothing needs cleaning up.

The range keeps clear of the default domain (0), of the test suite's per-process
domains (1..100, ``tests/conftest.py``) and of the top of the valid range.
Override with ``VIGIL_DOMAINS=first-last`` (e.g. ``150-160``).

The locks live in a folder private to the user (:func:`vigil.private_dir.private_dir`,
``/tmp/vigil-<uid>/ros-domains``, mode 0700; before: a world-readable
``/tmp/vigil-ros-domains`` with mode-0666 lock files that any local user could hold or
replace by a link). Two users' runs on one machine therefore no longer see each other's
claims: give them disjoint ``VIGIL_DOMAINS`` ranges, or a shared ``VIGIL_LOCK_DIR``
(taken as it is).
"""

from __future__ import annotations

import fcntl
import os
from dataclasses import dataclass
from pathlib import Path

from stack.cells import ConfigError

DOMAINS = range(120, 220)
LOCK_SUBDIR = "ros-domains"  # under the user's private folder (vigil.private_dir)


def default_lock_dir() -> Path:
    """``VIGIL_LOCK_DIR`` if set, else ``/tmp/vigil-<uid>/ros-domains`` (private)."""
    given = os.environ.get("VIGIL_LOCK_DIR")
    if given:
        return Path(given)
    from vigil.private_dir import private_dir

    return private_dir(LOCK_SUBDIR)


@dataclass
class DomainClaim:
    """A held domain id; :meth:`release` (or process exit) frees it."""

    domain_id: int
    fd: int | None

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def domain_range(text: str | None = None) -> range:
    """``VIGIL_DOMAINS`` ("first-last") or :data:`DOMAINS`.

    Raises:
        ConfigError: not two integers in [1, 232] with first <= last.
    """
    text = os.environ.get("VIGIL_DOMAINS", "") if text is None else text
    if not text:
        return DOMAINS
    try:
        first, last = (int(v) for v in text.split("-"))
    except ValueError:
        raise ConfigError("VIGIL_DOMAINS", text, "must be first-last, e.g. 150-160") from None
    if not 1 <= first <= last <= 232:
        raise ConfigError("VIGIL_DOMAINS", text, "must lie in 1..232 with first <= last")
    return range(first, last + 1)


def claim_domain(lock_dir: Path | None = None, domains: range | None = None) -> DomainClaim:
    """The first domain id no other live vigil process holds.

    Raises:
        ConfigError: every domain of the range is taken (names the lock folder).
    """
    folder = Path(lock_dir) if lock_dir else default_lock_dir()
    folder.mkdir(parents=True, exist_ok=True)
    for domain in domains if domains is not None else domain_range():
        path = folder / f"{domain}.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        return DomainClaim(domain, fd)
    raise ConfigError("ROS domain", str(folder), "every vigil domain is in use by other runs")
