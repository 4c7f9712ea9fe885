"""The differential-drive mode end to end (issue 14): scenario 5.2.2 in the twin with
``navigation.drive: diff`` (the twin's base constrained to move along its heading, the
follower turning and driving forward only) still guards every visit.

It runs through the in-process loop with the camera's model: the navigation, planner,
speech and twin cores a ROS run uses (tests/test_inprocess.py shows the two transports
make the same steps), in half a minute instead of three and a half; the nodes'
parameters it writes are a ROS run's (``stack.yaml``)."""

import json
import math
from pathlib import Path

from vigil.inprocess import run_inprocess

REPO = Path(__file__).resolve().parents[1]


def test_a_differential_base_still_guards_every_visit_of_5_2_2(tmp_path):
    out = tmp_path / "diff"
    summary = run_inprocess(
        REPO / "scenarios" / "5.2.2.yaml",
        out,
        config_path=REPO / "config" / "twin-diff.yaml",
        perception="model",
        say=lambda s: None,
    )
    assert (out / "stack.yaml").read_text().count("drive: diff") == 1
    assert "drive: diff" in (out / "twin.yaml").read_text()
    m = summary["metrics"]
    assert m["n_visits"] >= 1 and m["guarded"] == m["n_visits"], m["visits"]
    assert m["late_warnings"] == 0 and m["n_false_trips"] == 0
    assert summary["left_map"] is False
    # the ground truth (10 Hz): the base moved along its heading only, and turned to do so
    poses = [json.loads(line)["robot"] for line in (out / "trace.jsonl").read_text().splitlines()]
    travelled, lateral, turned = 0.0, [], 0.0
    for (x0, y0, a0), (x1, y1, a1) in zip(poses, poses[1:], strict=False):
        da = math.remainder(a1 - a0, math.tau)
        mid = a0 + da / 2
        lateral.append(abs(-math.sin(mid) * (x1 - x0) + math.cos(mid) * (y1 - y0)))
        travelled += math.hypot(x1 - x0, y1 - y0)
        turned += abs(da)
    assert travelled > 2.0
    assert max(lateral) < 0.005, max(lateral)
    assert turned > math.pi  # a mecanum base holds its heading; this one turns to drive
