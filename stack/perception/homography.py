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

Points file (YAML), for points clicked in a frame and measured on the floor::

    image_size_px: [640, 400]          # optional: the frame size the pixels were clicked at
    points:                            # or the list alone at the top level
      - {pixel: [u, v], map: [x, y]}   # >= 4 entries

:func:`load_points_file` reads it and names the entry at fault in its errors;
:func:`calibrate` then fits the homography and :func:`save_calibration` writes the
calibration file above.

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

from stack.config import dump_yaml, load_yaml, read_text_capped, write_text
from stack.memo import Memo
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

    def camera_matrix(self) -> np.ndarray | None:
        """The 3 x 4 projection of map points (x, y, z) [m] implied by the homography.

        A floor homography fixes the camera up to its focal length; with square pixels
        and the principal point at the image centre (``image_size_px`` needed), the
        focal length follows from r1 . r2 = 0 and |r1| = |r2| (Zhang's constraints
        for one plane), and the vertical axis r3 = r1 x r2, oriented so that the
        camera is above the floor. Used to judge whether a box's size fits a person
        standing at its foot point.

        Returns:
            P with lambda [u, v, 1]^T = P [x, y, z, 1]^T, or None without an image size
            or when the homography is not that of a tilted pinhole camera.
        """
        if self.image_size_px is None:
            return None
        cached = self.__dict__.get("_camera")
        if cached is not None:
            return cached if cached.size else None
        cx, cy = (self.image_size_px[0] - 1) / 2.0, (self.image_size_px[1] - 1) / 2.0
        g = np.array([[1.0, 0.0, -cx], [0.0, 1.0, -cy], [0.0, 0.0, 1.0]]) @ self._inverse
        g1, g2, g3 = g[:, 0], g[:, 1], g[:, 2]
        # r1 . r2 = 0 and |r1| = |r2| in f^2, least squares over both equations
        a = np.array(
            [g1[0] * g2[0] + g1[1] * g2[1], g1[0] ** 2 + g1[1] ** 2 - g2[0] ** 2 - g2[1] ** 2]
        )
        b = np.array([-g1[2] * g2[2], g2[2] ** 2 - g1[2] ** 2])
        inv_f2 = float(a @ b / (a @ a)) if a @ a > 0 else 0.0  # (1 / f^2) a = b
        if not inv_f2 > 0:
            object.__setattr__(self, "_camera", np.zeros(0))
            return None
        f = 1.0 / math.sqrt(inv_f2)
        k_inv = np.diag([1.0 / f, 1.0 / f, 1.0])
        r1, r2, t = k_inv @ g1, k_inv @ g2, k_inv @ g3
        scale = math.sqrt(np.linalg.norm(r1) * np.linalg.norm(r2))
        r1, r2, t = r1 / scale, r2 / scale, t / scale
        if t[2] < 0:  # the floor's origin must lie in front of the camera
            r1, r2, t = -r1, -r2, -t
        r3 = np.cross(r1, r2)
        centre = -np.c_[r1, r2, r3].T @ t
        if centre[2] < 0:  # the map's z must point up, towards the camera
            r3 = -r3
        k = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        cam = k @ np.c_[r1, r2, r3, t]
        cam.setflags(write=False)
        object.__setattr__(self, "_camera", cam)
        return cam

    def height_at_row_m(self, x: float, y: float, v: float) -> float | None:
        """Height above floor point (x, y) that the image row ``v`` sees [m].

        With :meth:`camera_matrix`: the point of the vertical line through (x, y)
        whose pixel lies on row v (e.g. a box's top row above its foot point).

        Returns:
            The height [m], or None without a camera matrix or for a horizontal line.
        """
        cam = self.camera_matrix()
        if cam is None:
            return None
        a = cam @ np.array([x, y, 0.0, 1.0])
        b = cam[:, 2]
        den = v * b[2] - b[1]
        if abs(den) < 1e-12:
            return None
        return float((a[1] - v * a[2]) / den)

    def row_of_point_px(self, x: float, y: float, z: float) -> float | None:
        """Image row of the point ``z`` metres above floor point (x, y) [px].

        With :meth:`camera_matrix`; e.g. the head row of a person standing at (x, y).

        Returns:
            The row v [px], or None without a camera matrix or for a point behind it.
        """
        cam = self.camera_matrix()
        if cam is None:
            return None
        q = cam @ np.array([x, y, z, 1.0])
        if q[2] <= 1e-12:
            return None
        return float(q[1] / q[2])

    def map_to_image(self, x: float, y: float) -> tuple[float, float] | None:
        """Map a floor point to its pixel (the inverse of eq. 4.4); None if behind the camera."""
        q = self._inverse @ np.array([x, y, 1.0])
        if abs(q[2]) < 1e-12:
            return None
        u, v = q[0] / q[2], q[1] / q[2]
        back = self.image_to_map(u, v)
        return None if back is None else (float(u), float(v))


@dataclass(frozen=True, eq=False)
class FloorPoints:
    """Floor points known both in the image and on the map (a points file's content).

    Attributes:
        image_px: (N, 2) pixels (u, v).
        map_m: (N, 2) their map coordinates (x, y) [m].
        image_size_px: (width, height) of the frame the pixels belong to, if given.
    """

    image_px: np.ndarray
    map_m: np.ndarray
    image_size_px: tuple[int, int] | None = None


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
    write_text(path, dump_yaml(data, sort_keys=False))


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
        text = read_text_capped(path)
    except (OSError, ValueError) as err:
        raise CalibrationError(f"cannot read calibration file {str(path)!r}: {err}") from err
    # a study's episodes each read their own copy of the same text, twice (the camera and
    # the observations): parsed and fitted once a process (the result is immutable)
    return _CALIBRATIONS.get(text, lambda: _parse_calibration(text, path))


