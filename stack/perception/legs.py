"""Leg detection in laser scans (thesis 4.5: the laser gives the person's speed).

A scan is split into segments where consecutive ranges jump by more than an
adaptive breakpoint distance (Borges and Aldon 2004: the jump a surface at
incidence ``lambda`` would make, plus three range sigmas), so that far segments
need larger jumps. A segment is a leg when its width, point count and shape fit a
leg: a leg is a small convex arc bulging towards the sensor; a wall piece is flat
or long. Segments on the static map's obstacles (chair and table legs, the
robot's map) are dropped. Legs within ``max_pair_distance_m`` of each other are
paired into a person at their midpoint; a lone leg may stand for a person whose
other leg it hides.

Everything after segmentation works in the map frame: the robot moves while it
scans, so leg positions are transformed with the robot's pose before tracking.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from stack.config import Config, require
from stack.geometry import Pose2D
from stack.memo import Memo
from stack.perception.errors import BadScanError


@dataclass(frozen=True, eq=False)
class Scan:
    """A laser scan in the shape of ``sensor_msgs/LaserScan``.

    Attributes:
        ranges_m: (N,) ranges [m]; NaN, inf and values outside [range_min, range_max]
            are "no return".
        angle_min_rad: angle of the first beam in the laser frame [rad].
        angle_increment_rad: angle between beams [rad], non-zero.
        range_min_m, range_max_m: the sensor's valid range [m].
        stamp_s: acquisition time [s].
    """

    ranges_m: np.ndarray
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float = 0.05
    range_max_m: float = 10.0
    stamp_s: float = 0.0

    def __post_init__(self) -> None:
        r = np.asarray(self.ranges_m, dtype=float)
        if r.ndim != 1 or r.size == 0:
            raise BadScanError(f"ranges must be a non-empty 1-D array, got shape {r.shape}")
        if not (math.isfinite(self.angle_min_rad) and math.isfinite(self.angle_increment_rad)):
            raise BadScanError("scan angles must be finite")
        if self.angle_increment_rad == 0.0:
            raise BadScanError("angle_increment must be non-zero")
        if not (0.0 <= self.range_min_m < self.range_max_m):
            raise BadScanError(
                f"need 0 <= range_min < range_max, got {self.range_min_m}, {self.range_max_m}"
            )
        r = r.copy()
        r.setflags(write=False)
        object.__setattr__(self, "ranges_m", r)

    @cached_property
    def valid(self) -> np.ndarray:
        """(N,) True where the beam returned a usable range (read-only)."""
        r = self.ranges_m
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(r) & (r >= self.range_min_m) & (r <= self.range_max_m)
        ok.setflags(write=False)
        return ok

    @property
    def angles_rad(self) -> np.ndarray:
        """(N,) the beams' angles (read-only)."""
        return _beams(self.angle_min_rad, self.angle_increment_rad, self.ranges_m.size)[0]

    def points(self) -> np.ndarray:
        """(N, 2) beam end points in the laser frame; NaN where invalid."""
        r = np.where(self.valid, self.ranges_m, np.nan)
        _, cos, sin = _beams(self.angle_min_rad, self.angle_increment_rad, r.size)
        out = np.empty((r.size, 2))
        np.multiply(r, cos, out=out[:, 0])
        np.multiply(r, sin, out=out[:, 1])
        return out


_BEAMS = Memo(8)  # a scanner's beam angles, their cosines and sines (the same every scan)


def _beams(angle_min_rad: float, increment_rad: float, n: int) -> tuple[np.ndarray, ...]:
    """(angles, cos, sin) of ``n`` beams, read-only, made once a process."""

    def make() -> tuple[np.ndarray, ...]:
        a = angle_min_rad + increment_rad * np.arange(n)
        out = (a, np.cos(a), np.sin(a))
        for v in out:
            v.setflags(write=False)
        return out

    return _BEAMS.get((angle_min_rad, increment_rad, n), make)


