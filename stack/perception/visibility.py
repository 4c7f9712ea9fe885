"""Where the ceiling camera can see a person: the robot's shadow and the image edges.

The absence of a detection is evidence of absence only where the camera could have
seen the person. The camera looks at the floor obliquely; the robot standing between
it and a person hides the person's legs or whole body, and floor near the image edges
shows only part of a person. This module computes, for a robot pose, which floor
points and which cells the camera cannot see.

Geometry, all from the calibration (no extra measurement): the floor homography
implies a pinhole camera (:meth:`FloorHomography.camera_matrix`). A person standing
at a floor point is a vertical rectangle ``person_height_m`` tall and
``2 * person_half_width_m`` wide facing the camera; the robot is a few boxes in its
base frame (``robot_boxes``: the MBot's chassis, body and head by default). Both are
projected into the image and rasterised at ``raster_scale``; a point is *hidden* when

- more than ``max_covered_frac`` of the person's silhouette lies behind the robot, or
  more than ``max_legs_covered_frac`` of its lower ``legs_frac`` (HOG needs the legs,
  and the foot point is the bottom of the legs: a partly hidden person is missed or
  put too far away), and the robot is nearer the camera than the person; or
- less than ``min_in_image_frac`` of the silhouette is inside the image.

A cell's *hidden fraction* is the share of ``samples_per_axis``² points spread over
it that are hidden. :func:`stack.planning.agent` uses it as the probability that a
person in that cell could not have been detected.

Pure: numpy and OpenCV only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from stack.cells import CellGrid
from stack.config import Config, require
from stack.memo import Memo
from stack.perception.homography import FloorHomography
from stack.perception.legs import Pose2D

Box = tuple[float, float, float, float, float, float]
# The MBot (twin/assets/mbot.xml): chassis, body, head as (x0, x1, y0, y1, z0, z1) [m]
# in the base frame (x forward, z up).
MBOT_BOXES: tuple[Box, ...] = (
    (-0.30, 0.30, -0.25, 0.25, 0.0, 0.23),
    (-0.21, 0.15, -0.19, 0.19, 0.23, 0.92),
    (-0.18, 0.12, -0.16, 0.16, 0.92, 1.23),
)


@dataclass(frozen=True)
class VisibilityConfig(Config):
    """Attributes:
    person_height_m: the person's silhouette height [m].
    person_half_width_m: half its width [m].
    legs_frac: the lower share of the silhouette that holds the legs.
    max_covered_frac: hidden when more of the whole silhouette is behind the robot.
    max_legs_covered_frac: hidden when more of the legs are behind the robot.
    min_in_image_frac: hidden when less of the silhouette is inside the image.
    samples_per_axis: points per cell side for the cell's hidden fraction.
    cell_inset_m: the sample points keep this far from the cell's edges [m].
    raster_scale: the image is rasterised at this fraction of its size.
    robot_boxes: the robot's body as boxes (x0, x1, y0, y1, z0, z1) in its base frame [m].
    """

    section = "visibility"  # errors name keys "visibility.<field>"

    person_height_m: float = 1.7
    person_half_width_m: float = 0.25
    legs_frac: float = 0.45
    max_covered_frac: float = 0.35
    max_legs_covered_frac: float = 0.5
    min_in_image_frac: float = 0.75
    samples_per_axis: int = 3
    cell_inset_m: float = 0.15
    raster_scale: float = 0.25
    robot_boxes: tuple[tuple[float, float, float, float, float, float], ...] = MBOT_BOXES

    def __post_init__(self) -> None:
        require(self.person_height_m > 0, "person_height_m", self.person_height_m, "must be > 0")
        require(self.person_half_width_m > 0, "person_half_width_m", self.person_half_width_m,
                "must be > 0")  # fmt: skip
        for key in ("legs_frac", "max_covered_frac", "max_legs_covered_frac", "min_in_image_frac"):
            v = getattr(self, key)
            require(0.0 < v <= 1.0, key, v, "must be in (0, 1]")
        require(self.samples_per_axis >= 1, "samples_per_axis", self.samples_per_axis,
                "must be >= 1")  # fmt: skip
        require(self.cell_inset_m >= 0, "cell_inset_m", self.cell_inset_m, "must be >= 0")
        require(0.05 <= self.raster_scale <= 1.0, "raster_scale", self.raster_scale,
                "must be in [0.05, 1]")  # fmt: skip
        for b in self.robot_boxes:
            require(
                len(b) == 6 and b[0] < b[1] and b[2] < b[3] and b[4] < b[5],
                "robot_boxes", b, "each box is (x0, x1, y0, y1, z0, z1) with x0 < x1 etc.",
            )  # fmt: skip


@dataclass(frozen=True)
class PointVisibility:
    """How the camera sees a person standing at one floor point."""

    covered_frac: float  # of the silhouette behind the robot
    legs_covered_frac: float  # of the legs behind the robot
    in_image_frac: float  # of the silhouette inside the image
    hidden: bool


@dataclass(frozen=True)
class _Silhouette:
    """A person's silhouette at one floor point in the raster, robot aside."""

    window: tuple[int, int, int, int]  # raster rows r0:r1, columns c0:c1 holding it
    whole: np.ndarray  # (r1 - r0, c1 - c0) uint8 0/1: the silhouette in the window
    legs: np.ndarray  # its legs (empty when nothing of it is in the image)
    inside: int  # the silhouette's pixels in the image
    n_legs: int  # the legs' pixels
    in_image: float  # the share of the silhouette in the image


