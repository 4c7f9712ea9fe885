"""Cell-to-cell moves of the navigation stack in the MuJoCo twin: simulated and wall time.

Run from the repository root:

    MUJOCO_GL=egl .venv/bin/python bench/bench_nav_twin.py            # 5 seeds
    MUJOCO_GL=egl .venv/bin/python bench/bench_nav_twin.py --repeats 2

The PathFollower (default FollowerConfig) runs in closed loop with ``Twin.step`` (one
20 ms control period per follower step), on the twin's own map saved as map_server
YAML + PGM and loaded with stack.nav, with the wheel odometry as the pose (the
navigation node's default ``pose_source``). The person stands in the room's north-west
corner, away from the cells; nothing is rendered. A move's simulated time runs from the
goal to the follower's SUCCEEDED; "settled" adds the time until the base is at rest
(zero commands after the result). Wall time is the closed loop (follower + twin) only.
Each repeat builds a fresh twin with another odometry-noise seed. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stack.cells import Direction  # noqa: E402
from stack.nav.config import FollowerConfig  # noqa: E402
from stack.nav.follower import NavResult, PathFollower, Pose2D  # noqa: E402
from stack.nav.occupancy import load_map_yaml  # noqa: E402
from stack.nav.waypoints import ActionOutcome, CellWaypoints  # noqa: E402
from twin.config import PersonConfig, RobotConfig, TwinConfig, Waypoint  # noqa: E402
from twin.twin import Twin, VelocityCommand  # noqa: E402


@dataclass
class Move:
    result: NavResult
    sim_s: float  # goal -> SUCCEEDED
    settle_s: float  # SUCCEEDED -> base at rest
    wall_s: float  # closed loop to SUCCEEDED
    steps: int
    error_m: float  # ground truth at rest to the waypoint
    cell: int | None


def drive(tw: Twin, follower: PathFollower, goal: tuple[float, float]) -> Move:
    follower.start(goal, tw.time_s)
    t0, w0, steps = tw.time_s, time.perf_counter(), 0
    while True:
        o = tw.odometry()
        st = follower.step(Pose2D(o.pose.x_m, o.pose.y_m, o.pose.yaw_rad), o.time_s, tw.time_s)
        if st.result is not None:
            break
        c = st.cmd
        tw.step(VelocityCommand(c.vx_mps, c.vy_mps, c.wz_radps))
        steps += 1
    wall = time.perf_counter() - w0
    sim = tw.time_s - t0
    while max(abs(v) for v in tw.ground_truth().robot_velocity) > 1e-3:
        tw.step(VelocityCommand())
    gt = tw.ground_truth()
    err = math.hypot(gt.robot.x_m - goal[0], gt.robot.y_m - goal[1])
    return Move(st.result, sim, tw.time_s - t0 - sim, wall, steps, err, gt.robot_cell)


def make(seed: int, start_cell: int, map_dir: str) -> tuple[Twin, PathFollower]:
    person = PersonConfig(waypoints=(Waypoint(x_m=-2.5, y_m=4.3),))
    cfg = TwinConfig(person=person, robot=replace(RobotConfig(), start_cell=start_cell))
    tw = Twin(cfg, seed=seed)
    _, yaml_path = tw.save_map(map_dir, "lrm")
    return tw, PathFollower(FollowerConfig(), load_map_yaml(yaml_path))


def run_case(seed: int, start: int, actions: list[Direction] | None, goal_cell: int, tmp: str):
    """Either a chain of actions (each starts when the previous result arrives, as the
    planner would) or one direct goal; returns per-move records."""
    tw, fol = make(seed, start, tmp)
    wp = CellWaypoints(tw.config.grid)
    moves = []
    if actions is None:
        moves.append(drive(tw, fol, wp.waypoint(goal_cell)))
    else:
        cell = start
        for a in actions:
            tgt = wp.target(cell, a)
            assert tgt.outcome is ActionOutcome.MOVE, tgt.reason
            moves.append(drive(tw, fol, tgt.waypoint_m))
            cell = tw.ground_truth().robot_cell
    tw.close()
    assert moves[-1].cell == goal_cell, (start, actions, moves[-1])
    return moves


def fmt(xs: list[float], digits: int = 2) -> str:
    med = statistics.median(xs)
    if len(xs) == 1 or max(xs) - min(xs) < 0.5 * 10**-digits:
        return f"{med:.{digits}f}"
    return f"{med:.{digits}f} ({min(xs):.{digits}f}-{max(xs):.{digits}f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="seeds per case")
    args = ap.parse_args()
    E, W, N, S = Direction.EAST, Direction.WEST, Direction.NORTH, Direction.SOUTH
    cases = [
        ("cell 7 -> 5, East (1.00 m)", 7, [E], 5),
        ("cell 5 -> 7, West (1.00 m)", 5, [W], 7),
        ("cell 7 -> 8, North (1.50 m)", 7, [N], 8),
        ("cell 8 -> 7, South (1.50 m)", 8, [S], 7),
        ("cell 12 -> 1 by actions S, E x5 (6 moves, 6.50 m)", 12, [S, E, E, E, E, E], 1),
        ("cell 12 -> 1 as one goal (5.22 m straight)", 12, None, 1),
    ]
    print(f"python {platform.python_version()}, {platform.machine()}, repeats {args.repeats}")
    print()
    print(
        "| move | simulated to SUCCEEDED | + until at rest | wall (closed loop) "
        "| per step | final error (gt) |"
    )
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, start, actions, goal in cases:
            sims, settles, walls, per, errs = [], [], [], [], []
            for seed in range(args.repeats):
                moves = run_case(seed, start, actions, goal, tmp)
                assert all(m.result is NavResult.SUCCEEDED for m in moves), moves
                sims.append(sum(m.sim_s for m in moves))
                # the chain rolls straight into the next move; only the last one settles
                settles.append(moves[-1].settle_s)
                walls.append(sum(m.wall_s for m in moves))
                per.append(1e3 * sum(m.wall_s for m in moves) / sum(m.steps for m in moves))
                errs.append(100 * moves[-1].error_m)
            print(
                f"| {name} | {fmt(sims)} s | {fmt(settles)} s | {fmt(walls, 3)} s "
                f"| {fmt(per)} ms | {fmt(errs, 1)} cm |"
            )


if __name__ == "__main__":
    main()