_CALIBRATIONS = Memo(8)  # calibration file text -> its calibration


def _parse_calibration(text: str, path: Path) -> Calibration:
    """:func:`load_calibration` of the file's ``text``."""
    try:
        data = load_yaml(text)
    except (ValueError, yaml.YAMLError) as err:
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


def _pair_of_numbers(value: Any) -> tuple[float, float] | None:
    if isinstance(value, str | bytes) or not isinstance(value, list | tuple) or len(value) != 2:
        return None
    if any(isinstance(v, bool) or not isinstance(v, int | float) for v in value):
        return None
    if not all(math.isfinite(v) for v in value):
        return None
    return (float(value[0]), float(value[1]))


def load_points_file(path: str | Path) -> FloorPoints:
    """Read a points file: floor points clicked in a frame and measured on the map.

    The file is YAML: either a list of ``{pixel: [u, v], map: [x, y]}`` entries, or a
    mapping with that list under ``points`` and an optional ``image_size_px: [w, h]``.

    Args:
        path: the file.

    Returns:
        The points (fit them with :func:`calibrate`).

    Raises:
        CalibrationError: the file is missing or not YAML, an entry is malformed
            (the message names the entry by its index, from 0, and what is wrong),
            a pixel or map point repeats, or there are fewer than 4 entries.
    """
    path = Path(path)
    name = repr(str(path))
    if not path.is_file():
        raise CalibrationError(f"points file {name} does not exist")
    try:
        data = load_yaml(read_text_capped(path))
    except (OSError, ValueError, yaml.YAMLError) as err:
        raise CalibrationError(f"cannot read points file {name}: {err}") from err
    size = None
    if isinstance(data, dict):
        unknown = sorted(set(data) - {"points", "image_size_px"})
        if unknown:
            raise CalibrationError(
                f"points file {name}: unknown key(s) {unknown} (known: image_size_px, points)"
            )
        if data.get("image_size_px") is not None:
            raw = data["image_size_px"]
            pair = _pair_of_numbers(raw)
            if pair is None or not all(v > 0 and float(v).is_integer() for v in pair):
                raise CalibrationError(
                    f"points file {name}: image_size_px {raw!r} must be [width, height] in "
                    "positive whole pixels"
                )
            size = (int(pair[0]), int(pair[1]))
        data = data.get("points")
    if not isinstance(data, list):
        raise CalibrationError(
            f"points file {name}: needs a list of {{pixel: [u, v], map: [x, y]}} entries "
            f"(at the top level or under 'points'), got {type(data).__name__}"
        )
    image_px: list[tuple[float, float]] = []
    map_m: list[tuple[float, float]] = []
    for i, entry in enumerate(data):
        where = f"points file {name}: entry {i} ({entry!r})"
        if not isinstance(entry, dict):
            raise CalibrationError(f"{where}: must be a mapping {{pixel: [u, v], map: [x, y]}}")
        extra = sorted(set(entry) - {"pixel", "map"})
        if extra:
            raise CalibrationError(f"{where}: unknown key(s) {extra} (known: pixel, map)")
        for key, unit in (("pixel", "[u, v] in pixels"), ("map", "[x, y] in metres")):
            if key not in entry:
                raise CalibrationError(f"{where}: missing '{key}' {unit}")
            if _pair_of_numbers(entry[key]) is None:
                raise CalibrationError(f"{where}: '{key}' must be {unit}, two finite numbers")
        u, v = _pair_of_numbers(entry["pixel"])  # type: ignore[misc]
        if u < 0 or v < 0 or (size is not None and (u > size[0] - 1 or v > size[1] - 1)):
            bounds = "" if size is None else f" inside the {size[0]} x {size[1]} image"
            raise CalibrationError(f"{where}: pixel [{u}, {v}] must be >= 0{bounds}")
        xy = _pair_of_numbers(entry["map"])
        assert xy is not None  # checked above
        for other, (px_seen, xy_seen) in enumerate(zip(image_px, map_m, strict=True)):
            if px_seen == (u, v) or xy_seen == xy:
                raise CalibrationError(f"{where}: repeats entry {other}'s pixel or map point")
        image_px.append((u, v))
        map_m.append(xy)
    if len(image_px) < MIN_POINTS:
        raise CalibrationError(
            f"points file {name}: needs at least {MIN_POINTS} points, got {len(image_px)}"
        )
    return FloorPoints(np.array(image_px, float), np.array(map_m, float), size)


def save_points_file(path: str | Path, points: FloorPoints) -> None:
    """Write floor points in the format :func:`load_points_file` reads.

    Args:
        path: the file to write (parent folders are created).
        points: the points (and optional image size).
    """
    data: dict[str, Any] = {}
    if points.image_size_px is not None:
        data["image_size_px"] = [int(v) for v in points.image_size_px]
    data["points"] = [
        {"pixel": [float(u), float(v)], "map": [float(x), float(y)]}
        for (u, v), (x, y) in zip(points.image_px, points.map_m, strict=True)
    ]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, dump_yaml(data, sort_keys=False, default_flow_style=None))
