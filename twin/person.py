"""The scripted person: a waypoint timeline and a gait whose feet do not slide.

Pure numpy, no MuJoCo: ``PersonScript.pose(t)`` returns where every body segment is at
time ``t`` and the twin copies that into mocap bodies. Being a pure function of time,
the same script always gives the same motion.

The gait (why it looks the way it does): each straight walk between two waypoints
starts and ends with the feet side by side. Its length D is split into n equal steps of
length l = D / n (n as small as the speed's maximum step length allows); the feet land
at l, 2l, ..., nl along the segment, alternating, and a last half-step brings the
trailing foot alongside. The pelvis moves at the commanded speed and is half a step
behind the leading foot at every landing, so a swing lasts l / v (the first and last
half that). A foot on the ground never moves, which is what a lidar leg tracker needs
(FEASIBILITY: an inverse-kinematics gait slid 6 cm, a plain leg swing 1.5 m). Knees are
placed by two-link inverse kinematics and the pelvis drops when a stride would
otherwise over-stretch a leg.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from stack.cells import CellGrid
from twin.config import PersonConfig, Waypoint

# Maximum step length as a function of speed: 0.33 m at 0.1 m/s, 0.72 m at 1.4 m/s,
# i.e. about 0.3 steps/s when strolling and 1.9 steps/s at a brisk walk; then on up to
# 0.90 m at 2.0 m/s (2.2 steps/s: a fast walk or a jog, issue 26; ISO 13855's walking
# speed 1.6 m/s takes 0.78 m steps). Measured gaits lengthen the step and quicken the
# cadence together; without a flight phase the pelvis dips lower on the longest steps.
_STEP_BASE_M = 0.30
_STEP_PER_SPEED_S = 0.30
_STEP_MAX_M = 0.90
_ARM_STRIDE_M = 0.72  # the step at which the arms swing fully (the brisk walk's)
_LIFT_M = 0.07  # swing-foot clearance


def max_step_length_m(speed_mps: float) -> float:
    """Longest step the gait takes at ``speed_mps`` [m]."""
    return min(_STEP_MAX_M, _STEP_BASE_M + _STEP_PER_SPEED_S * speed_mps)


@dataclass(frozen=True)
class BodyDims:
    """Segment sizes scaled from the person's height [m]."""

    height_m: float

    @property
    def hip_height_m(self) -> float:
        # standing: the legs almost straight (a fully straight leg has no knee direction)
        return self.ankle_height_m + 0.985 * (self.thigh_m + self.shin_m)

    @property
    def thigh_m(self) -> float:
        return 0.26 * self.height_m

    @property
    def shin_m(self) -> float:
        return 0.255 * self.height_m

    @property
    def ankle_height_m(self) -> float:
        return 0.04 * self.height_m

    @property
    def hip_half_width_m(self) -> float:
        return 0.055 * self.height_m

    @property
    def shoulder_height_m(self) -> float:
        return 0.81 * self.height_m

    @property
    def shoulder_half_width_m(self) -> float:
        return 0.11 * self.height_m

    @property
    def arm_m(self) -> float:
        return 0.33 * self.height_m


@dataclass(frozen=True)
class PersonPose:
    """Where the person is at one instant (world frame, metres, radians).

    Attributes:
        time_s: the instant.
        position_m: (x, y) of the pelvis projected on the floor.
        heading_rad: walking direction (0 = east, counter-clockwise).
        velocity_mps: (vx, vy) of the pelvis.
        pelvis_drop_m: how far the pelvis sits below its standing height.
        hips_m, knees_m, ankles_m, shoulders_m, hands_m: (2, 3) arrays, rows = (left, right).
    """

    time_s: float
    position_m: tuple[float, float]
    heading_rad: float
    velocity_mps: tuple[float, float]
    pelvis_drop_m: float
    hips_m: np.ndarray
    knees_m: np.ndarray
    ankles_m: np.ndarray
    shoulders_m: np.ndarray
    hands_m: np.ndarray

    @property
    def walking(self) -> bool:
        return math.hypot(*self.velocity_mps) > 0.0


