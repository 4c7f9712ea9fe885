"""The run's latencies (vigil.report.latency) on synthetic records with known answers."""

from __future__ import annotations

import pytest

from vigil.report.latency import BUDGET_S, latency, stats


def trace_of(moves: list[tuple[float, float]], until: float, dt: float = 0.04) -> list[dict]:
    """Robot at x = 0 until each (t_start, speed) segment; records every ``dt``."""
    out, x, t = [], 0.0, 0.0
    while t <= until + 1e-9:
        speed = next((v for t0, v in reversed(moves) if t >= t0), 0.0)
        out.append({"t": round(t, 6), "robot": [x, 0.0, 0.0]})
        x += speed * dt
        t += dt
    return out


def step(n: int, t: float, action: str, frame: float | None) -> dict:
    obs = {"robot": "7", "person": "5", "velocity": "Not moving"}
    if frame is not None:
        obs["frame_stamp_s"] = frame
    return {"step": n, "stamp_s": t, "action": action, "observation": obs}


def test_frame_to_decision_decision_to_motion_and_their_sum():
    # decisions at 1.0 s (frame 0.92) and 3.0 s (frame 2.75); the robot starts moving
    # 0.2 s after the first (its next action moves) and never after the second (Do nothing)
    steps = [
        step(1, 1.0, "Do nothing", 0.92),
        step(2, 3.0, "East", 2.75),
        step(3, 5.0, "Do nothing", None),
    ]
    trace = trace_of([(1.2, 0.3), (2.0, 0.0)], until=6.0)
    got = latency(steps, trace)
    assert got["frame_to_decision_s"]["n"] == 2
    assert got["frame_to_decision_s"]["max_s"] == pytest.approx(0.25)
    assert got["decision_to_motion_s"]["n"] == 1
    # the first record showing motion: the one after 1.2 s (speed measured since the last)
    assert got["decision_to_motion_s"]["median_s"] == pytest.approx(0.24, abs=1e-6)
    assert got["frame_to_motion_s"]["median_s"] == pytest.approx(0.08 + 0.24, abs=1e-6)
    assert got["within_budget"] == dict.fromkeys(BUDGET_S, True) | {"frame_to_warning_s": None}


def test_a_robot_already_moving_or_that_never_moves_is_not_counted():
    steps = [step(1, 1.0, "East", 0.9), step(2, 2.0, "East", 1.9), step(3, 9.0, "East", 8.9)]
    trace = trace_of([(0.0, 0.3)], until=3.0) + [{"t": 9.5, "robot": [0.9, 0, 0]}]
    got = latency(steps, trace)
    assert got["decision_to_motion_s"]["n"] == 0  # moving at every decision
    assert got["within_budget"]["decision_to_motion_s"] is None
    assert got["frame_to_decision_s"]["n"] == 3


def test_a_slow_stack_is_outside_the_budget():
    steps = [step(1, 2.0, "Do nothing", 1.0), step(2, 4.0, "East", 3.9)]
    got = latency(steps, trace_of([(3.0, 0.3)], until=4.0))
    assert got["frame_to_decision_s"]["p95_s"] == pytest.approx(1.0)
    assert got["within_budget"]["frame_to_decision_s"] is False
    assert got["decision_to_motion_s"]["median_s"] == pytest.approx(1.04, abs=1e-6)
    assert got["within_budget"]["decision_to_motion_s"] is False


def test_stats_nearest_rank():
    s = stats([float(k) for k in range(1, 21)])
    assert (s["n"], s["median_s"], s["p95_s"], s["max_s"]) == (20, 11.0, 19.0, 20.0)
    assert stats([])["median_s"] is None


def test_frame_to_warning_from_the_speech_log():
    from vigil.report.records import Utterance

    said = [Utterance(5.0, 2.0, "warning", "a.wav", 4.7), Utterance(9.0, 1.0, "hello", "b.wav")]
    got = latency([], [], said)
    assert got["frame_to_warning_s"]["n"] == 1
    assert got["frame_to_warning_s"]["median_s"] == pytest.approx(0.3)
    assert got["within_budget"]["frame_to_warning_s"] is True
