"""Run chapter 5's experiments and copy their reports into docs/experiments/.

    .venv/bin/python scripts/experiments.py [--only 5.2.2] [--runs runs/experiments]

Each scenario of scenarios/ runs through the whole ROS stack in the lock-step twin
(vigil run); 5.1.1 also runs with table 5.1's observations (as the thesis entered
them). For each run docs/experiments/<name>/ receives steps.md, positions.png,
belief.png and summary.json; docs/EXPERIMENTS.md discusses them.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from vigil.run import run_scenario  # noqa: E402

RUNS = [
    ("5.1.1-table", "5.1.1", "table"),
    ("5.1.1", "5.1.1", "twin"),
    ("5.1.2", "5.1.2", "twin"),
    ("5.2.1", "5.2.1", "twin"),
    ("5.2.2", "5.2.2", "twin"),
]
COPY = ("steps.md", "positions.png", "belief.png", "summary.json")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, help="run names, e.g. 5.2.2")
    ap.add_argument("--runs", default=str(REPO / "runs" / "experiments"))
    args = ap.parse_args()
    docs = REPO / "docs" / "experiments"
    for name, scenario, observations in RUNS:
        if args.only and name not in args.only:
            continue
        out = Path(args.runs) / name
        run_scenario(REPO / "scenarios" / f"{scenario}.yaml", out=out, observations=observations)
        dest = docs / name
        dest.mkdir(parents=True, exist_ok=True)
        for f in COPY:
            if (out / f).exists():
                shutil.copy(out / f, dest / f)
        print(f"{name}: copied to {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
