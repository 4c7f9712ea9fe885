"""A* on an occupancy grid: 8-connected, octile heuristic, no corner cutting.

Moves go to the 8 neighbouring cells; a straight move costs 1 cell, a diagonal one
sqrt(2). A diagonal move is allowed only when both cells it passes between are free too,
so the path never cuts the corner of an obstacle. The octile distance
``max(dr, dc) + (sqrt(2) - 1) * min(dr, dc)`` is the exact cost on an empty grid, hence
admissible, and it changes by at most the cost of any single move, hence consistent: a
node is final when first popped and the returned cost is optimal (Hart, Nilsson and
Raphael 1968, the global planner of thesis section 4.4).

The search runs on a flattened grid padded with a blocked border, so neighbour indices
are plain integer offsets and never wrap; heap entries are ``(f, h, index)`` so ties on
``f`` go to the node nearer the goal, which keeps expansions close to the path on open
floor. See docs/NAV.md for the measurements behind this choice over pyastar2d.
"""

from __future__ import annotations

import enum
import heapq
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from stack.nav.occupancy import OccupancyMap, inflate

SQRT2 = math.sqrt(2.0)
_OCTILE = SQRT2 - 1.0


class NoPathReason(enum.Enum):
    START_OUTSIDE = "start outside the map"
    GOAL_OUTSIDE = "goal outside the map"
    START_BLOCKED = "start inside an obstacle"
    GOAL_BLOCKED = "goal inside an obstacle"
    NO_CONNECTION = "no connection between start and goal"


class NoPathError(RuntimeError):
    """A* found no path; ``reason`` says why (a :class:`NoPathReason`)."""

    def __init__(self, reason: NoPathReason, start: tuple[int, int], goal: tuple[int, int]):
        self.reason, self.start, self.goal = reason, start, goal
        super().__init__(f"no path from cell {start} to cell {goal}: {reason.value}")


@dataclass(frozen=True, eq=False)
class GridPath:
    """A path as grid cells.

    Attributes:
        cells: (N, 2) int array of (row, col), start first, goal last; N >= 1.
        cost_cells: length in cell edges (straight 1, diagonal sqrt(2)).
    """

    cells: np.ndarray
    cost_cells: float


@dataclass(frozen=True, eq=False)
class Path:
    """A path in the map frame.

    Attributes:
        points_m: (N, 2) map positions (x, y) of the cell centres, start cell first [m].
        cells: (N, 2) grid cells (row, col) of the same points.
        cost_m: path length along the cell centres [m].
    """

    points_m: np.ndarray
    cells: np.ndarray
    cost_m: float

    def __len__(self) -> int:
        return len(self.points_m)


