"""bench/bench_intent_bound.py's "leg known when it starts" bound (issue 26): a guard
that learns a leg's destination the moment the person leaves their last stop."""

from __future__ import annotations

import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from bench_intent_bound import leg_known  # noqa: E402

from stack.planning.task import load_task  # noqa: E402

TASK = REPO / "config" / "task-r2-goal.yaml"  # rest cell 5, restricted 1 and 12
GRID = load_task(TASK).grid


def _episode(folder: Path, stop: tuple[float, float], end_x: float, speed: float, cell: int):
    """A person standing at ``stop`` for 10 s, then walking along y to ``end_x``."""
    lines, t, x = [], 0.0, stop[0]
    while t < 10.0:
        lines.append({"t": round(t, 2), "person": list(stop), "person_velocity": [0.0, 0.0]})
        t += 0.1
    step = speed * 0.1 * (1 if end_x > x else -1)
    arrival = None
    while (end_x - x) * step > 0:
        x += step
        lines.append(
            {"t": round(t, 2), "person": [x, stop[1]], "person_velocity": [step * 10, 0.0]}
        )
        if arrival is None and GRID.cell_at(x, stop[1]) == cell:
            arrival = round(t, 2)
        t += 0.1
    folder.mkdir(parents=True)
    (folder / "trace.jsonl").write_text("\n".join(json.dumps(r) for r in lines) + "\n")
    visit = {"cell": cell, "person_arrival_t": arrival, "robot_first": False}
    (folder / "episode.json").write_text(
        json.dumps({"title": f"random walk: direct R{cell}", "visits": [visit]})
    )
    return str(folder / "episode.json")


def test_the_guard_is_first_only_where_its_trip_beats_the_last_leg(tmp_path, capsys):
    task = load_task(TASK)
    files = [
        # from cell 8 at 1 m/s to 12: 2 s of walking, the guard's trip from 5 is 6 s
        _episode(tmp_path / "a", (3.0, 2.25), 0.5, 1.0, 12),
        # from cell 3 at 0.1 m/s to 1: 5 s of walking, the guard's trip is 3.7 s
        _episode(tmp_path / "b", (4.5, 0.75), 5.5, 0.1, 1),
    ]
    rows = leg_known(files, task, door_y=5.2)
    assert rows == {"direct": [2, 1, 0]}
    assert "| all | 2 | 50 % | 0 % |" in capsys.readouterr().out