@dataclass(frozen=True)
class LegConfig(Config):
    """Attributes:
    expected_beams: beams every scan must have (None: any); a scan of another
        length raises BadScanError.
    max_range_m: ranges beyond this are ignored (legs too sparse to see) [m].
    breakpoint_lambda_deg: the adaptive breakpoint's worst incidence angle [deg].
    range_sigma_m: the sensor's range noise [m].
    min_points, max_points: point count of a leg segment.
    min_width_m, max_width_m: end-to-end width of a leg segment [m].
    min_bulge_m, max_bulge_m: mean distance of the segment's points from its
        chord, positive towards the sensor [m]; legs are convex (> 0).
    max_pair_distance_m: legs closer than this pair into one person [m].
    allow_single_leg: an unpaired leg stands for a person (one leg hidden).
    obstacle_clearance_m: a segment point this close to an occupied map cell
        lies on a static obstacle [m].
    obstacle_fraction: segments with at least this fraction of their points on
        static obstacles are dropped.
    """

    section = "legs"  # errors name keys "legs.<field>"

    expected_beams: int | None = None
    max_range_m: float = 6.0
    breakpoint_lambda_deg: float = 10.0
    range_sigma_m: float = 0.01
    min_points: int = 3
    max_points: int = 40
    min_width_m: float = 0.03
    max_width_m: float = 0.25
    min_bulge_m: float = -0.005
    max_bulge_m: float = 0.08
    max_pair_distance_m: float = 0.8
    allow_single_leg: bool = True
    obstacle_clearance_m: float = 0.1
    obstacle_fraction: float = 0.5

    def __post_init__(self) -> None:
        if self.expected_beams is not None:
            require(self.expected_beams > 0, "expected_beams", self.expected_beams, "must be > 0")
        require(self.max_range_m > 0, "max_range_m", self.max_range_m, "must be > 0")
        require(0.0 < self.breakpoint_lambda_deg < 90.0, "breakpoint_lambda_deg",
                self.breakpoint_lambda_deg, "must be in (0, 90)")  # fmt: skip
        require(self.range_sigma_m >= 0, "range_sigma_m", self.range_sigma_m, "must be >= 0")
        require(1 <= self.min_points <= self.max_points, "min_points", self.min_points,
                "needs 1 <= min_points <= max_points")  # fmt: skip
        require(0 <= self.min_width_m < self.max_width_m, "min_width_m", self.min_width_m,
                "needs 0 <= min_width_m < max_width_m")  # fmt: skip
        require(self.min_bulge_m < self.max_bulge_m, "min_bulge_m", self.min_bulge_m,
                "must be < max_bulge_m")  # fmt: skip
        require(self.max_pair_distance_m > 0, "max_pair_distance_m", self.max_pair_distance_m,
                "must be > 0")  # fmt: skip
        require(self.obstacle_clearance_m >= 0, "obstacle_clearance_m",
                self.obstacle_clearance_m, "must be >= 0")  # fmt: skip
        require(0 < self.obstacle_fraction <= 1, "obstacle_fraction", self.obstacle_fraction,
                "must be in (0, 1]")  # fmt: skip


class StaticMap:
    """Occupied cells of the robot's map, for dropping segments on static obstacles.

    Args:
        occupied: (rows, cols) boolean grid, row 0 at ``origin_m``'s y, rows growing
            along +y (the layout of ``nav_msgs/OccupancyGrid``).
        resolution_m: cell side [m].
        origin_m: map position of cell (0, 0)'s corner [m].
    """

    def __init__(self, occupied: np.ndarray, resolution_m: float, origin_m: tuple[float, float]):
        occ = np.asarray(occupied, dtype=bool)
        if occ.ndim != 2 or occ.size == 0:
            raise ValueError(f"occupied must be a non-empty 2-D grid, got shape {occ.shape}")
        if not resolution_m > 0:
            raise ValueError(f"resolution_m {resolution_m!r} must be > 0")
        self.resolution_m = float(resolution_m)
        self.origin_m = (float(origin_m[0]), float(origin_m[1]))
        free = (~occ).astype(np.uint8)
        if occ.any():
            # Distance from each cell to the nearest occupied cell, in metres.
            self._dist = cv2.distanceTransform(free, cv2.DIST_L2, 5) * self.resolution_m
        else:
            self._dist = np.full(occ.shape, np.inf, dtype=np.float32)

    @classmethod
    def from_occupancy(
        cls,
        data: np.ndarray | list[int],
        width: int,
        height: int,
        resolution_m: float,
        origin_m: tuple[float, float],
        occupied_min: int = 65,
    ) -> StaticMap:
        """Build from ``nav_msgs/OccupancyGrid`` fields (values 0-100, -1 unknown)."""
        grid = np.asarray(data, dtype=np.int16).reshape(height, width)
        return cls(grid >= occupied_min, resolution_m, origin_m)

    def distance_m(self, points_m: np.ndarray) -> np.ndarray:
        """(N,) distance from map points to the nearest occupied cell [m]; inf off the map."""
        p = np.asarray(points_m, dtype=float).reshape(-1, 2)
        col = np.floor((p[:, 0] - self.origin_m[0]) / self.resolution_m)
        row = np.floor((p[:, 1] - self.origin_m[1]) / self.resolution_m)
        rows, cols = self._dist.shape
        inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
        out = np.full(len(p), np.inf)
        out[inside] = self._dist[row[inside].astype(int), col[inside].astype(int)]
        return out


