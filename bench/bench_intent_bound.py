"""How early the goal inference could send a guard, with no latency (issue 26).

    .venv/bin/python bench/bench_intent_bound.py STUDY [--task config/task-r2-goal.yaml]
        [--episodes 1000] [--wait-cell 5]

STUDY is a ``vigil montecarlo`` folder of the task. For each episode's first visit the
person's floor positions (``trace.jsonl``, from the moment they are inside the room)
feed the task's own goal inference (:mod:`stack.planning.intent`): their true
positions (perfect tracking), and the camera's (``camera.position_m``: what the
camera's model saw, with its misses, noise and lag). A guard waits in
``--wait-cell`` and sets off when P(goal) of a restricted cell first reaches the
threshold; heading for the wrong cell, it goes there first and then on (pessimistic:
the real layer turns on the way). It drives as the base does: straight toward the
point 0.35 m inside the cell nearest it (today's trip) at 0.5 m/s after accelerating at
the follower's 0.8 m/s^2, and it is in the cell when its centre crosses the border (as
the metrics count it). Its arrival against the person's gives the share of visits it
would be first and the mean delay: a bound for the rule on that track, with no
decision or control latency. The last rows, "goal known on entry", are a
clairvoyant guard's: it sets off for the person's true cell the moment they come into
the room (no inference at all): a bound for any guard of this base waiting in that cell.

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

from stack.cells import CellGrid  # noqa: E402
from stack.nav.config import FollowerConfig  # noqa: E402
from stack.planning.intent import GoalInference, TrackObservation  # noqa: E402
from stack.planning.task import load_task  # noqa: E402
from stack.vocabulary import TRIP_INSET_M  # noqa: E402

THRESHOLDS: tuple[float | str, ...] = (0.4, 0.5, 0.6, 0.8, "known")  # "known": clairvoyant
BEHAVIOURS = ("direct", "wander", "hesitate", "two_visits", "decoy", "pass_by")  # walks.yaml
SPEED_MPS = 0.5  # the base's top speed (FollowerConfig.max_speed_mps)
ACCEL_MPS2 = FollowerConfig().max_accel_x_mps2
SOURCES = ("true positions", "the camera's")


def drive_s(
    distance_m: float, speed_mps: float = SPEED_MPS, accel_mps2: float = ACCEL_MPS2
) -> float:
    """Seconds to cover ``distance_m`` from rest: accelerating at ``accel_mps2`` up to
    ``speed_mps``, then at that speed."""
    ramp_m = speed_mps**2 / (2.0 * accel_mps2)
    if distance_m <= ramp_m:
        return math.sqrt(2.0 * distance_m / accel_mps2)
    return speed_mps / accel_mps2 + (distance_m - ramp_m) / speed_mps


def trip(grid: CellGrid, here: tuple[float, float], cell: int) -> tuple[float, tuple[float, float]]:
    """(the way to the border m, the end point) of a trip from ``here`` straight toward
    the point ``TRIP_INSET_M`` inside ``cell`` nearest it: the robot is in the cell
    once its centre crosses the border."""
    end = grid.nearest_inside(cell, here[0], here[1], TRIP_INSET_M)
    x0, y0, x1, y1 = grid.bounds(cell)
    enter = 0.0  # the segment's parameter where it is inside both slabs
    for a, b, lo, hi in ((here[0], end[0], x0, x1), (here[1], end[1], y0, y1)):
        if lo <= a <= hi:
            continue
        enter = max(enter, ((lo if a < lo else hi) - a) / (b - a))
    return enter * math.dist(here, end), end


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("study", type=Path)
    p.add_argument("--task", type=Path, default=REPO / "config" / "task-r2-goal.yaml")
    p.add_argument("--episodes", type=int, default=1000, help="the study's first episodes")
    p.add_argument("--wait-cell", type=int, default=5)
    p.add_argument("--door-y", type=float, default=5.2, help="inside the room below this y")
    args = p.parse_args()
    task = load_task(args.task)
    cfg, grid = task.anticipation, task.grid
    files = sorted(glob.glob(str(args.study / "episodes" / "*" / "episode.json")))
    # (cell, arrival_t, {source: {threshold: (t, cell first reaching it)}}, behaviour)
    visits = []
    for f in files[: args.episodes]:
        episode = json.loads(Path(f).read_text())
        if not episode["visits"]:
            continue
        visit = episode["visits"][0]
        inference = {
            s: GoalInference(grid, task.restricted_cells, cfg.intent, cfg.exits_m) for s in SOURCES
        }
        cross: dict[str, dict[float | str, tuple[float, int]]] = {s: {} for s in SOURCES}
        for line in (Path(f).parent / "trace.jsonl").read_text().splitlines():
            rec = json.loads(line)
            if rec["t"] >= visit["person_arrival_t"]:
                break
            if not rec["person"] or rec["person"][1] > args.door_y:
                continue
            camera = (rec.get("camera") or {}).get("position_m")
            for source, point in zip(SOURCES, (rec["person"], camera), strict=True):
                cross[source].setdefault("known", (rec["t"], visit["cell"]))
                if point is None:
                    continue
                est = inference[source].update(TrackObservation(rec["t"], tuple(point[:2])))
                best = max(task.restricted_cells, key=est.p)
                for th in THRESHOLDS:
                    if th not in cross[source] and isinstance(th, float) and est.p(best) >= th:
                        cross[source][th] = (rec["t"], best)
        words = episode.get("title", "").split()
        kind = next((w for w in words if w in BEHAVIOURS), "?")
        visits.append((visit["cell"], visit["person_arrival_t"], cross, kind))

    wait = grid.center(args.wait_cell)
    print(f"{len(visits)} first visits of {args.study.name}, the guard waiting in cell "
          f"{args.wait_cell}")  # fmt: skip
    print("| threshold | inference fed | robot first | mean delay | never reached |")
    print("|---|---|---:|---:|---:|")
    for th in THRESHOLDS:
        for source in SOURCES[:1] if th == "known" else SOURCES:
            first, delays, never = 0, [], 0
            for cell, arrival, cross, _ in visits:
                if th not in cross[source]:
                    never += 1
                    continue
                t, heading = cross[source][th]
                here = wait
                if heading != cell:  # the wrong cell first (to its entry point), then on
                    here = trip(grid, here, heading)[1]
                    t += drive_s(math.dist(wait, here))
                t += drive_s(trip(grid, here, cell)[0])
                first += t < arrival
                delays.append(max(0.0, t - arrival))
            name = "goal known on entry" if th == "known" else f"P >= {th}"
            fed = "-" if th == "known" else source
            print(f"| {name} | {fed} | {100 * first / len(visits):.0f} % | "
                  f"{np.mean(delays):.1f} s | {never} |")  # fmt: skip
    # the clairvoyant trip, per walk behaviour: what the rest cell alone allows
    print()
    print("| behaviour | first visits | known on entry: robot first |")
    print("|---|---:|---:|")
    for kind in sorted({v[3] for v in visits}):
        rows = [v for v in visits if v[3] == kind]
        first = 0
        for cell, arrival, cross, _ in rows:
            t = cross[SOURCES[0]]["known"][0] + drive_s(trip(grid, wait, cell)[0])
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
            row = rows.setdefault(kind, [0, 0, 0])
            row[0] += 1
            row[1] += start + drive_s(trip(grid, wait, cell)[0]) < arrival
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
