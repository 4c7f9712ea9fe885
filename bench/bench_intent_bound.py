"""How early the goal inference could send a guard, with perfect tracking (issue 26).

    .venv/bin/python bench/bench_intent_bound.py STUDY [--task config/task-r2-goal.yaml]
        [--episodes 400] [--wait-cell 6]

STUDY is a ``vigil montecarlo`` folder of the task. For each episode's first visit the
person's true floor positions (``trace.jsonl``, from the moment they are inside the
room) feed the task's own goal inference (:mod:`stack.planning.intent`), as if tracking
were perfect. A guard waits in ``--wait-cell`` and sets off when P(goal) of a restricted
cell first reaches the threshold; heading for the wrong cell, it goes there first and
then on (pessimistic: the real layer turns on the way). Its arrival against the
person's, per threshold and motion (cell moves at their mean 0.41 m/s; straight from
centre to centre at the base's top speed, 0.5 m/s; or today's trip, straight to the
point 0.35 m inside the cell nearest the robot, 0.5 m/s), gives the share of visits it
would be first and the mean delay: a bound for the rule, not for a better inference.
The last rows, "goal known on entry", are a clairvoyant guard's: it sets off for the
person's true cell the moment they come into the room (no inference at all, no
acceleration): a bound for any guard of this base waiting in that cell.

The last table, "leg known when it starts", counts every visit, not only the first: a
guard that learns where the person is going the moment they set off on the leg that
ends in the restricted cell (leave their last stop, or come in at the door) and goes
there at 0.5 m/s straight into the cell, from the rest cell before a walk's first
visit and from the restricted cell it guarded before the next. No goal inference can
know more than this at the leg's start; a walker who stops at a cell's border
(hesitate, decoy) counts from the door, the way to the border showing where they
go. Its share is what 50 % first asks of an inference.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from stack.planning.intent import GoalInference, TrackObservation  # noqa: E402
from stack.planning.task import load_task  # noqa: E402
from stack.vocabulary import TRIP_INSET_M  # noqa: E402

THRESHOLDS: tuple[float | str, ...] = (0.4, 0.5, 0.6, 0.8, "known")  # "known": clairvoyant
BEHAVIOURS = ("direct", "wander", "hesitate", "two_visits", "decoy", "pass_by")  # walks.yaml
MOTIONS = (
    ("cell moves at 0.41 m/s", 0.41, "cells"),
    ("centre to centre at 0.5 m/s", 0.5, "straight"),
    ("trip into the cell at 0.5 m/s", 0.5, "trip"),
)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("study", type=Path)
    p.add_argument("--task", type=Path, default=REPO / "config" / "task-r2-goal.yaml")
    p.add_argument("--episodes", type=int, default=400)
    p.add_argument("--wait-cell", type=int, default=6)
    p.add_argument("--door-y", type=float, default=5.2, help="inside the room below this y")
    args = p.parse_args()
    task = load_task(args.task)
    cfg = task.anticipation
    centre = {c: task.grid.center(c) for c in task.grid.cells}
    files = sorted(glob.glob(str(args.study / "episodes" / "*" / "episode.json")))
    visits = []  # (cell, arrival_t, {threshold: (t, cell first reaching it)}, behaviour)
    for f in files[: args.episodes]:
        episode = json.loads(Path(f).read_text())
        if not episode["visits"]:
            continue
        visit = episode["visits"][0]
        inference = GoalInference(task.grid, task.restricted_cells, cfg.intent, cfg.exits_m)
        cross: dict[float | str, tuple[float, int]] = {}
        for line in (Path(f).parent / "trace.jsonl").read_text().splitlines():
            rec = json.loads(line)
            if rec["t"] >= visit["person_arrival_t"]:
                break
            if not rec["person"] or rec["person"][1] > args.door_y:
                continue
            cross.setdefault("known", (rec["t"], visit["cell"]))
            est = inference.update(TrackObservation(rec["t"], tuple(rec["person"][:2])))
            best = max(task.restricted_cells, key=est.p)
            for th in THRESHOLDS:
                if th not in cross and isinstance(th, float) and est.p(best) >= th:
                    cross[th] = (rec["t"], best)
        words = episode.get("title", "").split()
        kind = next((w for w in words if w in BEHAVIOURS), "?")
        visits.append((visit["cell"], visit["person_arrival_t"], cross, kind))

    def leg(here: tuple[float, float], cell: int, motion: str) -> tuple[float, tuple]:
        """(length, end point) of the robot's leg from ``here`` to ``cell``."""
        if motion == "trip":
            end = task.grid.nearest_inside(cell, here[0], here[1], TRIP_INSET_M)
            return math.dist(here, end), end
        end = centre[cell]
        if motion == "cells":
            return abs(here[0] - end[0]) + abs(here[1] - end[1]), end
        return math.dist(here, end), end

    wait = centre[args.wait_cell]
    print(f"{len(visits)} first visits of {args.study.name}, the guard waiting in cell "
          f"{args.wait_cell}")  # fmt: skip
    print("| threshold | motion | robot first | mean delay | never reached |")
    print("|---|---|---:|---:|---:|")
    for th in THRESHOLDS:
        for label, speed, motion in MOTIONS:
            first, delays, never = 0, [], 0
            for cell, arrival, cross, _ in visits:
                if th not in cross:
                    never += 1
                    continue
                t, heading = cross[th]
                here = wait
                if heading != cell:  # the wrong cell first, then on from there
                    length, here = leg(here, heading, motion)
                    t += length / speed
                t += leg(here, cell, motion)[0] / speed
                first += t < arrival
                delays.append(max(0.0, t - arrival))
            name = "goal known on entry" if th == "known" else f"P >= {th}"
            print(f"| {name} | {label} | {100 * first / len(visits):.0f} % | "
                  f"{np.mean(delays):.1f} s | {never} |")  # fmt: skip
    # the clairvoyant trip, per walk behaviour: what the rest cell alone allows
    print()
    print("| behaviour | first visits | known on entry: robot first |")
    print("|---|---:|---:|")
    for kind in sorted({v[3] for v in visits}):
        rows = [v for v in visits if v[3] == kind]
        first = 0
        for cell, arrival, cross, _ in rows:
            t = cross["known"][0] + leg(wait, cell, "trip")[0] / 0.5
            first += t < arrival
        print(f"| {kind} | {len(rows)} | {100 * first / len(rows):.0f} % |")
    leg_known(files[: args.episodes], task, args.door_y)
    return 0


