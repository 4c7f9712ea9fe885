"""Occupancy maps: the map_server file format, OccupancyGrid arrays, and inflation.

A map is an ``int8`` grid in the ``nav_msgs/OccupancyGrid`` convention: row ``i`` is the
``i``-th row of cells *northwards* from the origin (so row 0 is the southmost row, the
opposite of an image), column ``j`` the ``j``-th cell eastwards; values are 0 (free),
100 (occupied) and -1 (unknown). Cell ``(i, j)`` covers the square whose south-west corner
is ``origin + (j, i) * resolution``; its centre is half a cell further on.

The map_server YAML format (ROS ``map_server`` / nav2 ``map_io``)::

    image: room.pgm          # relative to the YAML file
    resolution: 0.05         # [m/cell]
    origin: [-1.0, -1.0, 0.0]  # map position of the image's lower-left pixel, yaw [rad]
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.25
    mode: trinary            # optional: trinary (default), scale or raw

For ``trinary`` and ``scale`` the occupancy probability of a pixel is
``p = (255 - v) / 255`` (``v / 255`` with ``negate: 1``); ``p > occupied_thresh`` is
occupied, ``p < free_thresh`` free, anything between unknown. ``raw`` takes ``v`` as the
value itself (0..100, anything else unknown).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path as FsPath
from typing import Any

import numpy as np
import yaml
from scipy import ndimage

from stack.config import (
    dump_yaml,
    load_yaml,
    read_bytes_capped,
    read_text_capped,
    write_bytes,
    write_text,
)

FREE = 0
OCCUPIED = 100
UNKNOWN = -1

_MODES = ("trinary", "scale", "raw")


class MapError(ValueError):
    """A map file or array is malformed; the message names the file, the field and the rule."""


@dataclass(frozen=True, eq=False)
class OccupancyMap:
    """An occupancy grid placed in the map frame.

    Attributes:
        data: (height, width) int8 array, OccupancyGrid convention (row 0 southmost).
        resolution_m: edge length of one cell [m].
        origin_m: map position (x, y) of the south-west corner of cell (0, 0) [m].
    """

    data: np.ndarray
    resolution_m: float
    origin_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 2 or data.size == 0:
            raise MapError(f"map data must be a non-empty 2-D array, got shape {data.shape}")
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0):
            raise MapError(f"resolution: {self.resolution_m!r} must be a finite number > 0")
        data = data.astype(np.int8, copy=True)
        data.setflags(write=False)
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "origin_m", (float(self.origin_m[0]), float(self.origin_m[1])))

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in cells."""
        return self.data.shape  # type: ignore[return-value]

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the map [m]."""
        h, w = self.shape
        return (w * self.resolution_m, h * self.resolution_m)

    def occupied(self, unknown_is_occupied: bool = True) -> np.ndarray:
        """Boolean (height, width) grid, True where the robot must not be.

        Args:
            unknown_is_occupied: treat unknown (-1) cells as obstacles (the safe default).
        """
        occ = self.data >= 50  # OccupancyGrid probabilities 50..100 count as occupied
        if unknown_is_occupied:
            occ |= self.data < 0
        return occ

    def world_to_cell(self, x: float, y: float) -> tuple[int, int]:
        """(row, col) of the cell containing map point (x, y); may lie outside the grid."""
        res = self.resolution_m
        return (
            int(math.floor((y - self.origin_m[1]) / res)),
            int(math.floor((x - self.origin_m[0]) / res)),
        )

    def cell_to_world(self, row: int, col: int) -> tuple[float, float]:
        """Map position (x, y) of a cell's centre [m]."""
        res = self.resolution_m
        return (self.origin_m[0] + (col + 0.5) * res, self.origin_m[1] + (row + 0.5) * res)

    def cells_to_world(self, cells: np.ndarray) -> np.ndarray:
        """Vectorised ``cell_to_world``: (N, 2) (row, col) -> (N, 2) (x, y)."""
        cells = np.asarray(cells, dtype=float).reshape(-1, 2)
        res = self.resolution_m
        return np.column_stack(
            (
                self.origin_m[0] + (cells[:, 1] + 0.5) * res,
                self.origin_m[1] + (cells[:, 0] + 0.5) * res,
            )
        )

    def contains(self, row: int, col: int) -> bool:
        h, w = self.shape
        return 0 <= row < h and 0 <= col < w

    def value_at(self, x: float, y: float) -> int:
        """Occupancy value at map point (x, y); UNKNOWN outside the map."""
        row, col = self.world_to_cell(x, y)
        return int(self.data[row, col]) if self.contains(row, col) else UNKNOWN

    def with_data(self, data: np.ndarray) -> OccupancyMap:
        """The same placement with other cell values (same shape)."""
        if np.shape(data) != self.shape:
            raise MapError(f"data shape {np.shape(data)} differs from map shape {self.shape}")
        return OccupancyMap(data, self.resolution_m, self.origin_m)

    @classmethod
    def empty(
        cls, width_m: float, height_m: float, resolution_m: float, origin_m=(0.0, 0.0)
    ) -> OccupancyMap:
        """A free map of the given size (rounded up to whole cells)."""
        w = int(math.ceil(width_m / resolution_m - 1e-9))
        h = int(math.ceil(height_m / resolution_m - 1e-9))
        return cls(np.zeros((h, w), dtype=np.int8), resolution_m, origin_m)


