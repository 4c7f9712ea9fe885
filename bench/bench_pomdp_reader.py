"""Time the ``.pomdp`` reader (and writer) on the public benchmark files.

Usage (from the repository root):

    .venv/bin/python bench/bench_pomdp_reader.py [--dir ../shared/pomdp] [--repeat 5]

Prints one row per file: size, model sizes, and the best / median wall time of
``read_pomdp`` (file read + parse + CSR assembly + reward expectation) over the repeats,
plus the time of ``format_pomdp`` on the model read.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from stack.planning.pomdp_format import format_pomdp, read_pomdp  # noqa: E402

DEFAULT_DIR = REPO.parent / "shared" / "pomdp"


def _times(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print a Markdown table.

    Args:
        argv: command-line arguments (``sys.argv[1:]`` when None).

    Returns:
        The exit status: 0, or 1 when the folder holds no ``.pomdp`` file.
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", type=Path, default=DEFAULT_DIR, help="folder of .pomdp files")
    ap.add_argument("--repeat", type=int, default=5, help="timed reads per file")
    args = ap.parse_args(argv)
    files = sorted(
        (p for p in args.dir.glob("*") if p.suffix.lower() == ".pomdp"),
        key=lambda p: p.stat().st_size,
    )
    if not files:
        print(f"no .pomdp files in {args.dir}", file=sys.stderr)
        return 1
    print(
        "| file | size [KB] | S | A | Z | nnz T | nnz O | read best [s] | read median [s] "
        "| MB/s | write [s] |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for path in files:
        model = read_pomdp(path)  # warm-up (imports, page cache)
        reads = _times(lambda p=path: read_pomdp(p), args.repeat)
        writes = _times(lambda m=model: format_pomdp(m), max(1, args.repeat // 2))
        size_kb = path.stat().st_size / 1024
        nnz_t = sum(t.nnz for t in model.T)
        nnz_o = sum(o.nnz for o in model.O)
        best = min(reads)
        print(
            f"| {path.name} | {size_kb:.0f} | {model.n_states} | {model.n_actions} "
            f"| {model.n_observations} | {nnz_t} | {nnz_o} | {best:.4f} "
            f"| {statistics.median(reads):.4f} | {size_kb / 1024 / best:.1f} | {min(writes):.4f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
