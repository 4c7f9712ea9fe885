"""The room's occupancy map, made from the twin's static geometry, in map_server format.

The navigation stack reads the same kind of file it would read on the robot: a PGM image
plus a YAML file with ``image``, ``mode``, ``resolution``, ``origin``, ``negate``,
``occupied_thresh`` and ``free_thresh`` (nav2 map_server / ROS 1 map_server).

Convention of :class:`OccupancyMap.data` (as nav_msgs/OccupancyGrid): int8, row 0 at
the map's origin (south edge), values 0 free, 100 occupied, -1 unknown.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import mujoco
import numpy as np
import yaml

FREE, OCCUPIED, UNKNOWN = 0, 100, -1
# trinary PGM values written by map_saver
_PGM_FREE, _PGM_OCCUPIED, _PGM_UNKNOWN = 254, 0, 205


@dataclass(frozen=True)
class OccupancyMap:
    """An occupancy grid in the map frame.

    Attributes:
        data: (rows, cols) int8, row 0 at origin_m's y, column 0 at origin_m's x.
        resolution_m: side of one cell [m].
        origin_m: map position of the lower-left corner of cell (0, 0) [m].
        occupied_thresh, free_thresh: the thresholds written to / read from YAML.
    """

    data: np.ndarray
    resolution_m: float
    origin_m: tuple[float, float]
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape  # type: ignore[return-value]

    def index_of(self, x: float, y: float) -> tuple[int, int] | None:
        """(row, col) of the cell holding map point (x, y); None outside the map."""
        col = int(np.floor((x - self.origin_m[0]) / self.resolution_m))
        row = int(np.floor((y - self.origin_m[1]) / self.resolution_m))
        if 0 <= row < self.data.shape[0] and 0 <= col < self.data.shape[1]:
            return row, col
        return None

    def value_at(self, x: float, y: float) -> int:
        """Occupancy value at map point (x, y); UNKNOWN outside the map."""
        idx = self.index_of(x, y)
        return UNKNOWN if idx is None else int(self.data[idx])

    def save(self, directory: str | Path, name: str = "map") -> tuple[Path, Path]:
        """Write ``name.pgm`` and ``name.yaml`` in map_server's trinary format.

        Args:
            directory: where to write (created if absent).
            name: file stem.

        Returns:
            (pgm_path, yaml_path).
        """
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        img = np.full(self.data.shape, _PGM_UNKNOWN, np.uint8)
        img[self.data == FREE] = _PGM_FREE
        img[self.data == OCCUPIED] = _PGM_OCCUPIED
        img = img[::-1]  # PGM row 0 is the top (north) edge
        pgm = directory / f"{name}.pgm"
        height, width = int(img.shape[0]), int(img.shape[1])  # type: ignore[misc]
        header = f"P5\n# vigil twin occupancy map\n{width} {height}\n255\n"
        pgm.write_bytes(header.encode("ascii") + img.tobytes())
        meta = {
            "image": pgm.name,
            "mode": "trinary",
            "resolution": float(self.resolution_m),
            "origin": [float(self.origin_m[0]), float(self.origin_m[1]), 0.0],
            "negate": 0,
            "occupied_thresh": float(self.occupied_thresh),
            "free_thresh": float(self.free_thresh),
        }
        yml = directory / f"{name}.yaml"
        yml.write_text(yaml.safe_dump(meta, sort_keys=False))
        return pgm, yml


def load_map(yaml_path: str | Path) -> OccupancyMap:
    """Read a map_server YAML + image pair the way map_server does (trinary mode).

    Args:
        yaml_path: the YAML file; its ``image`` is read relative to it.

    Returns:
        The occupancy map.

    Raises:
        ValueError: a required key is missing, or the image cannot be read.
    """
    yaml_path = Path(yaml_path)
    meta = yaml.safe_load(yaml_path.read_text())
    for key in ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"):
        if key not in meta:
            raise ValueError(f"{yaml_path}: missing key {key!r}")
    img = cv2.imread(str(yaml_path.parent / meta["image"]), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError(f"{yaml_path}: cannot read image {meta['image']!r}")
    p = img.astype(np.float64) / 255.0
    if not meta["negate"]:
        p = 1.0 - p  # dark = occupied
    data = np.full(img.shape, UNKNOWN, np.int8)
    data[p > meta["occupied_thresh"]] = OCCUPIED
    data[p < meta["free_thresh"]] = FREE
    return OccupancyMap(
        data=data[::-1].copy(),
        resolution_m=float(meta["resolution"]),
        origin_m=(float(meta["origin"][0]), float(meta["origin"][1])),
        occupied_thresh=float(meta["occupied_thresh"]),
        free_thresh=float(meta["free_thresh"]),
    )


def _geom_points(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> np.ndarray | None:
    """Points on a geom's surface (world frame) whose convex hull bounds it."""
    t = mujoco.mjtGeom(int(model.geom_type[g]))  # an enum: numpy ints compare unreliably
    size = model.geom_size[g]
    pos = data.geom_xpos[g]
    rot = data.geom_xmat[g].reshape(3, 3)
    ring = np.linspace(0, 2 * np.pi, 16, endpoint=False)
    c, s = np.cos(ring), np.sin(ring)
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        local = signs * size
    elif t in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE):
        r, h = size[0], size[1]
        ends = [h, -h]
        if t == mujoco.mjtGeom.mjGEOM_CAPSULE:
            ends += [h + r, -h - r]
        local = np.concatenate([np.column_stack([r * c, r * s, np.full(16, z)]) for z in ends])
    elif t in (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_ELLIPSOID):
        radii = size if t == mujoco.mjtGeom.mjGEOM_ELLIPSOID else np.full(3, size[0])
        pts = []
        for lat in np.linspace(-np.pi / 2, np.pi / 2, 7):
            pts.append(
                np.column_stack([np.cos(lat) * c, np.cos(lat) * s, np.full(16, np.sin(lat))])
            )
        local = np.concatenate(pts) * radii
    else:
        return None  # planes (the floor) and meshes are not obstacles here
    return pos + local @ rot.T


