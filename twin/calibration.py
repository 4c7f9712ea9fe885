"""Floor calibration of the twin's ceiling camera from points the twin reports.

On the robot the homography (thesis eqs. 4.4-4.7) is fitted to floor points whose
pixels were clicked and whose map coordinates were measured. In the twin both are
known exactly: the cells' corners (the floor points a calibration on site would use)
are projected into the image with the twin's own camera pose and intrinsics
(:func:`twin.sensors.project`). This module is the one place that does it, for the
``vigil calibrate`` command, the perception tests and the benchmarks.

    from twin.calibration import calibrate_twin
    cal = calibrate_twin(tw)                 # stack.perception.homography.Calibration
    cal.mean_error_m, cal.max_error_m        # reprojection error on the points [m]
"""

from __future__ import annotations

import numpy as np

from stack.cells import CellGrid
from stack.perception.errors import CalibrationError
from stack.perception.homography import MIN_POINTS, Calibration, FloorPoints, calibrate
from twin.sensors import project
from twin.twin import Twin


def cell_corners_m(grid: CellGrid) -> np.ndarray:
    """(N, 2) map coordinates of every cell corner of the grid [m], row by row."""
    w, h = grid.cell_size_m
    xs = grid.origin_m[0] + w * np.arange(grid.columns + 1)
    ys = grid.origin_m[1] + h * np.arange(grid.rows + 1)
    return np.array([(x, y) for x in xs for y in ys], dtype=float)


def twin_floor_points(
    tw: Twin, grid: CellGrid | None = None, floor_m: np.ndarray | None = None
) -> FloorPoints:
    """Floor points with their pixels in the twin's camera image.

    Args:
        tw: the twin (its camera pose and intrinsics are read).
        grid: the cells whose corners are used (default: the twin's grid).
        floor_m: (N, 2) floor points to use instead of the corners [m].

    Returns:
        The points that project inside the image, with the image size.

    Raises:
        CalibrationError: fewer than 4 points are in view.
    """
    grid = tw.config.grid if grid is None else grid
    floor = cell_corners_m(grid) if floor_m is None else np.asarray(floor_m, float).reshape(-1, 2)
    info = tw.camera_info
    pixels = project(info, tw.camera_pose(), np.c_[floor, np.zeros(len(floor))])
    inside = (
        np.all(np.isfinite(pixels), axis=1)
        & (pixels[:, 0] >= 0) & (pixels[:, 0] <= info.width - 1)
        & (pixels[:, 1] >= 0) & (pixels[:, 1] <= info.height - 1)
    )  # fmt: skip
    if inside.sum() < MIN_POINTS:
        raise CalibrationError(
            f"only {int(inside.sum())} of {len(floor)} floor points are in the twin camera's "
            f"{info.width} x {info.height} view; need {MIN_POINTS}"
        )
    return FloorPoints(pixels[inside], floor[inside], (info.width, info.height))


def calibrate_twin(tw: Twin, grid: CellGrid | None = None) -> Calibration:
    """Fit the image-to-floor homography of the twin's camera on the cells' corners.

    Args:
        tw: the twin.
        grid: the cell grid (default: the twin's).

    Returns:
        The calibration; ``errors_m`` / ``mean_error_m`` / ``max_error_m`` give the
        reprojection error on the corners (~1e-9 m: the twin renders a pinhole camera).

    Raises:
        CalibrationError: fewer than 4 corners in view, or a degenerate layout.
    """
    pts = twin_floor_points(tw, grid)
    return calibrate(pts.image_px, pts.map_m, image_size_px=pts.image_size_px)
