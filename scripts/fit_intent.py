"""Fit the goal inference's rationality and lapse to the walks of a Monte-Carlo study.

    .venv/bin/python scripts/fit_intent.py STUDY [STUDY ...] [--task TASK]
        [--walks config/walks.yaml] [--episodes N] [--holdout STUDY]

STUDY is a ``vigil montecarlo`` folder of a one-person task. Each episode's walk is
drawn again from the study's seed (:func:`vigil.montecarlo.episode_scenarios`), and
the floor positions the camera gave the planner (``trace.jsonl``) are cut into legs:
each position is labelled with the cell the walker is heading for (the leg under way,
from the true position), or the room's exit on the way out, as the guard would have
seen them. Positions within ``door_zone_m`` of an exit are left out, as the inference
leaves them out. Two fits of the rationality:

- the maximum likelihood of the steps (:func:`stack.planning.intent.fit_rationality`,
  rationality and lapse), which counts each step as independent evidence;
- the calibration of the belief (:func:`stack.planning.intent.calibrate_rationality`):
  the rationality whose goal beliefs give the walks' true goals the best mean
  log-probability, with the task's priors, exits and lapse. This is what the guard
  acts on, and what ``intent.rationality_per_m`` should be.

``--holdout`` studies (``TASK=STUDY``) are scored with both and with the task's own
parameters, on walks the fits did not see.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from stack.planning.intent import (  # noqa: E402
    GoalInference,
    LabelledTrack,
    TrackObservation,
    calibrate_rationality,
    fit_rationality,
    goal_log_score,
    track_log_likelihood,
)
from stack.planning.task import Task, load_task  # noqa: E402
from vigil.montecarlo import episode_scenarios  # noqa: E402
from vigil.walks import load_walks  # noqa: E402

ARRIVED_M = 0.1  # a walker this close to its leg's point has walked that leg


def _tuples(d: dict) -> dict:
    """JSON's lists back to the tuples a StudyConfig holds."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}


def labelled_tracks(study: Path, task: Task, walks: Path, limit: int | None) -> list[LabelledTrack]:
    """The study's camera tracks, one per leg, labelled with the leg's goal."""
    summary = json.loads((study / "montecarlo.json").read_text())
    episodes = summary["episodes"]
    # the study's own walk distribution, as it recorded it (else the walks file)
    study_cfg = load_walks(walks)
    if isinstance(summary.get("study"), dict):
        study_cfg = dataclasses.replace(study_cfg, **_tuples(summary["study"]))
    scenarios = episode_scenarios(Path(summary["task"]), len(episodes), int(summary["seed"]),
                                  study_cfg)  # fmt: skip
    cfg = task.anticipation
    exits = [tuple(e) for e in cfg.exits_m]
    door_zone = cfg.intent.door_zone_m
    tracks: list[LabelledTrack] = []
    for episode in episodes[:limit]:
        k = int(episode["episode"].split("-")[1])
        scenario = scenarios[k]
        if len(scenario.walkers) != 1:
            continue
        legs = [leg.to for leg in scenario.walkers[0].walk[1:]]  # after coming in
        trace = study / "episodes" / f"{k:03d}" / "trace.jsonl"
        if not trace.exists():
            continue
        i, current, obs = 0, None, []
        for line in trace.read_text().splitlines():
            rec = json.loads(line)
            truth = rec.get("person")
            while i < len(legs) and truth and isinstance(legs[i], tuple | list):
                if math.dist(truth[:2], legs[i]) > ARRIVED_M:
                    break
                i += 1  # arrived: the next leg's goal from now on
            if i >= len(legs):
                break
            to = legs[i]
            if isinstance(to, tuple | list):
                goal = task.grid.cell_at(float(to[0]), float(to[1]))
            elif to == "door" and exits:
                goal = exits[0]
            else:
                goal = None
            if goal != current:
                if current is not None and len(obs) > 1:
                    tracks.append(LabelledTrack(current, tuple(obs)))
                current, obs = goal, []
            seen = (rec.get("camera") or {}).get("position_m")
            if goal is None or seen is None:
                continue
            if any(math.dist(seen, e) <= door_zone for e in exits):
                continue
            obs.append(TrackObservation(float(rec["t"]), (float(seen[0]), float(seen[1]))))
        if current is not None and len(obs) > 1:
            tracks.append(LabelledTrack(current, tuple(obs)))
    return tracks


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("study", type=Path, nargs="+")
    p.add_argument("--task", type=Path, default=REPO / "config" / "task-r2-goal.yaml")
    p.add_argument("--walks", type=Path, default=REPO / "config" / "walks.yaml")
    p.add_argument("--episodes", type=int, default=None, help="the first N of each study")
    p.add_argument("--holdout", type=Path, action="append", default=[],
                   help="a study to score, not fit (its own --task: TASK=STUDY)")  # fmt: skip
    args = p.parse_args()
    task = load_task(args.task)
    own = task.anticipation.intent
    tracks = []
    for study in args.study:
        got = labelled_tracks(study, task, args.walks, args.episodes)
        print(f"{study.name}: {len(got)} legs")
        tracks += got
    fit = fit_rationality(tracks, task.grid, own)
    beta = fit.rationality_per_m
    print(f"fit on {fit.steps} steps: rationality_per_m {beta:.2f}, lapse {fit.lapse:.3f}")
    mine = track_log_likelihood(tracks, task.grid, own)
    print(f"log-likelihood a step: fitted {fit.log_likelihood / fit.steps:.4f}, the task's "
          f"({own.rationality_per_m}, {own.lapse}) {mine / fit.steps:.4f}")  # fmt: skip

    def inference(t: Task, beta: float | None = None) -> GoalInference:
        cfg = t.anticipation.intent
        if beta is not None:
            cfg = dataclasses.replace(cfg, rationality_per_m=beta)
        return GoalInference.for_task(t, cfg, t.anticipation.exits_m)

    calibrated, scores = calibrate_rationality(tracks, inference(task))
    print("mean log P(true goal) by rationality_per_m: "
          + ", ".join(f"{b:g}: {v:.4f}" for b, v in scores.items()))  # fmt: skip
    print(f"calibrated: rationality_per_m {calibrated:g} (the task's {own.rationality_per_m:g})")
    for spec in args.holdout:
        held_task = task
        if "=" in str(spec):
            t, s = str(spec).split("=", 1)
            held_task, spec = load_task(Path(t)), Path(s)
        held = labelled_tracks(spec, held_task, args.walks, args.episodes)
        fitted = dataclasses.replace(
            held_task.anticipation.intent, rationality_per_m=beta, lapse=fit.lapse
        )
        n = sum(max(0, len(t.observations) - 1) for t in held)
        a = track_log_likelihood(held, held_task.grid, fitted)
        b = track_log_likelihood(held, held_task.grid, held_task.anticipation.intent)
        print(f"held out {spec.name} ({len(held)} legs): log-likelihood fitted {a:.1f}, "
              f"the task's {b:.1f} (about {n} positions)")  # fmt: skip
        cal = goal_log_score(held, inference(held_task, calibrated))
        mine_held = goal_log_score(held, inference(held_task))
        print(f"held out {spec.name}: mean log P(true goal) calibrated {cal:.4f}, "
              f"the task's {mine_held:.4f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