def occupancy_from_model(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    room: tuple[float, float, float, float],
    resolution_m: float,
    z_range_m: tuple[float, float],
    margin_m: float = 0.5,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
) -> OccupancyMap:
    """Rasterise the static geoms of a compiled scene into an occupancy grid.

    A geom is an obstacle if it is static (welded to the world, not a mocap body) and
    reaches into the height band ``z_range_m``; its whole floor footprint is marked.

    Args:
        model, data: the compiled scene after mj_forward.
        room: (x_min, y_min, x_max, y_max) of the room's inside: free unless occupied;
            everything else is unknown.
        resolution_m: cell side [m].
        z_range_m: (z_min, z_max) height band of obstacles [m].
        margin_m: unknown border around the room (holds the walls) [m].
        occupied_thresh, free_thresh: thresholds recorded in the map.

    Returns:
        The map, origin at the room's south-west corner minus the margin.
    """
    x0, y0, x1, y1 = room
    ox, oy = x0 - margin_m, y0 - margin_m
    cols = int(np.ceil((x1 + margin_m - ox) / resolution_m))
    rows = int(np.ceil((y1 + margin_m - oy) / resolution_m))
    grid = np.full((rows, cols), UNKNOWN, np.int8)
    # free: cells whose centre lies in the room
    xs = ox + (np.arange(cols) + 0.5) * resolution_m
    ys = oy + (np.arange(rows) + 0.5) * resolution_m
    inside = (ys[:, None] >= y0) & (ys[:, None] <= y1) & (xs[None, :] >= x0) & (xs[None, :] <= x1)
    grid[inside] = FREE
    occ = np.zeros((rows, cols), np.uint8)
    for g in range(model.ngeom):
        body = model.geom_bodyid[g]
        if model.body_weldid[body] != 0 or model.body_mocapid[body] >= 0:
            continue
        pts = _geom_points(model, data, g)
        if pts is None:
            continue
        if pts[:, 2].max() < z_range_m[0] or pts[:, 2].min() > z_range_m[1]:
            continue
        # to pixel coordinates (col, row) of cell corners; fill the hull
        pix = (pts[:, :2] - (ox, oy)) / resolution_m - 0.5  # OpenCV: pixel centres at integers
        hull = cv2.convexHull(np.round(pix * 16).astype(np.int32))
        cv2.fillConvexPoly(occ, hull, 1, lineType=cv2.LINE_8, shift=4)
    grid[occ > 0] = OCCUPIED
    return OccupancyMap(grid, resolution_m, (ox, oy), occupied_thresh, free_thresh)