@dataclass
class _SampleTable:
    """The sample points' silhouettes, for :meth:`CameraVisibility.hidden_fractions`."""

    spans: dict[int, tuple[int, int]]  # cell -> its rows (consecutive, in order)
    starts: np.ndarray  # (cells,) each span's first row
    whole: np.ndarray  # (P, H*W) float32 0/1 silhouette masks
    legs: np.ndarray  # (P, H*W) their legs
    inside: np.ndarray  # (P,) silhouette pixels in the image
    n_legs: np.ndarray  # (P,) legs pixels in the image
    dist: np.ndarray  # (P,) distance from the camera's foot point [m]
    static_hidden: np.ndarray  # (P,) hidden whatever the robot (image edge)


@dataclass
class _Shared:
    """What every :class:`CameraVisibility` of one camera, cells and settings shares."""

    static: dict[int, float]  # each cell's hidden share without the robot
    table: _SampleTable | None = None  # made on first use


_SHARED = Memo(8)  # cameras remembered by a process
MASKS_KEPT = 4  # robot silhouettes an instance keeps (by pose)
SILHOUETTES_KEPT = 64  # person silhouettes an instance keeps (by floor point)


class CameraVisibility:
    """Which floor the camera sees, given where the robot stands.

    Args:
        homography: the camera's calibration (needs its image size).
        grid: the cells.
        config: shapes and thresholds.

    Raises:
        ValueError: a calibration without an image size, or not a pinhole camera's.
    """

    def __init__(
        self,
        homography: FloorHomography,
        grid: CellGrid,
        config: VisibilityConfig | None = None,
    ):
        self.config = config or VisibilityConfig()
        self.grid = grid
        cam = homography.camera_matrix()
        if cam is None or homography.image_size_px is None:
            raise ValueError(
                "the calibration needs its image size and a pinhole camera to judge visibility"
            )
        self.P = np.asarray(cam, dtype=float)
        _, _, vt = np.linalg.svd(self.P)
        c = vt[-1]
        self.centre_m = c[:3] / c[3]  # the camera's position in the map frame
        s = self.config.raster_scale
        w, h = homography.image_size_px
        self.shape = (max(1, round(h * s)), max(1, round(w * s)))
        self._scale = s
        # the robot's silhouettes of the last few poses: the camera model asks at the
        # true pose, the observations at the odometry's, in turns (one slot thrashed)
        self._masks = Memo(MASKS_KEPT)
        # each robot box's floor corners in the base frame, and its heights
        self._robot_corners = [
            (np.array([[x, y] for x in (x0, x1) for y in (y0, y1)]), z0, z1)
            for x0, x1, y0, y1, z0, z1 in self.config.robot_boxes
        ]
        # a person's silhouette at a floor point, robot aside (people stand still a lot)
        self._silhouettes = Memo(SILHOUETTES_KEPT)
        # what does not depend on the robot is the same for every instance of the same
        # camera, cells and settings (a study makes one an episode): made once a process
        key = (
            self.P.tobytes(),
            self.shape,
            self.config,
            tuple((c, grid.bounds(c)) for c in grid.cells),
        )
        shared = _SHARED.get(key, lambda: _Shared(self._static_fractions()))
        self._shared = shared
        self._static = shared.static

    # -- projection --------------------------------------------------------------
    def _project(self, pts: np.ndarray) -> np.ndarray | None:
        """(N, 3) map points to (N, 2) raster pixels; None if any is behind the camera."""
        h = np.ones((len(pts), 4))  # homogeneous (as np.column_stack makes them)
        h[:, :3] = pts
        q = h @ self.P.T
        if np.any(q[:, 2] <= 1e-6):
            return None
        return q[:, :2] / q[:, 2:3] * self._scale

    def _fill(self, mask: np.ndarray, px: np.ndarray, origin: tuple[int, int] = (0, 0)) -> None:
        """Fill the convex hull of raster points ``px`` into ``mask``, whose pixel (0, 0)
        is the raster's ``origin`` (row, column): a window shows the same pixels as the
        whole raster (whole pixels move the fixed-point polygon exactly)."""
        hull = cv2.convexHull(np.round(px * 16).astype(np.int32))
        if origin != (0, 0):
            hull = hull - np.array([origin[1] * 16, origin[0] * 16], np.int32)
        cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=4)

    def _window(self, *pxs: np.ndarray) -> tuple[int, int, int, int] | None:
        """Rows r0:r1 and columns c0:c1 of the raster that can hold the fill of the
        points ``pxs`` (a pixel of margin), clipped to it; None if it is empty."""
        lo = np.floor(np.min([p.min(axis=0) for p in pxs], axis=0)) - 1
        hi = np.ceil(np.max([p.max(axis=0) for p in pxs], axis=0)) + 2
        h, w = self.shape
        c0, r0 = max(0, int(lo[0])), max(0, int(lo[1]))
        c1, r1 = min(w, int(hi[0])), min(h, int(hi[1]))
        return (r0, r1, c0, c1) if r0 < r1 and c0 < c1 else None

    def robot_mask(self, pose: Pose2D) -> np.ndarray:
        """The robot's silhouette in the raster image (uint8 0/1; read-only: the last
        pose's is kept, for a robot at rest and a step that asks twice)."""
        return self._masks.get(pose, lambda: self._draw_robot(pose))

    def _draw_robot(self, pose: Pose2D) -> np.ndarray:
        mask = np.zeros(self.shape, np.uint8)
        for corners, z0, z1 in self._robot_corners:
            xy = pose.transform(corners)
            pts = np.empty((8, 3))
            pts[:4, :2], pts[4:, :2], pts[:4, 2], pts[4:, 2] = xy, xy, z0, z1
            px = self._project(pts)
            if px is not None:
                self._fill(mask, px)
        mask.setflags(write=False)
        return mask

    def _person_quads(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Raster corners of the whole silhouette and of its legs at floor point (x, y)."""
        cfg = self.config
        dx, dy = x - self.centre_m[0], y - self.centre_m[1]
        norm = math.hypot(dx, dy)
        if norm < 1e-6:
            return None
        px_, py_ = -dy / norm * cfg.person_half_width_m, dx / norm * cfg.person_half_width_m
        legs_z = cfg.person_height_m * cfg.legs_frac

        def quad(z1: float) -> np.ndarray | None:
            pts = np.array(
                [
                    [x - px_, y - py_, 0.0],
                    [x + px_, y + py_, 0.0],
                    [x + px_, y + py_, z1],
                    [x - px_, y - py_, z1],
                ]
            )
            return self._project(pts)

        whole, legs = quad(cfg.person_height_m), quad(legs_z)
        if whole is None or legs is None:
            return None
        return whole, legs

    def behind_robot_possible(self, x: float, y: float, robot_xy: tuple[float, float]) -> bool:
        """Whether :meth:`point` at (x, y) would look at the robot's mask (some of the
        silhouette is in the image and the robot at ``robot_xy`` is nearer the camera);
        if not, its answer is the same without the mask."""
        sil = self._silhouettes.get((x, y), lambda: self._silhouette(x, y))
        return sil is not None and sil.inside > 0 and self._nearer(robot_xy, x, y)

    def _nearer(self, robot_xy: tuple[float, float] | None, x: float, y: float) -> bool:
        return robot_xy is None or (
            math.dist(robot_xy, self.centre_m[:2]) < math.dist((x, y), self.centre_m[:2])
        )

    def point(self, x: float, y: float, robot: np.ndarray | None, robot_xy=None) -> PointVisibility:
        """How a person at floor point (x, y) is seen; ``robot`` from :meth:`robot_mask`."""
        cfg = self.config
        sil = self._silhouettes.get((x, y), lambda: self._silhouette(x, y))
        if sil is None:
            return PointVisibility(1.0, 1.0, 0.0, True)
        covered = legs_covered = 0.0
        if robot is not None and sil.inside > 0 and self._nearer(robot_xy, x, y):
            r0, r1, c0, c1 = sil.window
            under = robot[r0:r1, c0:c1]
            covered = float((sil.whole & under).sum()) / sil.inside
            legs_covered = float((sil.legs & under).sum()) / sil.n_legs if sil.n_legs else 0.0
        in_image = sil.in_image
        hidden = (
            in_image < cfg.min_in_image_frac
            or covered > cfg.max_covered_frac
            or legs_covered > cfg.max_legs_covered_frac
        )
        return PointVisibility(covered, legs_covered, in_image, hidden)

    def _silhouette(self, x: float, y: float) -> _Silhouette | None:
        """:meth:`point`'s raster work that does not depend on the robot; None when
        the point is under the camera or the person is behind it."""
        quads = self._person_quads(x, y)
        if quads is None:
            return None
        whole, legs = quads
        area = abs(cv2.contourArea(whole.astype(np.float32)))
        # the silhouette's window of the raster only: the same pixels, a fraction of the work
        window = self._window(whole, legs)
        inside = n_legs = 0
        mask = lmask = np.zeros((0, 0), np.uint8)
        if window is not None:
            r0, r1, c0, c1 = window
            mask = np.zeros((r1 - r0, c1 - c0), np.uint8)
            self._fill(mask, whole, (r0, c0))
            inside = int(mask.sum())
            if inside > 0:
                lmask = np.zeros(mask.shape, np.uint8)
                self._fill(lmask, legs, (r0, c0))
                n_legs = int(lmask.sum())
        in_image = min(1.0, inside / area) if area > 1e-9 else 0.0
        for m in (mask, lmask):
            m.setflags(write=False)
        return _Silhouette(window or (0, 0, 0, 0), mask, lmask, inside, n_legs, in_image)

    def _samples(self, cell: int) -> list[tuple[float, float]]:
        x0, y0, x1, y1 = self.grid.bounds(cell)
        k, m = self.config.samples_per_axis, self.config.cell_inset_m
        xs = np.linspace(x0 + m, x1 - m, k) if k > 1 else [(x0 + x1) / 2]
        ys = np.linspace(y0 + m, y1 - m, k) if k > 1 else [(y0 + y1) / 2]
        return [(float(x), float(y)) for x in xs for y in ys]

    def _static_fractions(self) -> dict[int, float]:
        out = {}
        for cell in self.grid.cells:
            pts = self._samples(cell)
            out[cell] = sum(self.point(x, y, None).hidden for x, y in pts) / len(pts)
        return out

    def hidden_fractions(self, robot_pose: Pose2D | None) -> dict[int, float]:
        """Each cell's share of floor the camera cannot see (0: all visible, 1: none).

        Args:
            robot_pose: the robot's pose in the map frame; None: only the image edges.
        """
        if robot_pose is None:
            return dict(self._static)
        robot = self.robot_mask(robot_pose)
        if not robot.any():
            return dict(self._static)
        # :meth:`point` for every sample at once: the silhouettes do not move, only the
        # robot does, so its overlap with each is one product with the stacked masks.
        t = self._sample_table()
        r = np.flatnonzero(robot.ravel())  # the robot's pixels: the overlaps are sums there
        nearer = math.dist((robot_pose.x_m, robot_pose.y_m), self.centre_m[:2]) < t.dist
        use = (t.inside > 0) & nearer
        covered = np.where(use, t.whole[:, r].sum(axis=1) / np.maximum(t.inside, 1), 0.0)
        legs_px = t.legs[:, r].sum(axis=1)
        legs = np.where(use & (t.n_legs > 0), legs_px / np.maximum(t.n_legs, 1), 0.0)
        cfg = self.config
        hidden = (
            t.static_hidden | (covered > cfg.max_covered_frac) | (legs > cfg.max_legs_covered_frac)
        )
        # each cell's hidden samples counted at once (exact integers, as the slices' sums)
        counts = np.add.reduceat(hidden.astype(np.intp), t.starts).tolist()
        return {
            cell: float(n) / (i1 - i0)
            for n, (cell, (i0, i1)) in zip(counts, t.spans.items(), strict=True)
        }

    def _sample_table(self) -> _SampleTable:
        """Every cell's sample silhouettes as stacked raster masks (made once a process)."""
        if self._shared.table is None:
            cfg = self.config
            spans: dict[int, tuple[int, int]] = {}
            whole: list[np.ndarray] = []
            legs: list[np.ndarray] = []
            inside: list[int] = []
            n_legs: list[int] = []
            dist: list[float] = []
            static: list[bool] = []
            for cell in self.grid.cells:
                i0 = len(whole)
                for x, y in self._samples(cell):
                    wm = np.zeros(self.shape, np.uint8)
                    lm = np.zeros(self.shape, np.uint8)
                    quads = self._person_quads(x, y)
                    if quads is not None:
                        self._fill(wm, quads[0])
                        self._fill(lm, quads[1])
                    whole.append(wm.ravel())
                    legs.append(lm.ravel())
                    inside.append(int(wm.sum()))
                    n_legs.append(int(lm.sum()))
                    dist.append(math.dist((x, y), self.centre_m[:2]))
                    p = self.point(x, y, None)
                    static.append(quads is None or p.in_image_frac < cfg.min_in_image_frac)
                spans[cell] = (i0, len(whole))
            self._shared.table = _SampleTable(
                spans=spans,
                starts=np.array([i0 for i0, _ in spans.values()], np.intp),
                whole=np.array(whole, np.float32),
                legs=np.array(legs, np.float32),
                inside=np.array(inside, float),
                n_legs=np.array(n_legs, float),
                dist=np.array(dist, float),
                static_hidden=np.array(static, bool),
            )
        return self._shared.table

    def point_hidden(self, x: float, y: float, robot_pose: Pose2D | None) -> bool:
        """Whether a person at floor point (x, y) is hidden from the camera."""
        robot = None if robot_pose is None else self.robot_mask(robot_pose)
        rxy = None if robot_pose is None else (robot_pose.x_m, robot_pose.y_m)
        return self.point(x, y, robot, rxy).hidden