@dataclass(frozen=True)
class _Phase:
    t0: float
    t1: float
    start: np.ndarray  # (2,)
    end: np.ndarray  # (2,)
    heading: float
    speed: float  # 0 for a pause
    n_steps: int  # number of full steps (the walk has n_steps + 1 swings)
    first_foot: int  # 0 = left, 1 = right: which foot swings first


class PersonScript:
    """A person following waypoints with speeds and pauses, with a foot-planting gait.

    Args:
        config: the person's configuration; ``config.waypoints`` must hold at least one.
        start_time_s: time at which the first walk (after the first pause) begins.

    Raises:
        ValueError: no waypoints.
    """

    def __init__(self, config: PersonConfig, start_time_s: float = 0.0):
        if not config.waypoints:
            raise ValueError("a PersonScript needs at least one waypoint")
        self.config = config
        self.dims = BodyDims(config.height_m)
        self._phases: list[_Phase] = []
        wps = config.waypoints
        t = start_time_s + wps[0].pause_s
        p0 = np.array([wps[0].x_m, wps[0].y_m])
        heading = 0.0
        if len(wps) > 1:
            d = np.array([wps[1].x_m, wps[1].y_m]) - p0
            heading = math.atan2(d[1], d[0]) if np.linalg.norm(d) > 0 else 0.0
        # a leading pause phase from -inf so that pose(t) is defined for all t
        self._phases.append(_Phase(-math.inf, t, p0, p0, heading, 0.0, 0, 0))
        foot = 0
        for wp in wps[1:]:
            p1 = np.array([wp.x_m, wp.y_m])
            d = p1 - p0
            dist = float(np.linalg.norm(d))
            if dist > 1e-6:
                heading = math.atan2(d[1], d[0])
                n = max(1, math.ceil(dist / max_step_length_m(wp.speed_mps) - 1e-9))
                dt = dist / wp.speed_mps
                self._phases.append(_Phase(t, t + dt, p0, p1, heading, wp.speed_mps, n, foot))
                # the foot that swung last (the closing half-step) leads next time
                foot = (foot + n) % 2
                t += dt
            if wp.pause_s > 0 or wp is wps[-1]:
                end = math.inf if wp is wps[-1] else t + wp.pause_s
                self._phases.append(_Phase(t, end, p1, p1, heading, 0.0, 0, 0))
                t = end
            p0 = p1
        self._starts = [ph.t0 for ph in self._phases]
        self._last: tuple[float, PersonPose] | None = None
        self.end_time_s = self._phases[-1].t0  # when the person stops for good

    def pose(self, t: float) -> PersonPose:
        """The person's pose at time ``t`` [s].

        Args:
            t: simulation time [s].

        Returns:
            The pose of every segment at ``t``.
        """
        if self._last is not None and self._last[0] == t:
            return self._last[1]  # the physics step, its sensors and its truth ask alike
        pose = self._pose(t)
        self._last = (t, pose)
        return pose

    def still_phase(self, t: float) -> int | None:
        """The index of the pause the person is in at ``t`` (their pose does not change
        during it, whatever ``t``), or None while walking."""
        i = max(0, bisect.bisect_right(self._starts, t) - 1)
        return i if self._phases[i].speed == 0.0 else None

    def motion(self, t: float) -> tuple[tuple[float, float], float, tuple[float, float]]:
        """Where the pelvis is at ``t``, the heading and the velocity: ``pose(t)``'s
        ``position_m``, ``heading_rad`` and ``velocity_mps`` (the same numbers) without
        the body's segments (the ground truth needs only these, at 25 Hz)."""
        # :meth:`_along` and ``start + u * f`` on floats (the same operations, no arrays)
        ph = self._phases[max(0, bisect.bisect_right(self._starts, t) - 1)]
        f0, f1 = math.cos(ph.heading), math.sin(ph.heading)
        u = 0.0 if ph.speed == 0.0 else (t - ph.t0) * ph.speed
        vel = (0.0, 0.0) if ph.speed == 0.0 else (f0 * ph.speed, f1 * ph.speed)
        x0, y0 = ph.start.tolist()
        return (x0 + u * f0, y0 + u * f1), ph.heading, vel

    def _along(self, t: float) -> tuple[_Phase, np.ndarray, float, tuple[float, float]]:
        """The phase at ``t``, its unit direction, the distance walked along it and the
        velocity."""
        i = max(0, bisect.bisect_right(self._starts, t) - 1)
        ph = self._phases[i]
        f = np.array([math.cos(ph.heading), math.sin(ph.heading)])
        if ph.speed == 0.0:
            return ph, f, 0.0, (0.0, 0.0)
        s = (t - ph.t0) * ph.speed  # distance walked along the segment
        return ph, f, s, (float(f[0] * ph.speed), float(f[1] * ph.speed))

    def _pose(self, t: float) -> PersonPose:
        ph, f, u, vel = self._along(t)
        left = np.array([-f[1], f[0]])  # unit vector to the person's left
        if ph.speed == 0.0:
            feet_u = np.array([0.0, 0.0])
            lift = np.array([0.0, 0.0])
        else:
            feet_u, lift = _feet_along(u, ph.speed, ph.n_steps, ph.end - ph.start, ph.first_foot)
        return self._assemble(t, ph.start, f, left, u, feet_u, lift, ph.heading, vel)

    def _assemble(
        self,
        t: float,
        origin: np.ndarray,
        f: np.ndarray,
        left: np.ndarray,
        u: float,
        feet_u: np.ndarray,
        lift: np.ndarray,
        heading: float,
        vel: tuple[float, float],
    ) -> PersonPose:
        d = self.dims
        pelvis_xy = origin + u * f
        side = np.array([1.0, -1.0])  # left, right
        ankles = np.zeros((2, 3))
        for k in range(2):
            xy = origin + feet_u[k] * f + side[k] * d.hip_half_width_m * left
            ankles[k] = (xy[0], xy[1], d.ankle_height_m + lift[k])
        # drop the pelvis if a leg cannot reach its foot (long strides)
        reach = 0.995 * (d.thigh_m + d.shin_m)
        drop = 0.0
        for k in range(2):
            horiz = abs(feet_u[k] - u)
            need = math.sqrt(max(reach**2 - horiz**2, 0.0)) + ankles[k, 2]
            drop = max(drop, d.hip_height_m - need)
        hip_z = d.hip_height_m - drop
        hips = np.zeros((2, 3))
        knees = np.zeros((2, 3))
        for k in range(2):
            xy = pelvis_xy + side[k] * d.hip_half_width_m * left
            hips[k] = (xy[0], xy[1], hip_z)
            knees[k] = _knee(hips[k], ankles[k], d.thigh_m, d.shin_m, np.array([f[0], f[1], 0.0]))
        shoulders = np.zeros((2, 3))
        hands = np.zeros((2, 3))
        for k in range(2):
            xy = pelvis_xy + side[k] * d.shoulder_half_width_m * left
            shoulders[k] = (xy[0], xy[1], d.shoulder_height_m - drop)
            # arms swing against the same-side leg, about 25 deg at a full stride
            swing = -0.45 * (feet_u[k] - u) / (0.5 * _ARM_STRIDE_M)
            swing = max(-0.45, min(0.45, swing))
            direction = np.array([math.sin(swing) * f[0], math.sin(swing) * f[1], -math.cos(swing)])
            # hands a little away from the hips, as a relaxed arm hangs
            direction[:2] += side[k] * 0.12 * left
            hands[k] = shoulders[k] + d.arm_m * direction / vector_norm(direction)
        return PersonPose(
            time_s=t,
            position_m=(float(pelvis_xy[0]), float(pelvis_xy[1])),
            heading_rad=heading,
            velocity_mps=vel,
            pelvis_drop_m=drop,
            hips_m=hips,
            knees_m=knees,
            ankles_m=ankles,
            shoulders_m=shoulders,
            hands_m=hands,
        )


