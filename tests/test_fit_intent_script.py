"""scripts/fit_intent.py: a study's camera tracks cut into legs labelled with the cell
each walker heads for (issue 26)."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

from fit_intent import labelled_tracks  # noqa: E402

from stack.planning.task import load_task  # noqa: E402
from vigil.montecarlo import episode_scenarios  # noqa: E402
from vigil.walks import load_walks  # noqa: E402

TASK = REPO / "config" / "task-r2-goal.yaml"
WALKS = REPO / "config" / "walks.yaml"


def _study(tmp_path: Path, n: int = 3, seed: int = 4) -> Path:
    """A study folder as ``vigil montecarlo`` writes it, with traces of each walk's
    legs walked straight at 1 m/s (the camera seeing the true position)."""
    study = load_walks(WALKS)
    scenarios = episode_scenarios(TASK, n, seed, study)
    episodes = []
    for k, sc in enumerate(scenarios):
        points = [leg.to for leg in sc.walkers[0].walk[1:] if isinstance(leg.to, tuple | list)]
        here, t, lines = np.array([7.0, 4.4]), 0.0, []
        for p in points:
            p = np.array(p, float)
            steps = max(1, int(np.linalg.norm(p - here) / 0.1))
            for i in range(1, steps + 1):
                x = here + (p - here) * i / steps
                rec = {"t": round(t, 2), "person": [float(x[0]), float(x[1])],
                       "camera": {"position_m": [float(x[0]), float(x[1])]}}  # fmt: skip
                lines.append(json.dumps(rec))
                t += 0.1
            here = p
        folder = tmp_path / "episodes" / f"{k:03d}"
        folder.mkdir(parents=True)
        (folder / "trace.jsonl").write_text("\n".join(lines) + "\n")
        episodes.append({"episode": f"mc-{k:03d}", "title": sc.title, "task": "task-r2-goal"})
    summary = {"task": str(TASK), "seed": seed, "episodes": episodes,
               "study": json.loads(json.dumps(dataclasses.asdict(study)))}  # fmt: skip
    (tmp_path / "montecarlo.json").write_text(json.dumps(summary))
    return tmp_path


def test_each_leg_is_labelled_with_the_cell_its_walker_heads_for(tmp_path):
    task = load_task(TASK)
    study = _study(tmp_path)
    tracks = labelled_tracks(study, task, WALKS, None)
    scenarios = episode_scenarios(TASK, 3, 4, load_walks(WALKS))
    expected = [task.grid.cell_at(*leg.to) for sc in scenarios for leg in sc.walkers[0].walk[1:]
                if isinstance(leg.to, tuple | list)]  # fmt: skip
    assert expected and [tr.goal for tr in tracks] == expected
    for tr in tracks:  # every position of a leg is on the way to its cell, off the door zone
        assert len(tr.observations) > 1
        assert all(math.dist(o.position_m, (7.0, 5.2)) > 1.0 for o in tr.observations)
        end = tr.observations[-1].position_m
        assert task.grid.cell_at(*end) == tr.goal


def test_the_script_runs_on_a_study_and_prints_both_fits(tmp_path):
    study = _study(tmp_path, n=4)
    out = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "fit_intent.py"), str(study), "--task", str(TASK)],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    ).stdout
    assert "legs" in out and "rationality_per_m" in out and "calibrated:" in out