@dataclass(frozen=True, eq=False)
class Leg:
    """A leg-like segment.

    Attributes:
        center_m: mean of its points in the map frame [m].
        width_m: distance between its end points [m].
        n_points: beams on it.
        bulge_m: mean distance of its points from the chord, towards the sensor [m].
    """

    center_m: tuple[float, float]
    width_m: float
    n_points: int
    bulge_m: float


@dataclass(frozen=True, eq=False)
class PersonCandidate:
    """A person seen by the laser: two paired legs, or one lone leg.

    Attributes:
        position_m: the midpoint of the legs in the map frame [m].
        legs: the one or two legs.
    """

    position_m: tuple[float, float]
    legs: tuple[Leg, ...]


@dataclass(frozen=True, eq=False)
class LegDetections:
    """All that one scan gave.

    Attributes:
        stamp_s: the scan's time [s].
        segments: number of segments the scan split into.
        legs: leg-like segments not on static obstacles.
        people: paired (and, if allowed, lone) legs.
        on_obstacles: leg-like segments dropped because they lie on the static map.
        valid_beams: beams with a usable range.
    """

    stamp_s: float
    segments: int
    legs: tuple[Leg, ...]
    people: tuple[PersonCandidate, ...]
    on_obstacles: int
    valid_beams: int


def segment_scan(scan: Scan, config: LegConfig) -> list[np.ndarray]:
    """Split a scan into segments at adaptive breakpoints and missing returns.

    Args:
        scan: the scan.
        config: breakpoint parameters and the maximum range.

    Returns:
        Arrays of beam indices, one per segment, in beam order.
    """
    idx, starts, ends = _segment_bounds(scan, config)
    return [idx[a:b] for a, b in zip(starts.tolist(), ends.tolist(), strict=True)]


