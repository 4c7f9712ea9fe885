"""CPU seconds of a solve, split into start-up (imports), reading and solving.

SARSOP's figures in ../shared/pomdp/README.md are CPU seconds; on a shared machine
the wall time of a short solve mostly measures the other processes. For each file,
in a fresh interpreter per repeat (so the imports are counted):

    import CPU s | read CPU s | solve CPU s | solve wall s | LB / UB | load (1 min)

    nice -n 5 .venv/bin/python bench/bench_solve_cpu.py RockSample_4_4.pomdp --repeats 3

The solve is ``solve(pomdp, SolverConfig())``: the belief-tree search to a gap of
1e-3, no time limit.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "pomdp"

CHILD = """
import json, sys, time
c0, w0 = time.process_time(), time.perf_counter()
from stack.planning.pomdp_format import read_pomdp
from stack.planning.solve import SolverConfig, solve
c1 = time.process_time()
pomdp = read_pomdp(sys.argv[1])
c2, w2 = time.process_time(), time.perf_counter()
r = solve(pomdp, SolverConfig())
c3, w3 = time.process_time(), time.perf_counter()
print(json.dumps({"import_cpu": c1 - c0, "read_cpu": c2 - c1, "solve_cpu": c3 - c2,
                  "solve_wall": w3 - w2, "lower": r.lower_bound, "upper": r.upper_bound}))
"""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="+", help="names in ../shared/pomdp/ or paths")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    print("| file | import CPU s | read CPU s | solve CPU s | solve wall s | LB / UB | load |")
    print("|---|---:|---:|---:|---:|---|---:|")
    for name in args.files:
        path = Path(name) if Path(name).exists() else SHARED / name
        for _ in range(args.repeats):
            load = os.getloadavg()[0]
            out = subprocess.run(
                [sys.executable, "-c", CHILD, str(path)],
                capture_output=True, text=True, env=env, cwd=REPO, check=True,
            )  # fmt: skip
            d = json.loads(out.stdout)
            print(
                f"| {path.name} | {d['import_cpu']:.2f} | {d['read_cpu']:.2f} | "
                f"{d['solve_cpu']:.2f} | {d['solve_wall']:.2f} | "
                f"{d['lower']:.4f} / {d['upper']:.4f} | {load:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
