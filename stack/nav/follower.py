"""Path following to a goal point, holonomic or differential drive, with replanning
around people.

The mecanum base moves in any planar direction without turning, so the follower steers
a velocity vector straight at a carrot point ``lookahead_m`` ahead on the A* path and
turns that map-frame velocity into body-frame (vx, vy); the yaw rate only holds the
heading the robot had when the task began. A differential-drive base
(``drive: diff``) turns towards the carrot instead (on the spot beyond
``turn_in_place_rad``) and drives forward only. The orientation is ignored at the goal
(thesis 4.4): the task succeeds once the position is within ``goal_tolerance_m``.

Long-running tasks report, they do not raise (nav2 ``TaskResult``): every call to
:meth:`PathFollower.step` returns a :class:`FollowerStatus` with the command to send and,
once the task has ended, its :class:`NavResult` and :class:`NavErrorCode`.

Safety rules, in order: a stale or missing pose gives zero velocity at once (no ramp);
a person on the path makes the follower replan with the person stamped on the grid,
and wait (zero velocity) while no path exists, ending BLOCKED after
``blocked_timeout_s``; every command is capped by :func:`cap_twist`.

It is just over 500 lines because the follower's state machine (plan, track, wait,
region fallback, end) reads best as one class with its small helpers beside it.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from stack.geometry import Pose2D
from stack.nav.astar import GridPath, NoPathError, NoPathReason, astar_grid, reachable
from stack.nav.config import FollowerConfig
from stack.nav.occupancy import OccupancyMap, disc_mask, inflate


class NavResult(enum.Enum):
    """How a navigation task ended (nav2 ``TaskResult`` plus the cases vigil needs)."""

    SUCCEEDED = "succeeded"
    BLOCKED = "blocked"  # a person stayed in the way for blocked_timeout_s
    NO_PATH = "no_path"  # the static map has no path (goal in a wall, no connection)
    TIMED_OUT = "timed_out"
    CANCELED = "canceled"  # stop requested or superseded by a new goal
    REFUSED = "refused"  # the action would leave the map: nothing was done


class NavErrorCode(enum.IntEnum):
    """Machine-readable detail of a result (0 on success)."""

    NONE = 0
    START_OUTSIDE_MAP = 101
    GOAL_OUTSIDE_MAP = 102
    START_OCCUPIED = 103
    GOAL_OCCUPIED = 104
    NO_CONNECTION = 105
    PATH_BLOCKED_BY_PERSON = 106
    TIMEOUT = 107
    CANCELED = 108
    ACTION_LEAVES_MAP = 109
    NO_MAP = 110
    NO_POSE = 111
    INVALID_ACTION = 112
    STOPPED = 113


_REASON_CODE = {
    NoPathReason.START_OUTSIDE: NavErrorCode.START_OUTSIDE_MAP,
    NoPathReason.GOAL_OUTSIDE: NavErrorCode.GOAL_OUTSIDE_MAP,
    NoPathReason.START_BLOCKED: NavErrorCode.START_OCCUPIED,
    NoPathReason.GOAL_BLOCKED: NavErrorCode.GOAL_OCCUPIED,
    NoPathReason.NO_CONNECTION: NavErrorCode.NO_CONNECTION,
}


class FollowerState(enum.Enum):
    IDLE = "idle"  # no task
    ACTIVE = "active"  # following the path
    WAITING = "waiting"  # a person blocks every path: holding still
    STALE_POSE = "stale_pose"  # holding still until a fresh pose arrives
    DONE = "done"  # the task has just ended (see result)


@dataclass(frozen=True)
class Twist2D:
    """Body-frame velocity command: vx forward, vy left [m/s], wz counter-clockwise [rad/s]."""

    vx_mps: float = 0.0
    vy_mps: float = 0.0
    wz_radps: float = 0.0

    def is_zero(self) -> bool:
        return self.vx_mps == 0.0 and self.vy_mps == 0.0 and self.wz_radps == 0.0


ZERO_TWIST = Twist2D()


@dataclass(frozen=True)
class FollowerStatus:
    """What one control step decided.

    Attributes:
        cmd: the body-frame command to send now (already capped).
        state: the follower's state after this step.
        result: set on the step the task ends, else None.
        error_code: detail of ``result`` (NONE while running or on success).
        message: human-readable detail ("" when there is nothing to say).
        distance_remaining_m: along the path to the goal (nan when unknown).
        replans: how many times the path has been replanned in this task.
    """

    cmd: Twist2D
    state: FollowerState
    result: NavResult | None = None
    error_code: NavErrorCode = NavErrorCode.NONE
    message: str = ""
    distance_remaining_m: float = math.nan
    replans: int = 0


def cap_twist(cmd: Twist2D, config: FollowerConfig) -> Twist2D:
    """Scale a command into the configured velocity limits, keeping its direction.

    The planar part is scaled by one factor so that |vx| <= max_vx, |vy| <= max_vy and
    |(vx, vy)| <= max_speed; wz is clipped. Non-finite values become zero.
    """
    vx, vy, wz = cmd.vx_mps, cmd.vy_mps, cmd.wz_radps
    if not (math.isfinite(vx) and math.isfinite(vy)):
        vx = vy = 0.0
    if config.drive == "diff":
        vy = 0.0  # a differential base cannot move sideways
    if not math.isfinite(wz):
        wz = 0.0
    scale = 1.0
    if abs(vx) > config.max_vx_mps:
        scale = min(scale, config.max_vx_mps / abs(vx))
    if abs(vy) > config.max_vy_mps:
        scale = min(scale, config.max_vy_mps / abs(vy))
    speed = math.hypot(vx, vy)
    if speed > config.max_speed_mps:
        scale = min(scale, config.max_speed_mps / speed)
    wz = max(-config.max_wz_radps, min(config.max_wz_radps, wz))
    return Twist2D(vx * scale, vy * scale, wz)


def limit_accel(cmd: Twist2D, prev: Twist2D, dt_s: float, config: FollowerConfig) -> Twist2D:
    """Limit the change from ``prev`` to ``cmd`` over ``dt_s`` to the acceleration limits."""

    def clamp(new: float, old: float, a: float) -> float:
        d = a * dt_s
        return max(old - d, min(old + d, new))

    return Twist2D(
        clamp(cmd.vx_mps, prev.vx_mps, config.max_accel_x_mps2),
        clamp(cmd.vy_mps, prev.vy_mps, config.max_accel_y_mps2),
        clamp(cmd.wz_radps, prev.wz_radps, config.max_accel_wz_radps2),
    )


CLOSEST_EXTRA_M = 0.15  # beside a person who stepped up to the robot: the least gap kept
REPLAN_SLACK_M = 0.1  # a person this much nearer a path than planned does not void it


def _wrap(a: float) -> float:
    return math.remainder(a, 2.0 * math.pi)


class PathFollower:
    """Plans with A* on the inflated map and follows the path with a holonomic base.

    Args:
        config: limits, tolerances and timeouts.
        occ_map: the static occupancy map (inflated here by the robot radius + margin).
    """

    def __init__(self, config: FollowerConfig, occ_map: OccupancyMap):
        self.config = config
        self.set_map(occ_map)
        self._goal: tuple[float, float] | None = None
        self._region: tuple[float, float, float, float] | None = None
        self._beside = False
        self._people = np.zeros((0, 2))
        self._state = FollowerState.IDLE
        self._prev_cmd = ZERO_TWIST
        self._last_step_s: float | None = None
        self._path = np.zeros((0, 2))
        self._path_cells = np.zeros((0, 2), dtype=int)
        self._index = 0
        self._replans = 0
        self._start_s = 0.0
        self._hold_yaw: float | None = None
        self._waiting_since: float | None = None
        self._last_try_s = -math.inf

    # -- setup ---------------------------------------------------------------
    def set_map(self, occ_map: OccupancyMap) -> None:
        """Replace the static map (e.g. a new ``/map``); the current path is replanned."""
        self.map = occ_map
        self.static_blocked = inflate(
            occ_map, self.config.inflation_radius_m, self.config.unknown_is_occupied
        )
        self._path = np.zeros((0, 2))
        self._path_cells = np.zeros((0, 2), dtype=int)

    @property
    def active(self) -> bool:
        return self._state in (
            FollowerState.ACTIVE,
            FollowerState.WAITING,
            FollowerState.STALE_POSE,
        )

    @property
    def state(self) -> FollowerState:
        return self._state

    @property
    def goal(self) -> tuple[float, float] | None:
        return self._goal

    @property
    def path(self) -> np.ndarray:
        """The current path as (N, 2) map points, ending at the goal itself."""
        return self._path.copy()

    # -- task control --------------------------------------------------------
    def start(
        self,
        goal_xy: tuple[float, float],
        now_s: float,
        region: tuple[float, float, float, float] | None = None,
    ) -> None:
        """Begin a task to ``goal_xy`` (supersedes any running task).

        The path is planned on the next :meth:`step`, where the pose is known.
        ``region`` (x_min, y_min, x_max, y_max): the target cell. When people make the
        goal unreachable, the follower drives to the nearest free point of the region
        instead (``region_margin_m`` inside it): the robot reaches the person's cell.
        """
        self._goal = (float(goal_xy[0]), float(goal_xy[1]))
        self._region = region
        self._beside = False
        self._people = np.zeros((0, 2))
        self._state = FollowerState.ACTIVE
        self._start_s = now_s
        self._replans = -1  # the first plan is not a replan
        self._path = np.zeros((0, 2))
        self._path_cells = np.zeros((0, 2), dtype=int)
        self._index = 0
        self._hold_yaw = None
        self._waiting_since = None
        self._last_try_s = -math.inf
        self._last_step_s = None  # the first step starts from rest: no acceleration credit

    def cancel(self, message: str = "canceled") -> FollowerStatus:
        """End the running task with CANCELED and zero velocity."""
        was_active = self.active
        self._finish()
        if not was_active:
            return FollowerStatus(ZERO_TWIST, FollowerState.IDLE, message=message)
        return FollowerStatus(
            ZERO_TWIST,
            FollowerState.DONE,
            NavResult.CANCELED,
            NavErrorCode.CANCELED,
            message,
            replans=max(self._replans, 0),
        )

    def _finish(self) -> None:
        self._state = FollowerState.IDLE
        self._goal = None
        self._prev_cmd = ZERO_TWIST

    def _end(
        self, result: NavResult, code: NavErrorCode, message: str, dist: float = math.nan
    ) -> FollowerStatus:
        replans = max(self._replans, 0)
        self._finish()
        return FollowerStatus(
            ZERO_TWIST, FollowerState.DONE, result, code, message, dist, replans=replans
        )

    # -- the control step ----------------------------------------------------
    def step(
        self,
        pose: Pose2D | None,
        pose_stamp_s: float,
        now_s: float,
        people_xy: Iterable[tuple[float, float]] = (),
    ) -> FollowerStatus:
        """One control cycle.

        Args:
            pose: the latest robot pose in the map frame (None if none has arrived).
            pose_stamp_s: when that pose was measured [s], same clock as ``now_s``.
            now_s: the current time [s].
            people_xy: map positions of people near the robot [m].

        Returns:
            The command to publish and the state; ``result`` is set when the task ends.
        """
        cfg = self.config
        dt = 0.0 if self._last_step_s is None else max(0.0, min(now_s - self._last_step_s, 0.2))
        self._last_step_s = now_s
        if not self.active or self._goal is None:
            self._prev_cmd = ZERO_TWIST
            return FollowerStatus(ZERO_TWIST, FollowerState.IDLE)
        if now_s - self._start_s > cfg.timeout_s:
            return self._end(
                NavResult.TIMED_OUT,
                NavErrorCode.TIMEOUT,
                f"goal not reached within {cfg.timeout_s:g} s",
            )
        if pose is None or not (now_s - pose_stamp_s <= cfg.stale_pose_s):
            self._state = FollowerState.STALE_POSE
            self._prev_cmd = ZERO_TWIST  # stop at once: no deceleration ramp on a blind robot
            age = "no pose" if pose is None else f"pose is {now_s - pose_stamp_s:.2f} s old"
            return FollowerStatus(
                ZERO_TWIST, FollowerState.STALE_POSE, message=age, replans=max(self._replans, 0)
            )
        if self._hold_yaw is None:
            self._hold_yaw = pose.yaw_rad
        if self._state is FollowerState.STALE_POSE:
            self._state = FollowerState.ACTIVE

        pos = np.array([pose.x_m, pose.y_m])
        goal = np.array(self._goal)
        d_goal = float(np.hypot(*(goal - pos)))
        if d_goal <= cfg.goal_tolerance_m:
            return self._end(NavResult.SUCCEEDED, NavErrorCode.NONE, "", d_goal)

        people = np.asarray(list(people_xy), dtype=float).reshape(-1, 2)
        if self._in_region_beside_person_on_goal(pos, goal, people):
            return self._end(
                NavResult.SUCCEEDED, NavErrorCode.NONE,
                "in the target cell; a person stands on its waypoint", d_goal,
            )  # fmt: skip
        # beside a person in the target cell: contact clearance only (see _plan_into_region)
        keep = cfg.robot_radius_m if self._beside else cfg.inflation_radius_m
        radius = cfg.person_radius_m + keep
        self._people = people
        if self._state is FollowerState.WAITING:
            need_plan = now_s - self._last_try_s >= cfg.replan_period_s
        else:
            # a path planned round people stays valid while they stay within
            # REPLAN_SLACK_M of where it assumed them: a track's jitter does not flip
            # the way round a person from one side to the other
            slack = disc_mask(self.map, people, radius - REPLAN_SLACK_M)
            need_plan = len(self._path) == 0 or self._path_blocked(slack)
        if need_plan:
            status = self._replan(pose, disc_mask(self.map, people, radius), now_s)
            if status is not None:
                return status
        if self._state is FollowerState.WAITING:
            return self._hold(now_s, d_goal)

        cmd, dist = self._track(pos, goal, pose, d_goal)
        cmd = cap_twist(limit_accel(cap_twist(cmd, cfg), self._prev_cmd, dt, cfg), cfg)
        self._prev_cmd = cmd
        return FollowerStatus(
            cmd, FollowerState.ACTIVE, distance_remaining_m=dist, replans=self._replans
        )

    def _in_region_beside_person_on_goal(
        self, pos: np.ndarray, goal: np.ndarray, people: np.ndarray
    ) -> bool:
        """Inside the target cell (``region_margin_m`` in) with a person on its waypoint."""
        cfg = self.config
        if len(people) == 0 or not self._in_region(pos[0], pos[1], cfg.region_margin_m):
            return False
        reach = cfg.person_radius_m + cfg.robot_radius_m + cfg.goal_tolerance_m
        return bool(np.hypot(*(people - goal).T).min() <= reach)

    def _in_region(self, x: float, y: float, margin_m: float = 0.0) -> bool:
        """(x, y) lies in the target region, ``margin_m`` inside its borders."""
        if self._region is None:
            return False
        x0, y0, x1, y1 = self._region
        return x0 + margin_m <= x <= x1 - margin_m and y0 + margin_m <= y <= y1 - margin_m

    def _hold(self, now_s: float, d_goal: float) -> FollowerStatus:
        assert self._waiting_since is not None
        if now_s - self._waiting_since >= self.config.blocked_timeout_s:
            return self._end(
                NavResult.BLOCKED,
                NavErrorCode.PATH_BLOCKED_BY_PERSON,
                f"a person blocked the way for {now_s - self._waiting_since:.1f} s",
                d_goal,
            )
        self._prev_cmd = ZERO_TWIST
        return FollowerStatus(
            ZERO_TWIST,
            FollowerState.WAITING,
            message="waiting for the way to clear",
            distance_remaining_m=d_goal,
            replans=max(self._replans, 0),
        )

    def _path_blocked(self, person_mask: np.ndarray) -> bool:
        ahead = self._path_cells[self._index :]
        if len(ahead) == 0:
            return False
        return bool(person_mask[ahead[:, 0], ahead[:, 1]].any())

    def _replan(self, pose: Pose2D, person_mask: np.ndarray, now_s: float) -> FollowerStatus | None:
        """Plan from the pose; returns a status only when the task ends or must wait."""
        self._last_try_s = now_s
        assert self._goal is not None
        start = self._start_cell(pose)
        goal_cell = self.map.world_to_cell(*self._goal)
        # first the static map alone: failing there is NO_PATH, whatever people do
        if len(self._path) == 0:
            try:
                astar_grid(self.static_blocked, start, goal_cell)
            except NoPathError as exc:
                return self._end(NavResult.NO_PATH, _REASON_CODE[exc.reason], str(exc))
        try:
            grid_path = astar_grid(self.static_blocked | person_mask, start, goal_cell)
        except NoPathError:
            grid_path = self._plan_into_region(start, (pose.x_m, pose.y_m))
        if grid_path is None:
            if self._waiting_since is None:
                self._waiting_since = now_s
            self._state = FollowerState.WAITING
            self._path = np.zeros((0, 2))
            self._path_cells = np.zeros((0, 2), dtype=int)
            return None
        self._waiting_since = None
        self._state = FollowerState.ACTIVE
        self._replans += 1
        cells = grid_path.cells
        pts = self.map.cells_to_world(cells)
        # the path runs through cell centres; begin at the robot and end at the goal itself
        pts[0] = (pose.x_m, pose.y_m)
        pts[-1] = self._goal
        self._path, self._path_cells, self._index = pts, cells, 0
        return None

    def _plan_into_region(self, start: tuple[int, int], pos_xy: tuple[float, float]):
        """A path to the free point of the target region nearest the robot that it can
        reach (round the person), or None: a point ``trip_inset_m`` inside the region's
        borders when one is free, else ``region_margin_m`` inside (well inside the cell
        when there is room, at its edge only when there is not).

        Beside a person the robot keeps contact clearance (person + robot radius, no
        inflation margin): close, as a robot asking someone to leave would stand. A
        robot already closer than that to someone (they stepped up to it) keeps its
        distance instead of freezing: it may move round them, its centre never nearer
        than ``robot_radius_m`` + ``CLOSEST_EXTRA_M`` to theirs (nor much nearer than it
        was: the path keeps the distance, the carrot cuts its corners by a few cm)."""
        if self._region is None:
            return None
        x0, y0, x1, y1 = self._region
        cfg = self.config
        contact = cfg.person_radius_m + cfg.robot_radius_m
        closest = cfg.robot_radius_m + CLOSEST_EXTRA_M  # however close they came
        near = np.zeros(self.map.shape, dtype=bool)
        for person in self._people:
            gap = float(np.hypot(person[0] - pos_xy[0], person[1] - pos_xy[1]))
            keep = max(closest, min(contact, gap - 0.5 * self.map.resolution_m))
            near |= disc_mask(self.map, [person], keep)
        blocked = self.static_blocked | near
        # a robot nearer than ``closest`` to someone (they stepped up to it) starts by
        # stepping back to that distance: it never closes in, and is not frozen there;
        # unless that takes it out of the cell it is in (it would leave what it guards):
        # then, far enough inside, the trip is done, and at the very edge it waits
        if blocked[start]:
            back = self._nearest_free(blocked, start)
            bx, by = self.map.cells_to_world(np.array([back]))[0]
            if self._in_region(*pos_xy) and not self._in_region(bx, by):
                if not self._in_region(*pos_xy, cfg.region_margin_m):
                    return None
                self._goal = (float(pos_xy[0]), float(pos_xy[1]))
                self._beside = True
                return GridPath(np.array([start], dtype=int), 0.0)
            start = back
        # the free points of the region the robot can reach (round the person, to the
        # far side of the cell when the near side is theirs)
        reach = reachable(blocked, start)
        h, w = self.map.shape
        margins = (cfg.trip_inset_m, cfg.region_margin_m)
        for m in margins if cfg.trip_inset_m > cfg.region_margin_m else margins[1:]:
            r_a, c_a = self.map.world_to_cell(x0 + m, y0 + m)
            r_b, c_b = self.map.world_to_cell(x1 - m, y1 - m)
            r0, r1 = sorted((r_a, r_b))
            c0, c1 = sorted((c_a, c_b))
            r0, c0, r1, c1 = max(r0, 0), max(c0, 0), min(r1, h - 1), min(c1, w - 1)
            if r1 < r0 or c1 < c0:
                continue
            free = np.argwhere(reach[r0 : r1 + 1, c0 : c1 + 1]) + (r0, c0)
            if len(free) == 0:
                continue
            # the point chosen before while it stays free and reachable (no swinging
            # from one side of the person to the other as their track jitters), else
            # the one nearest the robot (nearest the last goal, it drifted with them)
            held = None
            if self._beside and self._goal is not None:
                held = self.map.world_to_cell(self._goal[0], self._goal[1])
            if held is not None and r0 <= held[0] <= r1 and c0 <= held[1] <= c1 and reach[held]:
                cell = (int(held[0]), int(held[1]))
            else:
                k = int(np.argmin(((free - np.array(start)) ** 2).sum(axis=1)))
                cell = (int(free[k, 0]), int(free[k, 1]))
            path = astar_grid(blocked, start, cell)
            x, y = self.map.cells_to_world(np.array([cell]))[0]
            self._goal = (float(x), float(y))
            self._beside = True
            return path
        return None

    def _start_cell(self, pose: Pose2D) -> tuple[int, int]:
        """The robot's cell, or the nearest statically free cell when it stands in the
        inflated zone (it drifted close to a wall): planning from there lets it get out."""
        r, c = self.map.world_to_cell(pose.x_m, pose.y_m)
        if not self.map.contains(r, c):
            return (r, c)
        return self._nearest_free(self.static_blocked, (r, c))

    def _nearest_free(self, blocked: np.ndarray, cell: tuple[int, int]) -> tuple[int, int]:
        """``cell``, or when ``blocked`` there the nearest free cell within
        ``max_start_escape_m`` (``cell`` itself when there is none)."""
        r, c = cell
        if not blocked[r, c]:
            return (r, c)
        n = int(math.ceil(self.config.max_start_escape_m / self.map.resolution_m))
        h, w = self.map.shape
        r0, r1, c0, c1 = max(r - n, 0), min(r + n + 1, h), max(c - n, 0), min(c + n + 1, w)
        free = np.argwhere(~blocked[r0:r1, c0:c1])
        if len(free) == 0:
            return (r, c)
        free += (r0, c0)
        k = int(np.argmin(((free - (r, c)) ** 2).sum(axis=1)))
        return (int(free[k, 0]), int(free[k, 1]))

    def _track(
        self, pos: np.ndarray, goal: np.ndarray, pose: Pose2D, d_goal: float
    ) -> tuple[Twist2D, float]:
        cfg = self.config
        path = self._path
        # progress: the nearest path point from the current index on (never goes back)
        window = path[self._index : self._index + 40]
        self._index += int(np.argmin(((window - pos) ** 2).sum(axis=1)))
        rest = path[self._index :]
        seg = np.hypot(*np.diff(rest, axis=0).T).sum() if len(rest) > 1 else 0.0
        dist = float(np.hypot(*(rest[0] - pos)) + seg)
        # carrot: first path point at least lookahead_m away, else the goal
        far = np.flatnonzero(np.hypot(*(rest - pos).T) >= cfg.lookahead_m)
        target = rest[far[0]] if len(far) else goal
        d = target - pos
        norm = float(np.hypot(*d))
        if norm < 1e-9:
            return ZERO_TWIST, dist
        # brake so that the goal is reached at zero speed: v = min(v_max, sqrt(2 a d), k d)
        speed = min(
            cfg.max_speed_mps,
            math.sqrt(2.0 * cfg.decel_mps2 * max(dist, 0.0)),
            cfg.approach_gain_per_s * dist,
        )
        if cfg.drive == "diff":
            # turn towards the carrot, on the spot when it lies far off the heading;
            # forward speed falls with the heading error (cos), never backwards
            err = _wrap(math.atan2(d[1], d[0]) - pose.yaw_rad)
            wz = cfg.turn_gain_per_s * err
            vx = speed * math.cos(err) if abs(err) < cfg.turn_in_place_rad else 0.0
            return Twist2D(float(vx), 0.0, float(wz)), dist
        vw = d / norm * speed
        c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
        vx, vy = c * vw[0] + s * vw[1], -s * vw[0] + c * vw[1]
        assert self._hold_yaw is not None
        wz = cfg.heading_gain_per_s * _wrap(self._hold_yaw - pose.yaw_rad)
        return Twist2D(float(vx), float(vy), float(wz)), dist
