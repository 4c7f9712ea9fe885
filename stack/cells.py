"""The cell geometry shared by planning, perception and navigation.

The thesis (section 4.2, figure 4.5) divides the experiment region into cells
numbered ``12 10 8 6 4 2 / 11 9 7 5 3 1`` (north up, east right). The planner
only needs the topology (which cell is north of which); perception and
navigation also need the metric geometry (where a cell lies on the floor map).
Both live here, read from the ``grid`` section of a task file, so that every
component agrees on what "cell 7" means.

Map frame: x points east, y points north, units are metres. ``origin_m`` is the
map position of the region's south-west corner.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any


class ConfigError(ValueError):
    """A configuration value breaks a rule; the message names key, value and rule."""

    def __init__(self, key: str, value: Any, rule: str):
        self.key, self.value, self.rule = key, value, rule
        super().__init__(f"{key}: {value!r} is invalid: {rule}")


class Direction(enum.IntEnum):
    """A person's movement direction (table 3.1) and the robot's move actions (table 3.2)."""

    NORTH = 0
    SOUTH = 1
    EAST = 2
    WEST = 3
    NOT_MOVING = 4

    @property
    def opposite(self) -> Direction:
        return _OPPOSITE[self]

    @property
    def step(self) -> tuple[int, int]:
        """(d_row, d_col) of one step in this direction; rows grow southwards."""
        return _STEP[self]

    @property
    def label(self) -> str:
        return self.name.replace("_", " ").capitalize()


MOVING_DIRECTIONS = (Direction.NORTH, Direction.SOUTH, Direction.EAST, Direction.WEST)
_OPPOSITE = {
    Direction.NORTH: Direction.SOUTH,
    Direction.SOUTH: Direction.NORTH,
    Direction.EAST: Direction.WEST,
    Direction.WEST: Direction.EAST,
    Direction.NOT_MOVING: Direction.NOT_MOVING,
}
_STEP = {
    Direction.NORTH: (-1, 0),
    Direction.SOUTH: (1, 0),
    Direction.EAST: (0, 1),
    Direction.WEST: (0, -1),
    Direction.NOT_MOVING: (0, 0),
}

THESIS_NUMBERING = ((12, 10, 8, 6, 4, 2), (11, 9, 7, 5, 3, 1))


@dataclass(frozen=True)
class CellGrid:
    """A rectangular grid of numbered cells laid on the floor map.

    Attributes:
        numbering: cell numbers row by row, the first row northmost, each row west to east.
        cell_size_m: (width along x/east, height along y/north) of one cell [m].
        origin_m: map position of the region's south-west corner [m].
    """

    numbering: tuple[tuple[int, ...], ...] = THESIS_NUMBERING
    cell_size_m: tuple[float, float] = (1.0, 1.5)
    origin_m: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        rows = self.numbering
        if not rows or not rows[0]:
            raise ConfigError("grid.numbering", rows, "needs at least one row and one column")
        width = len(rows[0])
        for i, row in enumerate(rows):
            if len(row) != width:
                raise ConfigError(
                    f"grid.numbering[{i}]", list(row), f"every row needs {width} cells"
                )
        flat = [c for row in rows for c in row]
        if sorted(flat) != list(range(1, len(flat) + 1)):
            raise ConfigError(
                "grid.numbering",
                [list(r) for r in rows],
                f"must number the cells 1..{len(flat)} once each",
            )
        for i, v in enumerate(self.cell_size_m):
            if not v > 0:
                raise ConfigError(f"grid.cell_size_m[{i}]", v, "must be > 0")
        if len(self.cell_size_m) != 2 or len(self.origin_m) != 2:
            raise ConfigError("grid", (self.cell_size_m, self.origin_m), "sizes and origin are 2-D")
        index = {c: (r, k) for r, row in enumerate(rows) for k, c in enumerate(row)}
        object.__setattr__(self, "_rowcol", index)

    # -- topology ---------------------------------------------------------
    @property
    def rows(self) -> int:
        return len(self.numbering)

    @property
    def columns(self) -> int:
        return len(self.numbering[0])

    @property
    def n_cells(self) -> int:
        return self.rows * self.columns

    @property
    def cells(self) -> tuple[int, ...]:
        """All cell numbers in ascending order: 1..p."""
        return tuple(range(1, self.n_cells + 1))

    def rowcol(self, cell: int) -> tuple[int, int]:
        """(row, column) of a cell; row 0 is the northmost row, column 0 the westmost."""
        try:
            return self._rowcol[cell]  # type: ignore[attr-defined]
        except KeyError:
            raise ValueError(f"cell {cell!r} is not in the grid (1..{self.n_cells})") from None

    def cell_at_rowcol(self, row: int, col: int) -> int | None:
        if 0 <= row < self.rows and 0 <= col < self.columns:
            return self.numbering[row][col]
        return None

    def neighbour(self, cell: int, direction: Direction) -> int | None:
        """The cell one step from ``cell`` in ``direction``; None when that leaves the grid."""
        r, c = self.rowcol(cell)
        dr, dc = direction.step
        return self.cell_at_rowcol(r + dr, c + dc)

    def chebyshev(self, a: int, b: int) -> int:
        """Grid distance counting diagonal neighbours as adjacent (thesis 5.2.1: 9-11 adjoin 12)."""
        (ra, ca), (rb, cb) = self.rowcol(a), self.rowcol(b)
        return max(abs(ra - rb), abs(ca - cb))

    def manhattan(self, a: int, b: int) -> int:
        """Number of robot moves between two cells (the robot moves N/S/E/W only)."""
        (ra, ca), (rb, cb) = self.rowcol(a), self.rowcol(b)
        return abs(ra - rb) + abs(ca - cb)

    # -- metric geometry --------------------------------------------------
    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the whole region [m]."""
        return (self.columns * self.cell_size_m[0], self.rows * self.cell_size_m[1])

    def bounds(self, cell: int) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of a cell in the map frame [m]."""
        r, c = self.rowcol(cell)
        w, h = self.cell_size_m
        x0 = self.origin_m[0] + c * w
        y0 = self.origin_m[1] + (self.rows - 1 - r) * h
        return (x0, y0, x0 + w, y0 + h)

    def center(self, cell: int) -> tuple[float, float]:
        """Map position of a cell's centre [m]: the robot's waypoint for that cell."""
        x0, y0, x1, y1 = self.bounds(cell)
        return ((x0 + x1) / 2.0, (y0 + y1) / 2.0)

    def nearest_inside(
        self, cell: int, x: float, y: float, inset_m: float = 0.0
    ) -> tuple[float, float]:
        """The point of ``cell``, ``inset_m`` inside its borders, nearest map point
        (x, y) (a cell narrower than twice the inset: its middle line) [m]."""
        x0, y0, x1, y1 = self.bounds(cell)
        lo_x, hi_x = (x0 + inset_m, x1 - inset_m) if x1 - x0 > 2 * inset_m else ((x0 + x1) / 2,) * 2
        lo_y, hi_y = (y0 + inset_m, y1 - inset_m) if y1 - y0 > 2 * inset_m else ((y0 + y1) / 2,) * 2
        return (min(max(x, lo_x), hi_x), min(max(y, lo_y), hi_y))

    def cell_at(self, x: float, y: float) -> int | None:
        """The cell containing map point (x, y); None outside the region."""
        w, h = self.cell_size_m
        fx = (x - self.origin_m[0]) / w
        fy = (y - self.origin_m[1]) / h
        if not (0.0 <= fx < self.columns and 0.0 <= fy < self.rows):
            return None
        col = int(fx)
        row = self.rows - 1 - int(fy)
        return self.numbering[row][col]

    def cell_near(self, x: float, y: float, margin_m: float) -> int | None:
        """:meth:`cell_at`, or for a point within ``margin_m`` outside the region the
        nearest cell (a foot point just past the edge); None further out."""
        cell = self.cell_at(x, y)
        if cell is not None or margin_m <= 0:
            return cell
        x0, y0 = self.origin_m
        w, h = self.size_m
        cx, cy = min(max(x, x0), x0 + w - 1e-6), min(max(y, y0), y0 + h - 1e-6)
        if math.hypot(x - cx, y - cy) > margin_m:
            return None
        return self.cell_at(cx, cy)

    # -- construction -----------------------------------------------------
    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], key: str = "grid") -> CellGrid:
        """Build from a task file's ``grid`` section, validating every field."""
        if not isinstance(data, Mapping):
            raise ConfigError(key, data, "must be a mapping")
        known = {"rows", "columns", "numbering", "cell_size_m", "origin_m"}
        for k in data:
            if k not in known:
                raise ConfigError(f"{key}.{k}", data[k], f"unknown key (known: {sorted(known)})")
        numbering = data.get("numbering")
        rows, cols = data.get("rows"), data.get("columns")
        if numbering is None:
            rows = _positive_int(f"{key}.rows", 2 if rows is None else rows)
            cols = _positive_int(f"{key}.columns", 6 if cols is None else cols)
            numbering = default_numbering(rows, cols)
        else:
            if not isinstance(numbering, Sequence) or not all(
                isinstance(r, Sequence) and not isinstance(r, str) for r in numbering
            ):
                raise ConfigError(
                    f"{key}.numbering", numbering, "must be a list of rows of cell numbers"
                )
            numbering = tuple(
                tuple(_positive_int(f"{key}.numbering", c) for c in r) for r in numbering
            )
            if rows is not None and _positive_int(f"{key}.rows", rows) != len(numbering):
                raise ConfigError(f"{key}.rows", rows, f"numbering has {len(numbering)} rows")
            if cols is not None and _positive_int(f"{key}.columns", cols) != len(numbering[0]):
                raise ConfigError(
                    f"{key}.columns", cols, f"numbering has {len(numbering[0])} columns"
                )
        size = _pair(f"{key}.cell_size_m", data.get("cell_size_m", (1.0, 1.5)))
        origin = _pair(f"{key}.origin_m", data.get("origin_m", (0.0, 0.0)))
        return cls(numbering=numbering, cell_size_m=size, origin_m=origin)


