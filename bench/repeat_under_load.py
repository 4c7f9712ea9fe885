"""The twin repeatability test beside a CPU hog (docs/SAFETY.md, issue 13).

    .venv/bin/python bench/repeat_under_load.py [--hogs 2]

Starts ``--hogs`` busy-looping processes (one per core by default) for the length of
``tests/test_system_twin.py::test_same_scenario_same_seed_same_steps`` and prints its
result; the hogs stop with it. Exit code: pytest's.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEST = "tests/test_system_twin.py::test_same_scenario_same_seed_same_steps"


def _spin(stop: mp.Event) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hogs", type=int, default=os.cpu_count() or 2)
    args = ap.parse_args()
    stop = mp.Event()
    hogs = [mp.Process(target=_spin, args=(stop,), daemon=True) for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    t0 = time.monotonic()
    try:
        rc = subprocess.call([sys.executable, "-m", "pytest", "-q", TEST], cwd=REPO)
    finally:
        stop.set()
        for h in hogs:
            h.join(timeout=5)
    print(f"{TEST}: exit {rc} with {args.hogs} CPU hogs, {time.monotonic() - t0:.0f} s")
    return rc


if __name__ == "__main__":
    sys.exit(main())