def from_occupancy_grid(
    data: Any,
    width: int,
    height: int,
    resolution_m: float,
    origin_xy: tuple[float, float] = (0.0, 0.0),
    origin_yaw_rad: float = 0.0,
) -> OccupancyMap:
    """Build a map from the fields of a ``nav_msgs/OccupancyGrid`` (``info`` and ``data``).

    Args:
        data: flat row-major sequence of ``width * height`` values in -1..100.
        width, height: ``info.width`` and ``info.height`` [cells].
        resolution_m: ``info.resolution`` [m/cell].
        origin_xy: ``info.origin.position`` x and y [m].
        origin_yaw_rad: yaw of ``info.origin.orientation``; only 0 is supported.

    Returns:
        The map.

    Raises:
        MapError: the sizes disagree, values fall outside -1..100, or the origin is rotated.
    """
    arr = np.asarray(data, dtype=np.int64).ravel()
    if width <= 0 or height <= 0:
        raise MapError(f"OccupancyGrid: width {width} and height {height} must be > 0")
    if arr.size != width * height:
        raise MapError(
            f"OccupancyGrid: data has {arr.size} values, width*height is {width * height}"
        )
    bad = (arr < -1) | (arr > 100)
    if bad.any():
        raise MapError(
            f"OccupancyGrid: value {int(arr[bad][0])} at index {int(np.flatnonzero(bad)[0])} "
            "is outside -1..100"
        )
    _check_yaw("OccupancyGrid origin", origin_yaw_rad)
    return OccupancyMap(arr.reshape(height, width).astype(np.int8), resolution_m, origin_xy)


def load_map_yaml(path: str | FsPath) -> OccupancyMap:
    """Load a map_server map (YAML metadata + PGM/PNG image).

    Args:
        path: the YAML file; its ``image`` is resolved relative to the YAML's folder.

    Returns:
        The map, with row 0 the image's bottom row.

    Raises:
        MapError: the YAML or image is missing or malformed; the message names the file
            and the offending field.
    """
    path = FsPath(path)
    try:
        meta = load_yaml(read_text_capped(path))
    except OSError as exc:
        raise MapError(f"{path}: cannot read map YAML: {exc.strerror or exc}") from exc
    except ValueError as exc:  # too long, not UTF-8
        raise MapError(f"{path}: {exc}") from exc
    except yaml.YAMLError as exc:
        raise MapError(f"{path}: not valid YAML: {exc}") from exc
    meta_dict = _parse_meta(path, meta)
    image_path = FsPath(meta_dict["image"])
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    pixels = read_image(image_path)
    data = pixels_to_occupancy(
        pixels,
        negate=meta_dict["negate"],
        occupied_thresh=meta_dict["occupied_thresh"],
        free_thresh=meta_dict["free_thresh"],
        mode=meta_dict["mode"],
    )
    origin = meta_dict["origin"]
    return OccupancyMap(data, meta_dict["resolution"], (origin[0], origin[1]))


def save_map_yaml(
    occ_map: OccupancyMap,
    yaml_path: str | FsPath,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
) -> FsPath:
    """Write a map as map_server YAML + binary PGM (trinary, negate 0) beside it.

    Args:
        occ_map: the map.
        yaml_path: where the YAML goes (its folder is created); the image takes the
            same stem with ``.pgm``.
        occupied_thresh, free_thresh: the thresholds recorded for readers (the
            default free threshold is map_saver's: grey 205, p = 0.19607, reads back
            as unknown).

    Returns:
        The YAML path.
    """
    yaml_path = FsPath(yaml_path)
    yaml_path.parent.mkdir(parents=True, exist_ok=True)
    pgm = yaml_path.with_suffix(".pgm")
    img = np.full(occ_map.shape, 205, dtype=np.uint8)  # map_saver's grey for unknown
    img[occ_map.data == FREE] = 254
    img[occ_map.data >= 50] = 0
    img = img[::-1]  # image rows run southwards
    h, w = img.shape
    write_bytes(pgm, f"P5\n{w} {h}\n255\n".encode() + img.tobytes())
    meta = {
        "image": pgm.name,
        "resolution": occ_map.resolution_m,
        "origin": [occ_map.origin_m[0], occ_map.origin_m[1], 0.0],
        "negate": 0,
        "occupied_thresh": float(occupied_thresh),
        "free_thresh": float(free_thresh),
        "mode": "trinary",
    }
    write_text(yaml_path, dump_yaml(meta, sort_keys=False))
    return yaml_path


