"""The report of one run, written after the nodes have stopped, from the run folder.

Modules, each one concern:

- :mod:`~vigil.report.records`: read and check ``steps.jsonl``, ``trace.jsonl``, the
  speech log (formats in its docstring);
- :mod:`~vigil.report.timeline`: the ground truth as cells over time (pure);
- :mod:`~vigil.report.metrics`: the guarding metrics from ground truth (pure);
- :mod:`~vigil.report.tables`: the step table and the metric tables (text);
- :mod:`~vigil.report.figures`: positions, belief, the guarding timeline, the set;
- :mod:`~vigil.report.video`: ``camera.mp4`` (H.264) from the recorder's frames;
- :mod:`~vigil.report.html`: ``index.html`` linking everything.

:func:`write_report` runs them all. The recorder node imports none of this: it only
writes raw records (``trace.jsonl``, ``camera_frames.bin``), so nothing here runs
inside the lock-step.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stack.cells import CellGrid
from stack.config import write_text
from stack.planning.model import FactoredModel
from stack.vocabulary import ACTIONS, OUT_OF_MAP
from vigil.report.latency import latency
from vigil.report.metrics import Timeline, guard_metrics, timeline_from_trace
from vigil.report.people import people_markdown, people_metrics, walkers_in_trace
from vigil.report.records import (
    UNKNOWN,
    RunRecordError,
    RunRecords,
    Utterance,
    cell_of_label,
    direction_of,
    load_run,
    read_jsonl,
    read_realtime,
    true_velocity_label,
)
from vigil.report.tables import (
    StepRow,
    metrics_markdown,
    reward_of,
    round_or_none,
    step_rows,
    steps_csv,
    steps_markdown,
)

if TYPE_CHECKING:
    from stack.planning.replay import Table

__all__ = [
    "RunRecordError",
    "read_jsonl",
    "room_of_run",
    "summarise",
    "true_velocity_label",
    "write_report",
]


def room_of_run(run_dir: str | Path) -> tuple[float, float, float, float] | None:
    """The room's inside (x0, y0, x1, y1) [m] from the run's ``twin.yaml``; None when
    there is none (hardware, table runs) or it cannot be read."""
    path = Path(run_dir) / "twin.yaml"
    if not path.exists():
        return None
    try:
        from stack.config import load_yaml, read_text_capped
        from twin.config import TwinConfig
        from twin.scene import layout_of

        data = load_yaml(read_text_capped(path))
        return tuple(layout_of(TwinConfig.from_dict(data.get("twin", data))).room)
    except Exception:  # noqa: BLE001 - a report never fails on an unreadable side file
        return None


def summarise(
    model: FactoredModel,
    rows: Sequence[StepRow],
    records: RunRecords,
    tl: Timeline,
    wavs: Sequence[str],
    thesis_table: Table | None = None,
) -> dict:
    """The run's summary (JSON-ready, deterministic); ``metrics`` holds the guarding
    metrics (:func:`vigil.report.metrics.guard_metrics`)."""
    task = model.task
    restricted = tuple(task.restricted_cells)
    trace = records.trace
    horizon = tl.t[-1] if len(tl) else None
    utterances: list[Utterance] = [
        u for u in records.utterances if horizon is None or u.t <= horizon + 1e-9
    ]
    step_obs = [
        (
            r.stamp_s,
            None if r.obs_person == UNKNOWN else r.obs_person,
            r.source or None,
        )
        for r in rows
    ]
    metrics = guard_metrics(tl, restricted, [u.t for u in utterances], step_obs, grid=task.grid)
    metrics["speech_source"] = records.speech_source

    left_trace = [
        t for t, c, k in zip(tl.t, tl.robot, tl.robot_known, strict=True) if k and c is None
    ]
    left_steps = [r.step for r in rows if r.obs_robot == OUT_OF_MAP]
    in_region = [t for t, c in zip(tl.t, tl.person, strict=True) if c is not None]
    person_last = in_region[-1] if in_region else None
    returned, returned_t, still_there = None, None, False
    if person_last is not None:
        still_there = tl.person[-1] is not None
        later = [
            t
            for t, c in zip(tl.t, tl.robot, strict=True)
            if t > person_last and c == task.rest_cell
        ]
        returned_t = later[0] if later else None
        returned = None if still_there else returned_t is not None

    spoken = []
    for u, w in zip(utterances, metrics["warnings"], strict=True):
        spoken.append(
            {
                "t": round_or_none(u.t),
                "duration_s": u.duration_s,
                "text": u.text,
                "robot_cell": w["robot_cell"],
                "robot_in_restricted": w["robot_cell"] in restricted,
                "person_cell": w["person_cell"],
                "timely": w["timely"],
            }
        )

    camera = Counter()
    nav = Counter()
    for rec in trace:
        cam = rec.get("camera")
        camera["missing" if not isinstance(cam, dict) else str(cam.get("status"))] += 1
    for r in rows:
        if r.nav_result:
            nav[r.nav_result] += 1

    def agreement(pairs: list[tuple[str, str]]) -> dict:
        known = [(o, t) for o, t in pairs if UNKNOWN not in (o, t)]
        return {"same": sum(o == t for o, t in known), "compared": len(known)}

    rewarded = [r for r in rows if r.reward is not None]
    bases = sorted({r.reward_basis for r in rewarded})
    observed_total = 0.0
    R = model.reward_table().reshape(model.n_states, len(ACTIONS))
    n_observed = 0
    for r in rows:
        if r.obs_robot != UNKNOWN:
            rw = reward_of(
                model,
                R,
                cell_of_label(r.obs_robot),
                cell_of_label(r.obs_person),
                r.obs_velocity,
                r.action,
            )
            observed_total += rw * task.discount ** (r.step - 1)
            n_observed += 1
    times = [float(rec["t"]) for rec in trace]
    summary: dict[str, Any] = {
        "task": task.name,
        "restricted_cells": list(restricted),
        "rest_cell": task.rest_cell,
        "discount": task.discount,
        "ground_truth": tl.source == "ground truth",
        "events_source": tl.source,
        "events_until_t": round_or_none(horizon),
        "steps": len(rows),
        "step_errors": sum(1 for r in rows if r.error),
        "resumed_steps": sum(1 for r in rows if r.resumed),
        "actions": dict(sorted(Counter(r.action for r in rows).items())),
        "total_discounted_reward": round_or_none(sum(r.discounted for r in rewarded))
        if rows
        else 0.0,
        "total_reward": round_or_none(sum(r.reward for r in rewarded)) if rows else 0.0,
        "reward_basis": "+".join(bases) if bases else None,
        "steps_without_reward": len(rows) - len(rewarded),
        "total_discounted_reward_observed": round_or_none(observed_total) if n_observed else None,
        "metrics": metrics,
        "visits": metrics["visits"],
        # honest: the robot was in the cell while the person was, at every visit
        "robot_reached_every_visit": bool(metrics["visits"]) and metrics["every_visit_guarded"],
        "left_map": bool(left_trace or left_steps),
        "left_map_first_t": round_or_none(left_trace[0]) if left_trace else None,
        "left_map_observed_steps": left_steps,
        "person_last_in_region_t": round_or_none(person_last),
        "person_in_region_at_end": still_there,
        "returned_to_rest": returned,
        "returned_to_rest_t": round_or_none(returned_t),
        "warning_in_restricted": any(s["robot_in_restricted"] for s in spoken),
        "warnings_spoken": spoken,
        "wav_files": list(wavs),
        "trace": {
            "records": len(trace),
            "start_t": round_or_none(times[0]) if times else None,
            "end_t": round_or_none(times[-1]) if times else None,
            "camera_status": dict(sorted(camera.items())),
            "camera_person_frames": camera.get("person", 0),
            "frames_with_legs": sum(1 for rec in trace if rec.get("legs")),
            "speech_utterances": len(spoken),
        },
        "nav_results": dict(sorted(nav.items())),
        "observation_agreement": {
            "robot": agreement([(r.obs_robot, r.true_robot) for r in rows]),
            "person": agreement([(r.obs_person, r.true_person) for r in rows]),
            "velocity": agreement([(r.obs_velocity, r.true_velocity) for r in rows]),
            "direction": agreement(
                [
                    (direction_of(r.obs_velocity), direction_of(r.true_velocity))
                    if UNKNOWN not in (r.obs_velocity, r.true_velocity)
                    else (UNKNOWN, UNKNOWN)
                    for r in rows
                ]
            ),
        },
        "warnings": list(records.warnings),
    }
    if thesis_table is not None:
        common = min(len(thesis_table.steps), len(rows))
        summary["thesis"] = {
            "table": thesis_table.name,
            "thesis_steps": len(thesis_table.steps),
            "same_action": sum(
                rows[k].action == thesis_table.steps[k].action for k in range(common)
            ),
            "compared": common,
        }
    return summary


def write_report(
    run_dir: str | Path,
    task_path: str | Path,
    thesis_table: Table | None = None,
    *,
    plots: bool = True,
    video: bool = True,
    say: Callable[[str], None] | None = None,
) -> dict:
    """Write the report into ``run_dir`` from its records; return the summary.

    Files: ``steps.md``, ``steps.csv``, ``summary.json``; with ``plots``
    ``positions.png``, ``belief.png``, ``timeline.png``; with ``video`` ``camera.mp4``
    (when the recorder stored frames); always ``index.html``.

    Events and metrics end at the last decision's stamp (after it the twin runs on
    until a wall-clock stop). Every time in the report is seconds since the run's
    start, in lock-step (the simulated clock, as recorded) and in real time or on the
    robot (the system clock's epoch stamps less the run's earliest, which
    ``summary.json`` then holds as ``time_origin_s``): :func:`records.load_run`.
    Deterministic: the same inputs give byte-identical steps.md, steps.csv and
    summary.json (and PNGs, with the same matplotlib).

    Args:
        say: progress lines (about one a second while the video is written); None: quiet.

    Raises:
        RunRecordError: a malformed record (file and line named), or neither
            steps.jsonl nor trace.jsonl exists.
    """
    from stack.planning.runtime import task_model, task_of  # read once a process

    run_dir = Path(run_dir)
    task = task_of(str(task_path))
    model = task_model(str(task_path))
    grid: CellGrid = task.grid
    records = load_run(run_dir, model.n_cells)
    steps, trace = records.steps, records.trace
    until = float(steps[-1]["stamp_s"]) if steps else None
    room = room_of_run(run_dir)
    tl = timeline_from_trace(trace, grid, room, until)

    rows = step_rows(model, steps, trace, tl)
    wavs = sorted(p.relative_to(run_dir).as_posix() for p in (run_dir / "speech").glob("*.wav"))
    title = f"{run_dir.name} ({task.name})"
    summary = summarise(model, rows, records, tl, wavs, thesis_table)
    summary["latency"] = latency(steps, trace, records.utterances)  # camera to motion, warning
    if records.origin_s:  # the system clock: every time above is since this stamp
        summary["time_origin_s"] = records.origin_s
    realtime = read_realtime(run_dir, records.warnings)
    if realtime is not None:  # a real-time twin: how well it kept the wall clock
        summary["realtime"] = realtime
    walkers = walkers_in_trace(trace)
    if walkers > 1:  # several people (issue 16): visits per person
        tls = [timeline_from_trace(trace, grid, room, until, walker=i) for i in range(walkers)]
        warned = [w["t"] for w in summary["metrics"]["warnings"]]
        summary["people"] = people_metrics(
            tls, task.restricted_cells, grid=grid, warning_starts=warned
        )
    md = steps_markdown(rows, title, thesis_table, task.discount)
    md += "\n" + metrics_markdown(summary["metrics"])
    if "people" in summary:
        md += "\n" + people_markdown(summary["people"])
    write_text(run_dir / "steps.md", md, encoding="utf-8")
    write_text(run_dir / "steps.csv", steps_csv(rows), encoding="utf-8")
    files = ["steps.md", "steps.csv"]
    if plots:
        from vigil.report.figures import plot_run, plot_timeline

        files += plot_run(run_dir, model, rows, thesis_table, title)
        plot_timeline(
            run_dir / "timeline.png",
            tl,
            summary["metrics"],
            n_cells=model.n_cells,
            restricted=task.restricted_cells,
            rest_cell=task.rest_cell,
            steps=[(r.stamp_s, r.outcome) for r in rows],
            title=title,
        )
        files.append("timeline.png")
    if video and trace:
        from vigil.report.video import write_video

        t0 = time.monotonic()
        path = write_video(
            run_dir,
            grid,
            task.restricted_cells,
            trace,
            steps,
            rest_cell=task.rest_cell,
            room_m=room,
            say=say,
            origin_s=records.origin_s,
        )
        if path is not None:
            files.append(path.name)
            if say is not None:
                say(f"[report] {path.name}: {len(trace)} frames in {time.monotonic() - t0:.1f} s")
    summary["files"] = sorted(files + ["summary.json", "index.html"])
    write_text(
        run_dir / "summary.json",
        json.dumps(summary, indent=2, sort_keys=True) + "\n",
        encoding="utf-8",
    )
    from vigil.report.html import write_index

    write_index(run_dir, title, summary)
    return summary
