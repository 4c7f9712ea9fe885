"""CPU seconds of a solve, split into start-up (imports), reading, solving and writing,
and the whole ``vigil solve-pomdp`` command's wall and CPU time.

SARSOP's figures in ../shared/pomdp/README.md are CPU seconds; on a shared machine
the wall time of a short solve mostly measures the other processes. For each file,
in a fresh interpreter per repeat (so the imports are counted):

    import | read | solve | write (CPU s) | command wall s | command CPU s | LB / UB | load

    nice -n 5 .venv/bin/python bench/bench_solve_cpu.py RockSample_4_4.pomdp --repeats 3

The solve is ``solve(pomdp, SolverConfig())``: the belief-tree search to a gap of
1e-3, no time limit. "import" is what the command imports before it reads the model
(``vigil.cli`` and the solver), after the interpreter's own start. The command is

    python -m vigil.cli solve-pomdp FILE -o TMP.policy --json [--cpu-time]

timed from outside (wall: the process from start to exit; CPU: its user + system
seconds).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "pomdp"

CHILD = """
import json, sys, time
c0 = time.process_time()
import vigil.cli  # noqa: F401  (what the command imports)
from stack.planning.pomdp_format import read_pomdp
from stack.planning.solve import SolverConfig, solve
c1 = time.process_time()
pomdp = read_pomdp(sys.argv[1])
c2 = time.process_time()
r = solve(pomdp, SolverConfig())
c3 = time.process_time()
r.policy.save(sys.argv[2])
c4 = time.process_time()
print(json.dumps({"import_cpu": c1 - c0, "read_cpu": c2 - c1, "solve_cpu": c3 - c2,
                  "write_cpu": c4 - c3, "lower": r.lower_bound, "upper": r.upper_bound}))
"""


def _command(path: Path, policy: str, env: dict, cpu_time: bool) -> tuple[float, float]:
    """Wall and CPU seconds of the whole command, a process of its own."""
    cmd = [sys.executable, "-m", "vigil.cli", "solve-pomdp", str(path), "-o", policy, "--json"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        cmd + (["--cpu-time"] if cpu_time else []),
        capture_output=True, env=env, cwd=REPO, check=True,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("files", nargs="+", help="names in ../shared/pomdp/ or paths")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cpu-time", action="store_true", help="the command with --cpu-time")
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(REPO))
    print(
        "| file | import CPU s | read CPU s | solve CPU s | write CPU s | command wall s "
        "| command CPU s | LB / UB | load |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        policy = str(Path(tmp) / "bench.policy")
        for name in args.files:
            path = Path(name) if Path(name).exists() else SHARED / name
            for _ in range(args.repeats):
                load = os.getloadavg()[0]
                out = subprocess.run(
                    [sys.executable, "-c", CHILD, str(path), policy],
                    capture_output=True, text=True, env=env, cwd=REPO, check=True,
                )  # fmt: skip
                d = json.loads(out.stdout)
                wall, cpu = _command(path, policy, env, args.cpu_time)
                print(
                    f"| {path.name} | {d['import_cpu']:.2f} | {d['read_cpu']:.2f} | "
                    f"{d['solve_cpu']:.2f} | {d['write_cpu']:.3f} | {wall:.2f} | {cpu:.2f} | "
                    f"{d['lower']:.4f} / {d['upper']:.4f} | {load:.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