def _parse_meta(path: FsPath, meta: Any) -> dict[str, Any]:
    if not isinstance(meta, Mapping):
        raise MapError(f"{path}: must be a mapping of map_server fields, got {meta!r}")
    required = ("image", "resolution", "origin", "occupied_thresh", "free_thresh")
    missing = [k for k in required if k not in meta]
    if missing:
        raise MapError(f"{path}: missing required field(s) {missing}")
    known = set(required) | {"negate", "mode"}
    unknown = sorted(set(meta) - known)
    if unknown:
        raise MapError(f"{path}: unknown field(s) {unknown} (known: {sorted(known)})")
    image = meta["image"]
    if not isinstance(image, str) or not image:
        raise MapError(f"{path}: image: {image!r} must be a file name")
    res = _number(path, "resolution", meta["resolution"])
    if not res > 0:
        raise MapError(f"{path}: resolution: {res!r} must be > 0")
    origin = meta["origin"]
    if not isinstance(origin, list | tuple) or len(origin) != 3:
        raise MapError(f"{path}: origin: {origin!r} must be [x, y, yaw]")
    origin = [_number(path, f"origin[{i}]", v) for i, v in enumerate(origin)]
    _check_yaw(f"{path}: origin[2]", origin[2])
    occ_t = _number(path, "occupied_thresh", meta["occupied_thresh"])
    free_t = _number(path, "free_thresh", meta["free_thresh"])
    for key, v in (("occupied_thresh", occ_t), ("free_thresh", free_t)):
        if not 0.0 <= v <= 1.0:
            raise MapError(f"{path}: {key}: {v!r} must lie in [0, 1]")
    if not free_t < occ_t:
        raise MapError(f"{path}: free_thresh {free_t} must be below occupied_thresh {occ_t}")
    negate = meta.get("negate", 0)
    if negate not in (0, 1) or isinstance(negate, float):
        raise MapError(f"{path}: negate: {negate!r} must be 0 or 1")
    mode = meta.get("mode", "trinary")
    if mode not in _MODES:
        raise MapError(f"{path}: mode: {mode!r} must be one of {list(_MODES)}")
    return {
        "image": image,
        "resolution": res,
        "origin": origin,
        "occupied_thresh": occ_t,
        "free_thresh": free_t,
        "negate": int(negate),
        "mode": mode,
    }


