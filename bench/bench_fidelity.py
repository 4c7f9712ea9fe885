"""The perception model against the rendered camera: the same walks run both ways.

    .venv/bin/python bench/bench_fidelity.py --task config/task-r1.yaml --episodes 100 \
        --seed 202 --workers 2 --out runs/fidelity

runs ``vigil montecarlo`` twice on the same walks (``--walks``, default
config/walks.yaml): ``--perception rendered`` (EGL + HOG, the reference) into
OUT/rendered and ``--perception model`` into OUT/model (a study already in its folder
with the same episodes is read, not run again: ``--reuse``), then prints and writes
OUT/fidelity.md: each mode's guarded rate, delay, trips and warnings with their 95 %
intervals, and per visit whether the guarded outcome agrees.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from vigil.montecarlo import run_study  # noqa: E402
from vigil.study_stats import compare_studies, comparison_markdown  # noqa: E402
from vigil.walks import DEFAULT_WALKS, load_walks  # noqa: E402


def study(mode: str, args: argparse.Namespace) -> dict:
    out = args.out / mode
    saved = out / "montecarlo.json"
    if args.reuse and saved.exists():
        record = json.loads(saved.read_text())
        if len(record["episodes"]) == args.episodes and record["seed"] == args.seed:
            print(f"[fidelity] {mode}: reusing {saved}")
            return record
    return run_study(args.task, args.episodes, out, args.seed, args.workers,
                     study=load_walks(args.walks), perception=mode)  # fmt: skip


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", type=Path, default=REPO / "config" / "task-r1.yaml")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=202)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--walks", type=Path, default=DEFAULT_WALKS)
    p.add_argument("--out", type=Path, default=REPO / "runs" / "fidelity")
    p.add_argument("--reuse", action="store_true", help="read studies already in OUT")
    args = p.parse_args()
    rendered, model = study("rendered", args), study("model", args)
    c = compare_studies(rendered, model, ("rendered", "model"))
    text = comparison_markdown(c)
    (args.out / "fidelity.md").write_text(text)
    (args.out / "fidelity.json").write_text(json.dumps(c, indent=2) + "\n")
    print(text)
    for v in c["differing_visits"]:
        print(f"[fidelity] differs: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
