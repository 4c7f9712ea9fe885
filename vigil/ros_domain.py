"""A private ROS domain per run: two runs on one machine never hear each other.

:func:`claim_domain` takes the first free ROS domain id of :data:`DOMAINS` by holding an
exclusive ``flock`` on ``<lock dir>/<id>.lock`` for the life of the returned
:class:`DomainClaim`. The kernel drops the lock when the process dies however it dies,
so a crashed run never leaks its domain, and nothing needs cleaning up.

The range keeps clear of the default domain (0), of the test suite's per-process
domains (1..100, ``tests/conftest.py``) and of the top of the valid range.
Override with ``VIGIL_DOMAINS=first-last`` (e.g. ``150-160``).
"""

from __future__ import annotations

import fcntl
import os
from dataclasses import dataclass
from pathlib import Path

from stack.cells import ConfigError

DOMAINS = range(120, 220)
LOCK_DIR = Path(os.environ.get("VIGIL_LOCK_DIR", "/tmp/vigil-ros-domains"))


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
    lock_dir = Path(lock_dir or LOCK_DIR)
    lock_dir.mkdir(parents=True, exist_ok=True)
    for domain in domains if domains is not None else domain_range():
        fd = os.open(lock_dir / f"{domain}.lock", os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        return DomainClaim(domain, fd)
    raise ConfigError("ROS domain", str(lock_dir), "every vigil domain is in use by other runs")