def first_move(grid: CellGrid, start: int, goal: int) -> str | None:
    """The first action ("North", ...) of a shortest path of cell moves from ``start``
    to ``goal`` (ties: the order of :data:`MOVING_DIRECTIONS`); None when there."""
    if start == goal:
        return None
    first: dict[int, str] = {start: ""}
    queue = deque([start])
    while queue:
        c = queue.popleft()
        for d in MOVING_DIRECTIONS:
            n = grid.neighbour(c, d)
            if n is None or n in first:
                continue
            first[n] = first[c] or d.label
            if n == goal:
                return first[n]
            queue.append(n)
    return None


def default_numbering(rows: int, cols: int) -> tuple[tuple[int, ...], ...]:
    """The thesis's numbering generalised: columns numbered from the east, south row first.

    For 2 x 6 this gives ``12 10 8 6 4 2 / 11 9 7 5 3 1``.
    """
    grid = [[0] * cols for _ in range(rows)]
    n = 1
    for c in range(cols - 1, -1, -1):
        for r in range(rows - 1, -1, -1):
            grid[r][c] = n
            n += 1
    return tuple(tuple(r) for r in grid)


def _positive_int(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(key, value, "must be a positive integer")
    return value


def _pair(key: str, value: Any) -> tuple[float, float]:
    if (
        not isinstance(value, Sequence)
        or isinstance(value, str)
        or len(value) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise ConfigError(key, value, "must be a pair of numbers")
    return (float(value[0]), float(value[1]))
