"""The chaos soak (issue 23): a twin run with at least 20 seeded random SIGKILLs of its
restartable nodes (the base's sender first and while the robot drives: navigation in
lock-step; with ``--realtime`` the twin keeps the wall clock and the velocity gate sits
between navigation and the base, and is a victim too), then what must hold: the base
never kept a command past its timeout (it brakes at its acceleration limit),
steps.jsonl and every bag read back, and the run ended with one line naming the first
kill. Figures for docs/SAFETY.md.

    python bench/bench_chaos.py [--kills 20] [--steps 40] [--seed 0] [--realtime] [--out DIR]
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from vigil.chaos import GATE_VICTIMS, VICTIMS, chaos_files, check_run, run_chaos  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=20)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--realtime", action="store_true", help="the twin at real time, with the velocity gate"
    )
    ap.add_argument("--out", default=None, help="keep the run here (default: a temp folder)")
    args = ap.parse_args()
    folder = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="vigil-chaos-"))
    folder.mkdir(parents=True, exist_ok=True)
    scenario, config = chaos_files(folder, args.steps, realtime=args.realtime)
    run = run_chaos(
        scenario, config, folder / "run", kills=args.kills, seed=args.seed, first_s=2.0,
        gap_s=(4.0, 14.0), first="velocity_gate" if args.realtime else "navigation",
        victims=GATE_VICTIMS if args.realtime else VICTIMS, when_driving=True,
        timeout_s=7200.0, realtime=args.realtime,
        say=lambda line: print(line, flush=True) if "[chaos]" in line else None,
    )  # fmt: skip
    result = check_run(run.out)
    bags = result["bags"].values()
    figures = {
        "kills": len(run.kills),
        "kills_per_node": dict(collections.Counter(k.node for k in run.kills)),
        "wall_s": round(run.wall_s),
        "exit_code": run.returncode,
        "last_line": run.last_line,
        "steps": result["steps"],
        "bags": len(result["bags"]),
        "bag_messages": sum(b["messages"] for b in bags),
        "silences": sum(b["silences"] for b in bags),
        "worst_stop_s": max((b["worst_stop_s"] for b in bags), default=0.0),
        "excess_mps": max((b["excess"] for b in bags), default=0.0),
        "failures": len(result["run"].get("failures", [])),
    }
    print(json.dumps(figures, indent=2))
    ok = figures["excess_mps"] <= 0.03 and run.last_line.startswith("vigil run: ")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