def _number(path: FsPath, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MapError(f"{path}: {key}: {value!r} must be a finite number")
    return float(value)


def _check_yaw(where: str, yaw: float) -> None:
    if abs(math.remainder(yaw, 2 * math.pi)) > 1e-9:
        raise MapError(f"{where}: yaw {yaw!r} is not supported (rotated maps); use 0")


def read_image(path: FsPath) -> np.ndarray:
    """Read a greyscale map image as a (rows, cols) uint8/uint16 array, top row first.

    PGM (P2 ascii, P5 binary) is parsed here so that a malformed header gets a precise
    message; other formats (PNG, BMP) go through OpenCV.

    Raises:
        MapError: missing file, unreadable or malformed image.
    """
    if not path.is_file():
        raise MapError(f"{path}: image file not found")
    if path.suffix.lower() in (".pgm", ".pnm"):
        return _read_pgm(path)
    import cv2  # noqa: PLC0415 - only non-PGM maps need OpenCV

    try:  # a regular file within the cap, read once: OpenCV decodes those bytes
        data = read_bytes_capped(path)
    except ValueError as exc:
        raise MapError(str(exc)) from None
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise MapError(f"{path}: not a readable image")
    if img.ndim == 3:
        # map_server averages colour channels (alpha ignored in trinary mode)
        img = img[..., :3].mean(axis=2).round().astype(np.uint8)
    return img


def _read_pgm(path: FsPath) -> np.ndarray:
    try:
        raw = read_bytes_capped(path)
    except ValueError as exc:
        raise MapError(str(exc)) from None
    magic = raw[:2]
    if magic not in (b"P2", b"P5"):
        raise MapError(f"{path}: not a PGM image (magic {magic!r}, expected b'P5' or b'P2')")
    # header: magic, width, height, maxval, separated by whitespace, '#' comments allowed
    fields: list[int] = []
    pos = 2
    while len(fields) < 3:
        while pos < len(raw) and raw[pos : pos + 1].isspace():
            pos += 1
        if pos < len(raw) and raw[pos : pos + 1] == b"#":
            while pos < len(raw) and raw[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < len(raw) and raw[pos : pos + 1].isdigit():
            pos += 1
        if start == pos:
            raise MapError(f"{path}: malformed PGM header (expected width, height, maxval)")
        fields.append(int(raw[start:pos]))
    width, height, maxval = fields
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise MapError(f"{path}: PGM header width={width} height={height} maxval={maxval}")
    if magic == b"P5":
        pos += 1  # exactly one whitespace byte before the raster
        dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
        need = width * height * dtype.itemsize
        body = raw[pos : pos + need]
        if len(body) != need:
            raise MapError(
                f"{path}: PGM raster truncated: {len(body)} of {need} bytes for {width}x{height}"
            )
        img = np.frombuffer(body, dtype=dtype).reshape(height, width)
    else:
        try:
            vals = np.array(raw[pos:].split(), dtype=np.int64)
        except ValueError as exc:
            raise MapError(f"{path}: PGM (P2) raster has a non-integer value") from exc
        if vals.size != width * height:
            raise MapError(f"{path}: PGM raster has {vals.size} values, expected {width * height}")
        img = vals.reshape(height, width)
    if maxval != 255:  # map_server thresholds assume 8-bit greys
        img = np.round(img.astype(float) * 255.0 / maxval)
    return img.astype(np.uint8)


def pixels_to_occupancy(
    pixels: np.ndarray,
    negate: int = 0,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.25,
    mode: str = "trinary",
) -> np.ndarray:
    """Convert image greys (top row first) to OccupancyGrid values (row 0 southmost).

    Follows nav2 ``map_io``: trinary gives 0/100/-1; scale maps the band between the
    thresholds linearly to 1..99; raw copies the value (anything over 100 is unknown).
    """
    v = pixels.astype(float)
    if mode == "raw":
        out = np.where(v <= 100, v, UNKNOWN)
    else:
        p = v / 255.0 if negate else (255.0 - v) / 255.0
        out = np.full(v.shape, UNKNOWN, dtype=float)
        out[p > occupied_thresh] = OCCUPIED
        out[p < free_thresh] = FREE
        if mode == "scale":
            band = (p >= free_thresh) & (p <= occupied_thresh)
            ratio = (p[band] - free_thresh) / (occupied_thresh - free_thresh)
            out[band] = 1 + np.round(98 * ratio)
    return out[::-1].astype(np.int8)


def inflate(occ_map: OccupancyMap, radius_m: float, unknown_is_occupied: bool = True) -> np.ndarray:
    """Cells where a disc of ``radius_m`` centred on the cell centre could touch an obstacle.

    An obstacle cell is a square of side ``resolution``; a cell is kept free only when
    the distance between its centre and the nearest obstacle cell's centre exceeds
    ``radius_m`` plus half the cell diagonal. That bound is conservative: every point of
    every obstacle square lies at least ``radius_m`` away from a free cell's centre, so
    a robot of that radius standing on a free cell's centre touches no obstacle.

    Args:
        occ_map: the map.
        radius_m: robot radius plus safety margin [m], >= 0.
        unknown_is_occupied: treat unknown cells as obstacles.

    Returns:
        (height, width) bool array, True where the robot's centre must not be.

    Raises:
        ValueError: negative radius.
    """
    if not radius_m >= 0:
        raise ValueError(f"inflation radius {radius_m!r} must be >= 0")
    occ = occ_map.occupied(unknown_is_occupied)
    if not occ.any():
        return occ.copy()
    res = occ_map.resolution_m
    dist_m = ndimage.distance_transform_edt(~occ) * res
    return dist_m <= radius_m + res * math.sqrt(0.5)


def disc_mask(occ_map: OccupancyMap, centres_xy: Any, radius_m: float) -> np.ndarray:
    """Cells whose centre lies within ``radius_m`` of any of the given map points.

    Used to stamp people (with the robot's radius added) onto the planning grid.
    """
    mask = np.zeros(occ_map.shape, dtype=bool)
    pts = np.asarray(centres_xy, dtype=float).reshape(-1, 2)
    if pts.size == 0:
        return mask
    res = occ_map.resolution_m
    n = int(math.ceil(radius_m / res)) + 1
    h, w = occ_map.shape
    for x, y in pts:
        r0, c0 = occ_map.world_to_cell(x, y)
        rows = np.arange(max(r0 - n, 0), min(r0 + n + 1, h))
        cols = np.arange(max(c0 - n, 0), min(c0 + n + 1, w))
        if rows.size == 0 or cols.size == 0:
            continue
        cy = occ_map.origin_m[1] + (rows + 0.5) * res
        cx = occ_map.origin_m[0] + (cols + 0.5) * res
        inside = (cy[:, None] - y) ** 2 + (cx[None, :] - x) ** 2 <= radius_m**2
        mask[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1] |= inside
    return mask