def _segment_bounds(scan: Scan, config: LegConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The valid beams' indices and each segment's [start, end) positions among them."""
    r = scan.ranges_m
    with np.errstate(invalid="ignore"):
        valid = scan.valid & (r <= config.max_range_m)
    dphi = abs(scan.angle_increment_rad)
    lam = math.radians(config.breakpoint_lambda_deg)
    ratio = math.sin(dphi) / math.sin(lam - dphi) if lam > dphi else math.inf
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return idx, idx, idx
    a, b = r[idx[:-1]], r[idx[1:]]
    # Distance between consecutive end points (law of cosines) against the breakpoint.
    jump = np.sqrt(np.maximum(0.0, a**2 + b**2 - 2.0 * a * b * math.cos(dphi)))
    d_max = a * ratio + 3.0 * config.range_sigma_m
    breaks = np.flatnonzero((np.diff(idx) != 1) | (jump > d_max)) + 1
    starts = np.concatenate(([0], breaks))
    ends = np.concatenate((breaks, [idx.size]))
    return idx, starts, ends


def segment_features(points: np.ndarray) -> tuple[float, float]:
    """(width, bulge) of a segment given in the sensor frame.

    Args:
        points: (N, 2) points in the laser frame (sensor at the origin).

    Returns:
        width_m: distance between the end points; bulge_m: mean distance of the
        points from the chord, positive towards the sensor (0 for N < 3).
    """
    chord = points[-1] - points[0]
    width = float(np.hypot(*chord))
    return width, _bulge(points, chord, width)


def _bulge(points: np.ndarray, chord: np.ndarray, width: float) -> float:
    """:func:`segment_features`'s bulge, the chord and its length given."""
    n = len(points)
    if n < 3 or width == 0.0:
        return 0.0
    p0 = points[0]
    normal = np.array([-chord[1] / width, chord[0] / width])
    if np.dot(normal, -p0) < 0:  # point the normal towards the sensor
        normal = -normal
    # the mean as np.mean makes it (one sum, then the division), without its checks
    return float(((points[1:-1] - p0) @ normal).sum() / (n - 2))


def detect_legs(
    scan: Scan,
    config: LegConfig,
    laser_pose: Pose2D = Pose2D(),
    static_map: StaticMap | None = None,
) -> LegDetections:
    """Find legs and people in one scan.

    Args:
        scan: the scan (laser frame).
        config: segmentation, leg and pairing parameters.
        laser_pose: the laser's pose in the map frame at the scan's time (robot pose
            composed with the laser's mounting).
        static_map: the robot's map; segments on its obstacles are dropped.

    Returns:
        Legs and people in the map frame.

    Raises:
        BadScanError: the scan's length differs from ``config.expected_beams``.
    """
    n = scan.ranges_m.size
    if config.expected_beams is not None and n != config.expected_beams:
        raise BadScanError(f"scan has {n} beams, expected {config.expected_beams}")
    pts_laser = scan.points()
    idx, starts, ends = _segment_bounds(scan, config)
    # the cheap tests on every segment at once (beam count, end-to-end width), then the
    # few that pass one by one (a scan has tens of segments, a handful leg-sized)
    count = ends - starts
    if idx.size:
        chord = pts_laser[idx[ends - 1]] - pts_laser[idx[starts]]
        widths = np.hypot(chord[:, 0], chord[:, 1])
    else:
        widths = np.zeros(0)
    keep = (count >= config.min_points) & (count <= config.max_points)
    keep &= (widths >= config.min_width_m) & (widths <= config.max_width_m)
    legs: list[Leg] = []
    on_obstacles = 0
    kept = np.flatnonzero(keep)
    if kept.size:
        # the survivors' points in one array: bulge, map frame and static map at once
        seg = np.concatenate([idx[starts[k] : ends[k]] for k in kept.tolist()])
        size = count[kept]
        first = np.concatenate(([0], np.cumsum(size)[:-1]))
        p = pts_laser[seg]
        bulges = [
            _bulge(p[a : a + m], chord[k], float(widths[k]))
            for a, m, k in zip(first.tolist(), size.tolist(), kept.tolist(), strict=True)
        ]
        p_map = laser_pose.transform(p)
        if static_map is not None:
            near = static_map.distance_m(p_map) <= config.obstacle_clearance_m
            near_frac = np.add.reduceat(near.astype(float), first) / size
        for j, k in enumerate(kept.tolist()):
            if not (config.min_bulge_m <= bulges[j] <= config.max_bulge_m):
                continue
            if static_map is not None and near_frac[j] >= config.obstacle_fraction:
                on_obstacles += 1
                continue
            c = p_map[first[j] : first[j] + size[j]].mean(axis=0)
            legs.append(Leg((float(c[0]), float(c[1])), float(widths[k]), int(size[j]), bulges[j]))
    people = pair_legs(legs, config.max_pair_distance_m, config.allow_single_leg)
    return LegDetections(
        stamp_s=scan.stamp_s,
        segments=int(starts.size),
        legs=tuple(legs),
        people=people,
        on_obstacles=on_obstacles,
        valid_beams=int(scan.valid.sum()),
    )


def pair_legs(
    legs: list[Leg] | tuple[Leg, ...], max_distance_m: float, allow_single: bool
) -> tuple[PersonCandidate, ...]:
    """Pair legs greedily, closest pairs first.

    Args:
        legs: the scan's legs.
        max_distance_m: legs farther apart than this are not one person's [m].
        allow_single: unpaired legs become one-leg people.

    Returns:
        People, paired ones first.
    """
    centers = np.array([leg.center_m for leg in legs]).reshape(-1, 2)
    pairs: list[tuple[float, int, int]] = []
    if len(legs) > 1:  # every pair i < j at once (the same np.hypot of the same differences)
        a, b = np.triu_indices(len(legs), 1)
        d = np.hypot(centers[a, 0] - centers[b, 0], centers[a, 1] - centers[b, 1])
        close = d <= max_distance_m
        pairs = sorted(zip(d[close].tolist(), a[close].tolist(), b[close].tolist(), strict=True))
    used: set[int] = set()
    people = []
    for _, i, j in pairs:
        if i in used or j in used:
            continue
        used.update((i, j))
        mid = (centers[i] + centers[j]) / 2.0
        people.append(PersonCandidate((float(mid[0]), float(mid[1])), (legs[i], legs[j])))
    if allow_single:
        for i, leg in enumerate(legs):
            if i not in used:
                people.append(PersonCandidate(leg.center_m, (leg,)))
    return tuple(people)
