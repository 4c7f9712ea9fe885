"""The room's occupancy map, rasterised from the twin's static geometry.

The map is the stack's one map type, :class:`stack.nav.occupancy.OccupancyMap`
(nav_msgs/OccupancyGrid convention), written and read as map_server files by
:func:`stack.nav.occupancy.save_map_yaml` / ``load_map_yaml``: the navigation stack
reads the same kind of file it would read on the robot.
"""

from __future__ import annotations

import cv2
import mujoco
import numpy as np

from stack.nav.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap

__all__ = ["FREE", "OCCUPIED", "UNKNOWN", "OccupancyMap", "occupancy_from_model"]


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
    return OccupancyMap(grid, resolution_m, (ox, oy))