def _feet_along(
    s: float, speed: float, n: int, delta: np.ndarray, first_foot: int
) -> tuple[np.ndarray, np.ndarray]:
    """Positions of both feet along a walk segment, and their lift, at distance ``s``.

    Args:
        s: distance the pelvis has covered along the segment [m].
        speed: walking speed [m/s] (unused: the gait is laid out in distance).
        n: number of full steps; the step length is |delta| / n.
        delta: segment vector [m].
        first_foot: index of the foot that swings first (0 left, 1 right).

    Returns:
        (feet_u, lift): distance along the segment of each foot [m] and its height
        above the ground [m], both indexed (left, right).
    """
    del speed
    length = vector_norm(delta)
    step = length / n
    s = min(max(s, 0.0), length)
    # swing k (0-based) moves the pelvis over [a_k, b_k]: half a step first and last
    if s < 0.5 * step:
        k, a, b = 0, 0.0, 0.5 * step
    elif s >= length - 0.5 * step:
        k, a, b = n, length - 0.5 * step, length
    else:
        k = 1 + int((s - 0.5 * step) // step)
        k = min(k, n - 1)
        a = 0.5 * step + (k - 1) * step
        b = a + step
    tau = (s - a) / (b - a) if b > a else 1.0
    ease = tau * tau * (3.0 - 2.0 * tau)
    # foot that swings in swing k, where it comes from and goes to
    swinging = (first_foot + k) % 2
    if k == 0:
        src, dst = 0.0, step
    elif k == n:
        src, dst = (n - 1) * step, n * step
    else:
        src, dst = (k - 1) * step, (k + 1) * step
    stance_u = k * step if k < n else n * step
    if k == 0:
        stance_u = 0.0
    feet = np.zeros(2)
    lift = np.zeros(2)
    feet[swinging] = src + (dst - src) * ease
    lift[swinging] = _LIFT_M * math.sin(math.pi * tau)
    feet[1 - swinging] = stance_u
    return feet, lift


def vector_norm(v: np.ndarray) -> float:
    """``np.linalg.norm`` of a float vector, as it computes it (the square root of
    v . v) without its checks: the walkers' poses ask a dozen times a scan."""
    return math.sqrt(v.dot(v))


def _knee(hip: np.ndarray, ankle: np.ndarray, a: float, b: float, fwd: np.ndarray) -> np.ndarray:
    """Two-link inverse kinematics: the knee, bending forward, for thigh a and shin b."""
    d_vec = ankle - hip
    d = vector_norm(d_vec)
    u = d_vec / d
    if d >= a + b:
        return hip + u * a
    x = (a * a - b * b + d * d) / (2.0 * d)
    h = math.sqrt(max(a * a - x * x, 0.0))
    p = fwd - np.dot(fwd, u) * u
    norm = vector_norm(p)
    p = p / norm if norm > 1e-9 else np.array([0.0, 0.0, 1.0])
    return hip + x * u + h * p


def default_waypoints(
    grid: CellGrid, door_xy_m: tuple[float, float], room_north_y_m: float
) -> tuple[Waypoint, ...]:
    """A script that enters through the door, tours the region and leaves.

    Args:
        grid: the cell grid; the tour visits its north-west, middle and south-east cells
            (12, 7 and 1 of the thesis's grid).
        door_xy_m: centre of the doorway on the north wall [m].
        room_north_y_m: inner face of the north wall [m].

    Returns:
        Waypoints: outside the door, through it, to the three cells' centres, pausing at
        each, and back out.
    """
    numbering = grid.numbering
    north_west = numbering[0][0]
    middle = numbering[grid.rows - 1][(grid.columns - 1) // 2]
    south_east = numbering[-1][-1]
    dx, _ = door_xy_m
    outside = (dx, room_north_y_m + 1.2)
    inside = (dx, room_north_y_m - 0.8)
    return (
        Waypoint(x_m=outside[0], y_m=outside[1], speed_mps=1.0, pause_s=1.0),
        Waypoint(x_m=inside[0], y_m=inside[1], speed_mps=1.0, pause_s=0.0),
        Waypoint(*grid.center(north_west), speed_mps=1.2, pause_s=3.0),
        Waypoint(*grid.center(middle), speed_mps=0.6, pause_s=2.0),
        Waypoint(*grid.center(south_east), speed_mps=1.4, pause_s=2.0),
        Waypoint(x_m=inside[0], y_m=inside[1], speed_mps=0.8, pause_s=0.0),
        Waypoint(x_m=outside[0], y_m=outside[1], speed_mps=1.0, pause_s=0.0),
    )