def leg_known(files: list[str], task, door_y: float) -> dict[str, list[int]]:
    """The "leg known when it starts" table (module docstring), per behaviour; returns
    {behaviour: [visits, first if the leg is known when it starts, first in the study]}."""
    grid, rows = task.grid, {}
    for f in files:
        episode = json.loads(Path(f).read_text())
        if not episode["visits"]:
            continue
        trace = [json.loads(x) for x in (Path(f).parent / "trace.jsonl").read_text().splitlines()]
        words = episode.get("title", "").split()
        kind = next((w for w in words if w in BEHAVIOURS), "?")
        wait = grid.center(task.rest_cell)
        for visit in episode["visits"]:
            arrival, cell = visit["person_arrival_t"], visit["cell"]
            start = trace[0]["t"]
            # the last moment before arrival the person stood or came in (a stop at the
            # border, hesitate's or a decoy's, is part of the leg: the way to the border
            # shows where they go)
            border = kind in ("hesitate", "decoy")
            for rec in trace:
                if rec["t"] >= arrival:
                    break
                vx, vy = rec.get("person_velocity") or (0.0, 0.0)
                outside = not rec["person"] or rec["person"][1] > door_y
                if outside or (not border and math.hypot(vx, vy) < 0.05):
                    start = rec["t"]
            end = grid.nearest_inside(cell, wait[0], wait[1], TRIP_INSET_M)
            row = rows.setdefault(kind, [0, 0, 0])
            row[0] += 1
            row[1] += start + math.dist(wait, end) / 0.5 < arrival
            row[2] += bool(visit["robot_first"])
            wait = grid.center(cell)
    print()
    print("| behaviour | visits | leg known when it starts: robot first | the study's guard |")
    print("|---|---:|---:|---:|")
    for kind in sorted(rows) + ["all"]:
        n, known, first = rows[kind] if kind != "all" else np.sum(list(rows.values()), axis=0)
        print(f"| {kind} | {n} | {100 * known / n:.0f} % | {100 * first / n:.0f} % |")
    return rows


if __name__ == "__main__":
    sys.exit(main())
