"""Actions and goals in, velocity commands and results out: the navigation node's core.

Pure (no rclpy): :mod:`stack.nav.node_navigation` feeds it messages and publishes what
it returns; an in-process loop can drive it the same way.

- An **action** ("North" ... "Do nothing", table 3.2) becomes a cell waypoint
  (:class:`~stack.nav.waypoints.CellWaypoints`) followed on an A* path
  (:class:`~stack.nav.follower.PathFollower`). A move is reported ``succeeded`` once
  the robot is ``arrive_margin_m`` inside its target cell; the robot drives on to the
  waypoint meanwhile, so the next decision comes while it still moves. An action
  toward the cell of the move under way keeps it driving. "Do nothing" during a move
  settles the robot in the cell it is in (not on a border); at rest it holds.
- A **trip** ("To 1", :func:`stack.vocabulary.parse_trip`) drives straight into a cell
  at top speed, to the point of it nearest the robot that no person stands on
  (:func:`~stack.nav.waypoints.entry_point`), reported like a move once the robot is
  inside it; a trip to the cell of the trip under way keeps it driving.
- A **goal pose** in the map frame is followed the same way, reported on arrival.
- **Stop** cancels at once with zero velocity and refuses goals until released.

Every call returns a list of :class:`Output`: ``cmd`` (a :class:`Twist2D`), ``result``
and ``progress`` (JSON-ready dicts), ``log`` (a warning).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from stack.cells import CellGrid
from stack.geometry import Pose2D
from stack.nav.config import FollowerConfig
from stack.nav.follower import (
    ZERO_TWIST,
    FollowerState,
    FollowerStatus,
    NavErrorCode,
    NavResult,
    PathFollower,
    Twist2D,
    cap_twist,
)
from stack.nav.occupancy import OccupancyMap
from stack.nav.waypoints import ActionOutcome, CellWaypoints, entry_point, parse_action
from stack.vocabulary import parse_trip, trip_command


@dataclass(frozen=True)
class Output:
    kind: str  # "cmd" | "result" | "progress" | "log"
    cmd: Twist2D = ZERO_TWIST
    body: dict[str, Any] = field(default_factory=dict)
    text: str = ""


class ActionExecutor:
    """The navigation state for one robot.

    Args:
        grid: the cells.
        config: the follower's limits.
        occ_map: the map to plan on (replace with :meth:`set_map`).
        progress_every: ticks between progress reports.
    """

    def __init__(
        self,
        grid: CellGrid,
        config: FollowerConfig,
        occ_map: OccupancyMap,
        progress_every: int = 10,
    ):
        self.grid, self.config = grid, config
        self.waypoints = CellWaypoints(grid)
        self.follower = PathFollower(config, occ_map)
        self.pose: Pose2D | None = None
        self.pose_stamp_s = -math.inf
        self.people: list[tuple[float, float]] = []
        self.stopped = False
        self.goal_id = 0
        self.task: dict[str, Any] = {}
        self.arrived = False  # the move's success was reported on entering its cell
        self._was_moving = False
        self._ticks = 0
        self._progress_every = max(1, int(progress_every))

    # -- inputs ------------------------------------------------------------------
    def set_pose(self, pose: Pose2D, now_s: float) -> list[Output]:
        """The robot's pose in the map frame, received at ``now_s`` (a non-finite one is
        ignored: a source that stops publishing makes the last pose stale)."""
        if not pose.is_finite():
            return [Output("log", text=f"ignoring a non-finite pose {pose}")]
        self.pose, self.pose_stamp_s = pose, now_s
        return []

    def set_people(self, people: list[tuple[float, float]]) -> None:
        self.people = [(x, y) for x, y in people if math.isfinite(x) and math.isfinite(y)]

    def set_map(self, occ_map: OccupancyMap) -> None:
        self.follower.set_map(occ_map)

    def stop(self, stopped: bool) -> list[Output]:
        self.stopped = bool(stopped)
        out: list[Output] = []
        if self.stopped:
            out.append(Output("cmd", ZERO_TWIST))
            if self.follower.active:
                out += self._report(self.follower.cancel("stop requested"))
        return out

    def cancel(self, goal_id: int, reason: str) -> list[Output]:
        """Cancel goal ``goal_id`` if it is the one under way (a zero command and its
        "canceled" result); nothing for another goal or when idle."""
        if goal_id != self.goal_id or not self.follower.active:
            return []
        return [Output("cmd", ZERO_TWIST), *self._report(self.follower.cancel(reason))]

    def action(self, raw: str | int, now_s: float, goal_id: int = 0) -> list[Output]:
        """One of the thesis's actions (name or :class:`stack.cells.Direction` number).

        ``goal_id``: the sender's id for it, carried by its result and progress (0: the
        sender gave none, e.g. ``/nav/action_id``; the planner's ids start at 1).
        """
        previous_target = self.task.get("target_cell") if self.follower.active else None
        gid = int(goal_id)
        task: dict[str, Any]
        if isinstance(raw, str) and (dest := parse_trip(raw)) is not None:
            return self._trip(dest, now_s, gid, previous_target)
        # a refused goal is answered under its own id and leaves the goal under way (its
        # id, task and motion) as it was: it never takes over another goal's id
        try:
            action = parse_action(raw)
        except ValueError as exc:
            task = {"action": None}
            return [
                Output("log", text=str(exc)),
                self._result(NavResult.REFUSED, NavErrorCode.INVALID_ACTION, str(exc), gid, task),
            ]
        task = {"action": action.label if action.value < 4 else "Do nothing"}
        if self.pose is None:
            no_pose = NavErrorCode.NO_POSE
            return [self._result(NavResult.REFUSED, no_pose, "no pose yet", gid, task)]
        cell = self.waypoints.cell_of(self.pose.x_m, self.pose.y_m)
        target = self.waypoints.target(cell, action)
        task.update(from_cell=cell, target_cell=target.cell)
        waypoint = target.waypoint_m
        if target.outcome is ActionOutcome.REFUSED:
            leaves = NavErrorCode.ACTION_LEAVES_MAP
            return [
                Output("log", text=f"refusing action: {target.reason}"),
                self._result(NavResult.REFUSED, leaves, target.reason, gid, task),
            ]
        self.goal_id, self.task = gid, task
        out: list[Output] = []
        if target.outcome is ActionOutcome.HOLD:
            if self.follower.active and previous_target != cell:
                # stopped mid-move: settle in the cell it is in, not on a border
                out += self._begin(self.waypoints.waypoint(cell), now_s, cell)
                self.arrived = True
            elif not self.follower.active:
                out.append(Output("cmd", ZERO_TWIST))
            # else: already in the cell, settling on its waypoint: let it
            out.append(self._result(NavResult.SUCCEEDED, NavErrorCode.NONE, "holding position"))
        elif target.cell == previous_target:
            # the same cell as the move under way: keep driving, report under this goal
            if self.arrived:
                out.append(
                    self._result(NavResult.SUCCEEDED, NavErrorCode.NONE, "in the target cell")
                )
        elif waypoint is not None:
            out += self._begin(waypoint, now_s, target.cell)
        return out

    def _trip(self, dest: int, now_s: float, gid: int, previous_target: int | None) -> list[Output]:
        """A trip into cell ``dest`` (see the module)."""
        task: dict[str, Any] = {"action": trip_command(dest)}
        if dest not in self.grid.cells:
            text = f"trip to cell {dest}: no such cell (cells {min(self.grid.cells)}.."
            text += f"{max(self.grid.cells)})"
            return [
                Output("log", text=text),
                self._result(NavResult.REFUSED, NavErrorCode.INVALID_ACTION, text, gid, task),
            ]
        if self.pose is None:
            no_pose = NavErrorCode.NO_POSE
            return [self._result(NavResult.REFUSED, no_pose, "no pose yet", gid, task)]
        cell = self.waypoints.cell_of(self.pose.x_m, self.pose.y_m)
        task.update(from_cell=cell, target_cell=dest)
        self.goal_id, self.task = gid, task
        if dest == previous_target:  # the trip under way: keep driving
            if self.arrived:
                return [self._result(NavResult.SUCCEEDED, NavErrorCode.NONE, "in the target cell")]
            return []
        c = self.config
        point = entry_point(
            self.grid, dest, (self.pose.x_m, self.pose.y_m), self.people,
            c.trip_inset_m, c.trip_clearance_m,
        )  # fmt: skip
        out = self._begin(point, now_s, dest)
        if not self.stopped and self.in_target_cell():
            self.arrived = True  # already inside: done, settling on the entry point
            out.append(self._result(NavResult.SUCCEEDED, NavErrorCode.NONE, "in the target cell"))
        return out

    def goal(self, x: float, y: float, now_s: float, goal_id: int = 0) -> list[Output]:
        """A goal point in the map frame (``goal_id`` as in :meth:`action`)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return [Output("log", text=f"ignoring a non-finite goal ({x}, {y})")]
        self.goal_id = int(goal_id)
        self.task = {"action": "goal_pose", "target_cell": self.grid.cell_at(x, y)}
        return self._begin((x, y), now_s)

    # -- the control loop ----------------------------------------------------------
    def tick(self, now_s: float) -> list[Output]:
        """One control step."""
        self._ticks += 1
        if not self.follower.active:
            if self._was_moving:  # one zero after a task ends; idle otherwise is silent
                self._was_moving = False
                return [Output("cmd", ZERO_TWIST)]
            return []
        status = self.follower.step(self.pose, self.pose_stamp_s, now_s, self.people)
        cmd = ZERO_TWIST if self.stopped else cap_twist(status.cmd, self.config)
        out = [Output("cmd", cmd)]
        self._was_moving = True
        if status.result is not None:
            if not (self.arrived and status.result is NavResult.SUCCEEDED):
                out += self._report(status)  # (an arrival was reported on entering the cell)
        elif not self.arrived and self.in_target_cell():
            self.arrived = True  # the goal cell is reached: report now, settle on its waypoint
            out.append(self._result(NavResult.SUCCEEDED, NavErrorCode.NONE, "in the target cell"))
        elif self._ticks % self._progress_every == 0:
            out.append(self._progress(status))
        return out

    # -- state ---------------------------------------------------------------------
    def in_target_cell(self) -> bool:
        """The robot is ``arrive_margin_m`` inside the cell its action moves it to."""
        target = self.task.get("target_cell")
        if self.pose is None or target is None or self.task.get("action") == "goal_pose":
            return False
        m = self.config.arrive_margin_m
        x0, y0, x1, y1 = self.grid.bounds(target)
        return x0 + m <= self.pose.x_m <= x1 - m and y0 + m <= self.pose.y_m <= y1 - m

    def robot_cell(self) -> int | None:
        if self.pose is None:
            return None
        return self.grid.cell_at(self.pose.x_m, self.pose.y_m)

    # -- internals -----------------------------------------------------------------
    def _begin(
        self, goal_xy: tuple[float, float], now_s: float, cell: int | None = None
    ) -> list[Output]:
        if self.stopped:
            return [self._result(NavResult.CANCELED, NavErrorCode.STOPPED, "stop is active")]
        region = self.grid.bounds(cell) if cell is not None else None
        self.arrived = False
        self.follower.start(goal_xy, now_s, region)
        return []

    def _report(self, status: FollowerStatus) -> list[Output]:
        assert status.result is not None
        out = []
        if status.state is FollowerState.DONE and status.result is not NavResult.SUCCEEDED:
            out.append(Output("log", text=f"navigation {status.result.value}: {status.message}"))
        out.append(self._result(status.result, status.error_code, status.message))
        return out

    def _progress(self, status: FollowerStatus) -> Output:
        dist = status.distance_remaining_m
        return Output(
            "progress",
            body={
                "goal_id": self.goal_id,
                "state": status.state.value,
                "distance_remaining_m": None if math.isnan(dist) else round(dist, 3),
                "replans": status.replans,
                "message": status.message,
                "cell": self.robot_cell(),
            },
        )

    def _result(
        self,
        result: NavResult,
        code: NavErrorCode,
        message: str,
        goal_id: int | None = None,
        task: dict | None = None,
    ) -> Output:
        """The result of the goal under way, or of ``goal_id`` with ``task`` (a refusal)."""
        task = self.task if task is None else task
        return Output(
            "result",
            body={
                "goal_id": self.goal_id if goal_id is None else goal_id,
                "result": result.value,
                "error_code": int(code),
                "error_name": code.name,
                "message": message,
                "action": task.get("action"),
                "from_cell": task.get("from_cell"),
                "target_cell": task.get("target_cell"),
                "cell": self.robot_cell(),
            },
        )
