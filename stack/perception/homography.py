"""Image-to-floor homography (thesis eqs. 4.4-4.7) and its calibration file.

A person's foot pixel (u, v) maps to the floor map point (x', y') through a 3 x 3
homogeneous matrix H: lambda [x' y' 1]^T = H [u v 1]^T (4.4), with
lambda = h20 u + h21 v + h22 (4.5), x' and y' by (4.6) and (4.7). H comes from
``cv2.findHomography`` on at least four floor points whose image pixels and map
coordinates are both known: clicked or measured on the robot, reported by the twin
in simulation.

Calibration file (YAML)::

    image_size_px: [640, 400]          # optional, checked against frames
    points:                            # >= 4 floor points, not collinear
      - {image_px: [u, v], map_m: [x, y]}
    homography: [[h00, h01, h02], ...] # written by save_calibration
    reprojection_error_m: {mean: ..., max: ...}

Pixels above the horizon have lambda of the wrong sign (or ~0): they map to no
floor point, and :meth:`FloorHomography.image_to_map` returns None for them rather
than a point behind the camera.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from stack.perception.errors import CalibrationError

MIN_POINTS = 4


@dataclass(frozen=True, eq=False)
class FloorHomography:
    """The image-to-floor mapping of one camera.

    Attributes:
        matrix: H of eq. 4.4, image pixels -> map metres, normalised to h22 = 1.
        lambda_sign: sign of lambda (4.5) for floor pixels (+1 or -1).
        image_size_px: (width, height) the calibration was made at, or None.
    """

    matrix: np.ndarray
    lambda_sign: float = 1.0
    image_size_px: tuple[int, int] | None = None
    _inverse: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, dtype=float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise CalibrationError(f"homography must be a finite 3 x 3 matrix, got {m.tolist()}")
        if abs(np.linalg.det(m)) < 1e-12:
            raise CalibrationError("homography is singular (det ~ 0)")
        m.setflags(write=False)
        inv = np.linalg.inv(m)
        inv.setflags(write=False)
        object.__setattr__(self, "matrix", m)
        object.__setattr__(self, "_inverse", inv)

    def image_to_map(
        self, u: float, v: float, min_lambda: float = 1e-9
    ) -> tuple[float, float] | None:
        """Map one pixel to the floor (eqs. 4.4-4.7).

        Args:
            u, v: pixel column and row.
            min_lambda: |lambda| at or below which the pixel is taken as the horizon.

        Returns:
            (x', y') in metres, or None for a pixel on or above the horizon.
        """
        h = self.matrix
        lam = h[2, 0] * u + h[2, 1] * v + h[2, 2]  # (4.5)
        if not math.isfinite(lam) or lam * self.lambda_sign <= min_lambda:
            return None
        x = (h[0, 0] * u + h[0, 1] * v + h[0, 2]) / lam  # (4.6)
        y = (h[1, 0] * u + h[1, 1] * v + h[1, 2]) / lam  # (4.7)
        return (float(x), float(y))

    def image_to_map_many(self, pixels: np.ndarray) -> np.ndarray:
        """Map (N, 2) pixels to (N, 2) map points; rows above the horizon are NaN."""
        p = np.asarray(pixels, dtype=float).reshape(-1, 2)
        hom = np.c_[p, np.ones(len(p))] @ self.matrix.T
        lam = hom[:, 2]
        out = hom[:, :2] / lam[:, None]
        out[lam * self.lambda_sign <= 1e-9] = np.nan
        return out

    def map_to_image(self, x: float, y: float) -> tuple[float, float] | None:
        """Map a floor point to its pixel (the inverse of eq. 4.4); None if behind the camera."""
        q = self._inverse @ np.array([x, y, 1.0])
        if abs(q[2]) < 1e-12:
            return None
        u, v = q[0] / q[2], q[1] / q[2]
        back = self.image_to_map(u, v)
        return None if back is None else (float(u), float(v))


@dataclass(frozen=True, eq=False)
class Calibration:
    """The result of a calibration: the homography and its fit on the points used.

    Attributes:
        homography: the fitted mapping.
        image_px: (N, 2) calibration pixels.
        map_m: (N, 2) their map coordinates [m].
        errors_m: (N,) distance between each map point and its pixel mapped by H [m].
    """

    homography: FloorHomography
    image_px: np.ndarray
    map_m: np.ndarray
    errors_m: np.ndarray

    @property
    def mean_error_m(self) -> float:
        """Mean reprojection error on the floor [m]."""
        return float(np.mean(self.errors_m))

    @property
    def max_error_m(self) -> float:
        """Largest reprojection error on the floor [m]."""
        return float(np.max(self.errors_m))


def calibrate(
    image_px: Sequence[Sequence[float]] | np.ndarray,
    map_m: Sequence[Sequence[float]] | np.ndarray,
    image_size_px: tuple[int, int] | None = None,
    ransac_threshold_m: float | None = None,
) -> Calibration:
    """Fit the image-to-floor homography from point pairs with ``cv2.findHomography``.

    Args:
        image_px: (N, 2) pixels (u, v) of floor points, N >= 4.
        map_m: (N, 2) their map coordinates (x, y) [m].
        image_size_px: (width, height) of the frames, stored for checking.
        ransac_threshold_m: with a value, RANSAC rejects pairs off by more than this
            on the floor (mis-clicked points); None fits all points by least squares.

    Returns:
        The homography and its reprojection errors on the given points.

    Raises:
        CalibrationError: fewer than 4 pairs, mismatched shapes, non-finite values,
            or a degenerate layout (collinear points) for which no homography exists.
    """
    src = np.asarray(image_px, dtype=np.float64)
    dst = np.asarray(map_m, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 2 or dst.shape != src.shape:
        raise CalibrationError(
            f"need matching (N, 2) point arrays, got image {src.shape} and map {dst.shape}"
        )
    if len(src) < MIN_POINTS:
        raise CalibrationError(f"need at least {MIN_POINTS} point pairs, got {len(src)}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise CalibrationError("calibration points must be finite numbers")
    if ransac_threshold_m is None:
        matrix, _ = cv2.findHomography(src, dst, 0)
    else:
        matrix, _ = cv2.findHomography(src, dst, cv2.RANSAC, ransac_threshold_m)
    if matrix is None or not np.all(np.isfinite(matrix)) or abs(np.linalg.det(matrix)) < 1e-12:
        raise CalibrationError("no homography fits these points (are they collinear?)")
    matrix = matrix / matrix[2, 2]
    lam = np.c_[src, np.ones(len(src))] @ matrix[2]
    if np.all(lam > 0):
        sign = 1.0
    elif np.all(lam < 0):
        sign = -1.0
    else:
        raise CalibrationError("calibration points lie on both sides of the horizon")
    hom = FloorHomography(matrix, lambda_sign=sign, image_size_px=image_size_px)
    mapped = hom.image_to_map_many(src)
    errors = np.linalg.norm(mapped - dst, axis=1)
    return Calibration(homography=hom, image_px=src, map_m=dst, errors_m=errors)


def save_calibration(path: str | Path, calibration: Calibration) -> None:
    """Write the points, the homography and its reprojection error to a YAML file.

    Args:
        path: the file to write (parent folders are created).
        calibration: the result of :func:`calibrate`.
    """
    hom = calibration.homography
    data: dict[str, Any] = {}
    if hom.image_size_px is not None:
        data["image_size_px"] = [int(v) for v in hom.image_size_px]
    data["points"] = [
        {"image_px": [float(u), float(v)], "map_m": [float(x), float(y)]}
        for (u, v), (x, y) in zip(calibration.image_px, calibration.map_m, strict=True)
    ]
    data["homography"] = [[float(v) for v in row] for row in hom.matrix]
    data["reprojection_error_m"] = {
        "mean": calibration.mean_error_m,
        "max": calibration.max_error_m,
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; fit the homography from its points.

    The points are the source of truth: the stored ``homography`` is only checked
    against the refit (a hand-edited file whose matrix disagrees is an error).

    Args:
        path: a YAML file as written by :func:`save_calibration`.

    Returns:
        The calibration, with reprojection errors.

    Raises:
        CalibrationError: file missing or unreadable, points malformed or degenerate,
            or a stored homography that disagrees with the points.
    """
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"calibration file {str(path)!r} does not exist")
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise CalibrationError(f"cannot read calibration file {str(path)!r}: {err}") from err
    if not isinstance(data, dict) or not isinstance(data.get("points"), list):
        raise CalibrationError(f"{str(path)!r}: needs a 'points' list of image_px/map_m pairs")
    try:
        image_px = [tuple(p["image_px"]) for p in data["points"]]
        map_m = [tuple(p["map_m"]) for p in data["points"]]
        size = data.get("image_size_px")
        size = None if size is None else (int(size[0]), int(size[1]))
        src, dst = np.array(image_px, dtype=float), np.array(map_m, dtype=float)
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise CalibrationError(f"{str(path)!r}: malformed points ({err})") from err
    cal = calibrate(src, dst, image_size_px=size)
    stored = data.get("homography")
    if stored is not None:
        try:
            stored_h = FloorHomography(np.array(stored, dtype=float))
        except (TypeError, ValueError) as err:
            raise CalibrationError(f"{str(path)!r}: malformed homography ({err})") from err
        check = stored_h.image_to_map_many(src)
        if not np.allclose(check, cal.homography.image_to_map_many(src), atol=1e-3):
            raise CalibrationError(f"{str(path)!r}: stored homography disagrees with its points")
    return cal
