"""How long the planner takes to decide, anticipation layer included (issue 26).

    .venv/bin/python bench/bench_decision.py [--episodes 30] [--walks config/walks.yaml] \
        [TASK ...]   # default: the goal-model tasks r1, r2 and the two-person task

Runs each task's first random walks of a study (seed 0) through the in-process loop
with the perception model, as ``vigil montecarlo`` does, and times (wall clock, this
process) every call the planner makes on the way to an action:

- ``track``: at every observation, the anticipation layer's goal inference and its
  target (one person: :class:`stack.planning.anticipate.Anticipator`; several:
  :class:`~stack.planning.anticipate.PeopleAnticipator`);
- ``observe``: at a step's end, the belief update (the exact belief of the offline
  policy's model; the online planner's factored belief);
- ``decide``: the action (the offline policy's alpha vectors, or the online planner's
  search) with the layer's advice over it;
- ``revise``: a new trip in the middle of a step when the layer's target changed.

A decision is the ``observe`` and ``decide`` of a step's end plus the ``track`` of the
observation that triggered it; issue 26 asks for it to stay under 0.1 s on this machine.
Prints per task and call the count, median, p99 and maximum in milliseconds.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")  # one BLAS thread, as a study's workers have

from stack.planning.agent_state import AgentCore  # noqa: E402
from stack.planning.anticipating import Anticipating  # noqa: E402
from vigil.inprocess import run_inprocess  # noqa: E402
from vigil.montecarlo import episode_scenarios  # noqa: E402
from vigil.walks import DEFAULT_WALKS, load_walks  # noqa: E402

TASKS = ("config/task-r1-goal.yaml", "config/task-r2-goal.yaml", "config/task-r2-n2-goal.yaml")
CALLS = (
    (AgentCore, "observe"),
    (AgentCore, "decide"),
    (Anticipating, "track"),
    (Anticipating, "revise"),
)


def timed(times: dict[str, list[float]]):
    """Wrap the agents' calls (:data:`CALLS`) to append their wall time to ``times``."""
    originals = []
    for cls, name in CALLS:
        fn = getattr(cls, name)
        originals.append((cls, name, fn))

        def wrapper(self, *args, _fn=fn, _name=name, **kwargs):
            t0 = time.perf_counter()
            try:
                return _fn(self, *args, **kwargs)
            finally:
                times[_name].append(time.perf_counter() - t0)

        setattr(cls, name, wrapper)
    return originals


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("tasks", nargs="*", type=Path, default=[REPO / t for t in TASKS])
    p.add_argument("--walks", type=Path, default=DEFAULT_WALKS)
    p.add_argument("--episodes", type=int, default=30)
    args = p.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    study = load_walks(args.walks)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-decision-") as tmp:
        for task in args.tasks:
            times: dict[str, list[float]] = defaultdict(list)
            scs = episode_scenarios(task.resolve(), args.episodes + 1, 0, study)
            # the first walk warms up (imports, the task's policy and models), untimed
            run_inprocess(scs[0], Path(tmp) / f"{task.stem}-warm", max_steps=0,
                          max_sim_s=study.max_sim_s, tail_s=study.tail_s,
                          say=lambda _s: None, perception="model")  # fmt: skip
            originals = timed(times)
            try:
                for k, sc in enumerate(scs[1:], 1):
                    run_inprocess(sc, Path(tmp) / f"{task.stem}-{k}", max_steps=0,
                                  max_sim_s=study.max_sim_s, tail_s=study.tail_s,
                                  say=lambda _s: None, perception="model")  # fmt: skip
                    n = sum(len(v) for v in times.values())
                    print(f"[decision] {task.stem} {k}/{args.episodes}: {n} calls", flush=True)
            finally:
                for cls, name, fn in originals:
                    setattr(cls, name, fn)
            for _cls, name in CALLS:
                ms = np.asarray(times[name]) * 1e3
                if len(ms):
                    rows.append((task.stem, name, len(ms), *np.percentile(ms, [50, 99]), ms.max()))
    print(f"\n{args.episodes} walks a task (seed 0), perception model, wall clock; "
          f"load {os.getloadavg()[0]:.1f}\n")  # fmt: skip
    print("| task | call | calls | median [ms] | p99 [ms] | max [ms] |")
    print("|---|---|---:|---:|---:|---:|")
    for task, name, n, med, p99, mx in rows:
        print(f"| {task} | {name} | {n} | {med:.2f} | {p99:.2f} | {mx:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
