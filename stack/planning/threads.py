"""BLAS thread control without extra dependencies.

The solvers multiply many small matrices (tens to hundreds of rows); OpenBLAS's
threads cost more than they bring there, and on a shared 2-core machine they fight
the other processes for the cores: TagAvoid ran 4x more backups in the same time
with one BLAS thread (docs/BENCHMARKS.md). :func:`blas_threads` sets the thread
count of the OpenBLAS that numpy loaded, for the duration of a ``with`` block.
"""

from __future__ import annotations

import ctypes
import re
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache

# what a process started with one of these set to "1" uses: one BLAS thread from the
# start (a study's workers, the nodes of a run: vigil.montecarlo, vigil.system)
ENV_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

_SETTERS = ("scipy_openblas_set_num_threads64_", "openblas_set_num_threads")
_GETTERS = ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads")


@cache  # the library numpy loaded does not change; reading the maps costs ~1 ms
def _openblas() -> tuple | None:
    import numpy  # noqa: F401  (loads its OpenBLAS)

    try:
        with open("/proc/self/maps") as f:
            paths = {m.group(0) for m in re.finditer(r"/\S*openblas\S*\.so\S*", f.read())}
    except OSError:
        return None
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SETTERS if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GETTERS if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            return setter, getter
    return None


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run the block with ``n`` OpenBLAS threads (a no-op if OpenBLAS is not found)."""
    lib = _openblas()
    if lib is None:
        yield
        return
    setter, getter = lib
    before = int(getter())
    setter(int(n))
    try:
        yield
    finally:
        setter(before)
