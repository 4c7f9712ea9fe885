"""The belief-tree search against SARSOP on the shared benchmark files.

For every file in ../shared/pomdp/ with a discount below 1, and every time limit:

    vigil solve-pomdp FILE --time-limit T SOLVER_ARGS -o OUT.policy --json --quiet
    vigil evaluate FILE --policy OUT.policy --episodes N --horizon 100 --json

(the time limit covers the whole command: start-up, reading, solving, writing), and
prints a Markdown table beside SARSOP's 60 s figures from ../shared/pomdp/README.md,
with the load average (1 min) before each command. With ``--pomdpsim PATH`` SARSOP's
own simulator also reads each policy we wrote (``--sim-num`` runs, one-step lookahead).

    nice -n 5 .venv/bin/python bench/bench_solver.py --limits 10 60 --episodes 1000 \
        --pomdpsim ../sarsop-build/sarsop/src/pomdpsim --keep /tmp/policies

Limits in CPU seconds (SARSOP's measure; the result no longer depends on the load):
``--solver-args=--cpu-time``. The solver's own defaults are what is measured (with a
limit of 10 s or more, Perseus first for 30 % of it, its vectors seeding the search).

Held-out family members (optional; not in ../shared): ``--heldout`` generates
RockSample_7_8.pomdp (12,545 states, bench/gen_rocksample.py) into the policy folder
and runs it too; ``--files`` also takes paths, e.g. SARSOP's RockSample_7_8.pomdpx:

    nice -n 5 .venv/bin/python bench/bench_solver.py --limits 60 --files --heldout \
        --solver-args=--cpu-time

Progress: one line per run on stderr.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "pomdp"
VIGIL = [sys.executable, "-m", "vigil.cli"]
SARSOP_60S = {  # LB / UB at 60 CPU seconds, ../shared/pomdp/README.md; simulated: issue 12
    "Tiger.pomdp": ("19.371 / 19.372", ""),
    "4x3.95.POMDP": ("1.8899 / 1.8909", ""),
    "cheese.95.POMDP": ("3.4853 / 3.4862", ""),
    "RockSample_4_4.pomdp": ("17.924 exact (0.23 s)", ""),
    "Hallway.pomdp": ("0.995 / 1.206", "1.006 ± 0.009"),
    "Hallway2.pomdp": ("0.364 / 0.904", "0.516 ± 0.008"),
    "TagAvoid.pomdp": ("−6.200 / −1.998", "−6.07 ± 0.12"),
    "RockSample_5_7.pomdp": ("24.475 / 27.107", "24.35 ± 0.14"),
    # held-out: pomdpsol --timeout 60 on this machine (docs/BENCHMARKS.md, 24 Nov)
    "RockSample_7_8.pomdp": ("20.121 / 25.526", ""),
    "RockSample_7_8.pomdpx": ("21.125 / 24.529", "21.82 (21.41, 22.23)"),
}


def run(cmd: list[str]) -> dict:
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {out.stderr.strip()[-400:]}")
    return json.loads(out.stdout)


def pomdpsim(binary: str, model: Path, policy: Path, runs: int, timeout_s: float) -> str:
    """SARSOP's simulator on our policy: "mean (low, high)" or why not."""
    cmd = [binary, str(model), "--policy-file", str(policy), "--simLen", "100"]
    cmd += ["--simNum", str(runs), "--srand", "1"]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        return f"(over {timeout_s:g} s)"
    # its last table row: runs, mean discounted reward, (CI low, CI high)
    num = r"([-\d.e+]+)"
    rows = re.findall(rf"^\s*(\d+)\s+{num}\s+\(\s*{num},\s*{num}\)", out.stdout, re.M)
    if not rows:
        return "(no result)"
    _, mean, lo, hi = rows[-1]
    return f"{float(mean):.3f} ({float(lo):.3f}, {float(hi):.3f}), {runs} runs"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--limits", type=float, nargs="+", default=[10.0, 60.0])
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--files", nargs="*", default=list(SARSOP_60S))
    ap.add_argument(
        "--solver-args",
        default="",
        help="extra solve-pomdp arguments (default: none, the command's defaults; "
        "'--perseus-share 0' for the search alone)",
    )
    ap.add_argument("--pomdpsim", help="SARSOP's pomdpsim binary (optional)")
    ap.add_argument("--sim-num", type=int, default=1000, help="pomdpsim runs")
    ap.add_argument("--sim-timeout", type=float, default=600.0, help="[s] per pomdpsim run")
    ap.add_argument("--keep", help="directory to keep the policies in (default: a temporary one)")
    ap.add_argument(
        "--heldout",
        action="store_true",
        help="also RockSample_7_8.pomdp, generated into the policy folder",
    )
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        keep = Path(args.keep or tmp)
        keep.mkdir(parents=True, exist_ok=True)
        files = list(args.files)
        if args.heldout:
            gen = keep / "RockSample_7_8.pomdp"
            if not gen.is_file():
                subprocess.run(
                    [sys.executable, str(REPO / "bench" / "gen_rocksample.py"), "7", "8"]
                    + ["-o", str(gen)],
                    check=True,
                )
            files.append(str(gen))
        for file in files:
            path = SHARED / file  # an absolute path stays itself
            name = path.name
            for limit in args.limits:
                out = keep / f"{path.name}-{limit:g}.policy"
                load = os.getloadavg()[0]
                t0 = time.perf_counter()
                s = run(
                    VIGIL
                    + ["solve-pomdp", str(path), "--time-limit", str(limit)]
                    + args.solver_args.split()
                    + ["-o", str(out), "--json", "--quiet"]
                )
                wall = time.perf_counter() - t0
                ev = run(
                    VIGIL
                    + ["evaluate", str(path), "--policy", str(out), "--episodes"]
                    + [str(args.episodes), "--horizon", "100", "--seed", "1", "--json"]
                )
                sim = (
                    pomdpsim(args.pomdpsim, path, out, args.sim_num, args.sim_timeout)
                    if args.pomdpsim
                    else ""
                )
                rows.append((name, limit, s, wall, ev, sim, load, out.stat().st_size))
                print(
                    f"{name} {limit:g} s: LB {s['lower_bound']:.4f} UB {s['upper_bound']:.4f} "
                    f"simulated {ev['mean']:.3f} ± {ev['ci95']:.3f}, command {wall:.1f} s, "
                    f"pomdpsim {sim}, load {load:.1f}",
                    file=sys.stderr,
                    flush=True,
                )
    print("| file | limit | vigil LB / UB | vigil evaluate (95 % CI) | pomdpsim on ours | vectors "
          "| MB | command s | load | SARSOP 60 s LB / UB | SARSOP simulated |")  # fmt: skip
    print("|---|---:|---|---|---|---:|---:|---:|---:|---|---|")
    for name, limit, s, wall, ev, sim, load, size in rows:
        ref, ref_sim = SARSOP_60S.get(name, ("", ""))
        print(
            f"| {name} | {limit:g} s | {s['lower_bound']:.4f} / {s['upper_bound']:.4f} | "
            f"{ev['mean']:.3f} ± {ev['ci95']:.3f} | {sim} | {s['alpha_vectors']} | "
            f"{size / 1e6:.1f} | {wall:.2f} | {load:.1f} | {ref} | {ref_sim} |"
        )


if __name__ == "__main__":
    main()
