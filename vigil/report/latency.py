"""How long the stack takes from a camera frame to a decision, and from a decision to motion.

Per decision step, from the run's records:

- **frame to decision**: the step's decision time (``stamp_s``) minus the stamp of the
  camera frame its observation's labels came from (``observation.frame_stamp_s``, the
  frame's capture time): the frame's age when it arrived, the people detector, the
  observations node and the planner together.
- **decision to motion**: for a step that moves a robot standing still, the first
  ground-truth record (``trace.jsonl``) after the decision in which the robot moves
  faster than :data:`MOVING_MPS`, minus the decision time: the navigation goal, the
  path, the follower, the base's command and its acceleration.
- **frame to motion**: the two summed, for the steps that have both.
- **frame to warning**: a warning's start in the speech log minus the stamp of the
  camera frame whose observation made the speech node warn (its ``frame_stamp_s``
  column): detector, observations, the speech node's decision and espeak-ng.

Each is reported as count, median, 95th percentile and maximum, against the budget of
docs/HARDWARE.md (:data:`BUDGET_S`, p95). In lock-step runs (the twin waits for the
stack) the times are simulated and hold only the sensors' periods and the base's
response; in real time (``vigil run --realtime``) and on the robot they are what the
stack costs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

MOVING_MPS = 0.05  # the robot moves: faster than this between two trace records
AT_REST_MPS = 0.02  # the robot stands still at a decision: slower than this
MOTION_WINDOW_S = 5.0  # no motion this long after a decision: the step is not counted
# docs/HARDWARE.md, "Latency budget": p95 of each, seconds
BUDGET_S = {
    "frame_to_decision_s": 0.5,
    "decision_to_motion_s": 0.5,
    "frame_to_motion_s": 1.0,
    "frame_to_warning_s": 1.0,
}


def _speeds(trace: Sequence[dict]) -> list[tuple[float, float]]:
    """(time, the robot's speed since the previous record) for each trace record with
    a robot pose after the first."""
    out: list[tuple[float, float]] = []
    prev: tuple[float, float, float] | None = None
    for rec in trace:
        robot = rec.get("robot")
        if not robot:
            continue
        t, x, y = float(rec["t"]), float(robot[0]), float(robot[1])
        if prev is not None and t > prev[0]:
            out.append((t, math.hypot(x - prev[1], y - prev[2]) / (t - prev[0])))
        prev = (t, x, y)
    return out


def _motion_after(speeds: list[tuple[float, float]], t0: float) -> float | None:
    """Seconds from ``t0`` to the first record after it with the robot moving, if it
    stood still at ``t0``; else None."""
    before = [v for t, v in speeds if t <= t0]
    if not before or before[-1] >= AT_REST_MPS:
        return None
    for t, v in speeds:
        if t <= t0:
            continue
        if t - t0 > MOTION_WINDOW_S:
            return None
        if v > MOVING_MPS:
            return t - t0
    return None


def stats(values: Sequence[float]) -> dict[str, Any]:
    """Count, median, 95th percentile (nearest rank) and maximum, in seconds."""
    if not values:
        return {"n": 0, "median_s": None, "p95_s": None, "max_s": None}
    v = sorted(values)
    p95 = v[min(len(v) - 1, math.ceil(0.95 * len(v)) - 1)]
    return {
        "n": len(v),
        "median_s": round(v[len(v) // 2], 4),
        "p95_s": round(p95, 4),
        "max_s": round(v[-1], 4),
    }


def latency(
    steps: Sequence[dict], trace: Sequence[dict], utterances: Sequence[Any] = ()
) -> dict[str, Any]:
    """The run's latencies (see the module's docstring) with the budget and whether
    each p95 is within it (None: nothing measured). ``utterances``: the speech log's
    (:class:`vigil.report.records.Utterance`: ``t`` and ``frame_stamp_s``)."""
    speeds = _speeds(trace)
    frame: list[float] = []
    motion: list[float] = []
    both: list[float] = []
    for rec in steps:
        obs = rec.get("observation") or {}
        t = float(rec["stamp_s"])
        f = obs.get("frame_stamp_s")
        to_decision = t - float(f) if isinstance(f, int | float) else None
        if to_decision is not None:
            frame.append(to_decision)
    # a decision's action is the next record's: its motion follows this record's stamp
    for rec, nxt in zip(steps, steps[1:], strict=False):
        if nxt.get("action") in (None, "Do nothing"):
            continue
        t = float(rec["stamp_s"])
        m = _motion_after(speeds, t)
        if m is None:
            continue
        motion.append(m)
        f = (rec.get("observation") or {}).get("frame_stamp_s")
        if isinstance(f, int | float):
            both.append(t - float(f) + m)
    out: dict[str, Any] = {
        "frame_to_decision_s": stats(frame),
        "decision_to_motion_s": stats(motion),
        "frame_to_motion_s": stats(both),
        "frame_to_warning_s": stats(
            [u.t - u.frame_stamp_s for u in utterances if u.frame_stamp_s is not None]
        ),
        "budget_p95_s": dict(BUDGET_S),
    }
    out["within_budget"] = {
        k: (None if out[k]["p95_s"] is None else out[k]["p95_s"] <= BUDGET_S[k]) for k in BUDGET_S
    }
    return out