def reachable(blocked: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """The cells :func:`astar_grid` can reach from ``start`` on ``blocked``: a bool
    array of its shape, all False when ``start`` is outside or blocked. (Without corner
    cutting a diagonal move is two orthogonal ones, so this is the start's 4-connected
    free component.)"""
    blocked = np.asarray(blocked, dtype=bool)
    r, c = int(start[0]), int(start[1])
    h, w = blocked.shape
    if not (0 <= r < h and 0 <= c < w) or blocked[r, c]:
        return np.zeros_like(blocked)
    labels, _ = ndimage.label(~blocked)
    return labels == labels[r, c]


def astar_grid(blocked: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> GridPath:
    """Shortest 8-connected path on a boolean grid without corner cutting.

    Args:
        blocked: (height, width) bool array, True where the robot's centre may not be.
        start: (row, col) of the start cell.
        goal: (row, col) of the goal cell.

    Returns:
        The optimal path (a single cell when start == goal).

    Raises:
        NoPathError: start or goal outside the grid or blocked, or no connection.
        ValueError: ``blocked`` is not 2-D.
    """
    blocked = np.asarray(blocked, dtype=bool)
    if blocked.ndim != 2:
        raise ValueError(f"blocked grid must be 2-D, got shape {blocked.shape}")
    h, w = blocked.shape
    start = (int(start[0]), int(start[1]))
    goal = (int(goal[0]), int(goal[1]))
    for cell, out_reason, in_reason in (
        (start, NoPathReason.START_OUTSIDE, NoPathReason.START_BLOCKED),
        (goal, NoPathReason.GOAL_OUTSIDE, NoPathReason.GOAL_BLOCKED),
    ):
        if not (0 <= cell[0] < h and 0 <= cell[1] < w):
            raise NoPathError(out_reason, start, goal)
        if blocked[cell]:
            raise NoPathError(in_reason, start, goal)
    if start == goal:
        return GridPath(np.array([start], dtype=int), 0.0)

    W = w + 2
    padded = np.ones((h + 2, W), dtype=bool)
    padded[1:-1, 1:-1] = blocked
    free = (~padded).ravel().tolist()  # list indexing is much faster than numpy's here
    n = len(free)
    s = (start[0] + 1) * W + start[1] + 1
    g_idx = (goal[0] + 1) * W + goal[1] + 1
    gr, gc = divmod(g_idx, W)

    straight = (1, -1, W, -W)
    # (offset, side offset a, side offset b): both sides must be free (no corner cutting)
    diagonal = ((W + 1, W, 1), (W - 1, W, -1), (-W + 1, -W, 1), (-W - 1, -W, -1))

    inf = math.inf
    g = [inf] * n
    parent = [-1] * n
    closed = bytearray(n)
    g[s] = 0.0
    # the octile heuristic for every cell at once: one numpy pass beats a divmod per push
    rr = np.abs(np.arange(h + 2) - gr)[:, None]
    cc = np.abs(np.arange(W) - gc)[None, :]
    hlist = (np.maximum(rr, cc) + _OCTILE * np.minimum(rr, cc)).ravel().tolist()
    h0 = hlist[s]
    heap = [(h0, h0, s)]
    push, pop = heapq.heappush, heapq.heappop
    found = False
    while heap:
        _, _, u = pop(heap)
        if closed[u]:
            continue
        if u == g_idx:
            found = True
            break
        closed[u] = 1
        gu = g[u]
        for mv in straight:
            v = u + mv
            if free[v] and not closed[v]:
                gv = gu + 1.0
                if gv < g[v]:
                    g[v] = gv
                    parent[v] = u
                    hv = hlist[v]
                    push(heap, (gv + hv, hv, v))
        for mv, side_a, side_b in diagonal:
            v = u + mv
            if free[v] and free[u + side_a] and free[u + side_b] and not closed[v]:
                gv = gu + SQRT2
                if gv < g[v]:
                    g[v] = gv
                    parent[v] = u
                    hv = hlist[v]
                    push(heap, (gv + hv, hv, v))
    if not found:
        raise NoPathError(NoPathReason.NO_CONNECTION, start, goal)
    idx = [g_idx]
    while idx[-1] != s:
        idx.append(parent[idx[-1]])
    idx.reverse()
    rows, cols = np.divmod(np.asarray(idx, dtype=np.int64), W)
    cells = np.column_stack((rows - 1, cols - 1))
    return GridPath(cells, float(g[g_idx]))


def plan(
    occ_map: OccupancyMap,
    start_xy: tuple[float, float],
    goal_xy: tuple[float, float],
    blocked: np.ndarray | None = None,
    inflation_radius_m: float = 0.0,
) -> Path:
    """Plan between two map points on an occupancy map.

    Args:
        occ_map: the map (placement and resolution).
        start_xy: start position in the map frame [m].
        goal_xy: goal position in the map frame [m].
        blocked: a precomputed planning grid (e.g. the inflated map plus people); when
            None the map is inflated by ``inflation_radius_m`` here.
        inflation_radius_m: robot radius plus margin [m], used only when ``blocked`` is None.

    Returns:
        The optimal path through cell centres. Its first point is the start cell's centre
        and its last the goal cell's centre; a follower steers to ``goal_xy`` itself at
        the end.

    Raises:
        NoPathError: see :func:`astar_grid`.
    """
    if blocked is None:
        blocked = inflate(occ_map, inflation_radius_m)
    elif blocked.shape != occ_map.shape:
        raise ValueError(f"blocked grid shape {blocked.shape} differs from map {occ_map.shape}")
    grid_path = astar_grid(
        blocked, occ_map.world_to_cell(*start_xy), occ_map.world_to_cell(*goal_xy)
    )
    return Path(
        points_m=occ_map.cells_to_world(grid_path.cells),
        cells=grid_path.cells,
        cost_m=grid_path.cost_cells * occ_map.resolution_m,
    )


def path_cost_cells(cells: np.ndarray) -> float:
    """Length of a cell path in cell edges (for checks: 1 per straight, sqrt(2) per diagonal)."""
    d = np.abs(np.diff(np.asarray(cells), axis=0))
    if d.size and (d.max() > 1 or (d.sum(axis=1) == 0).any()):
        raise ValueError("consecutive cells must be distinct 8-neighbours")
    diag = (d.sum(axis=1) == 2).sum() if d.size else 0
    return float(len(d) - diag + SQRT2 * diag)
