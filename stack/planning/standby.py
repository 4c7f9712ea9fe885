"""Where a guard waits (issue 26): trip lengths, the rest cell, expected lateness.

A guard is judged by how much later than the person it reaches a restricted cell.
Waiting in cell w, its trip into restricted cell c takes ``trip_s[c][w]`` seconds; a
person heading for c is predicted to enter in ``eta`` seconds; the robot is late by
``max(0, trip - eta)``. Weighted by how likely each cell is the person's goal, that is
the *expected lateness* of waiting in w (:func:`expected_lateness`), which the
anticipation layer (:mod:`stack.planning.anticipate`) minimises while a person is seen.

With the room empty the guard waits in the task's rest cell. ``rest_cell: auto`` is
:func:`watch_cell`: with the room's exits known, the cell whose expected lateness is
least for a person who has just come in at an exit (:func:`entry_lateness`); without
them, the cell whose longest trip to a restricted cell is shortest.

Pure: geometry on :class:`stack.cells.CellGrid`.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Iterable, Mapping, Sequence

from stack.cells import MOVING_DIRECTIONS, CellGrid
from stack.planning.intent import IntentEstimate
from stack.vocabulary import TRIP_INSET_M

# Walking speeds a person who has just come in is assumed to walk at, evenly from the
# goal inference's slowest forecast (``IntentConfig.eta_min_speed_mps``, 0.5 m/s) to
# the walking speed industrial safety designs for (ISO 13855: 1.6 m/s).
ENTRY_SPEEDS_MPS = tuple(0.5 + 0.1 * k for k in range(12))


def travel_m(grid: CellGrid, start: int) -> dict[int, float]:
    """The length (m, centre to centre) of the shortest path of cell moves from
    ``start`` to every cell of ``grid`` (Dijkstra: cells may be oblong)."""
    dist = {start: 0.0}
    queue = [(0.0, start)]
    while queue:
        d, c = heapq.heappop(queue)
        if d > dist[c]:
            continue
        (x0, y0) = grid.center(c)
        for direction in MOVING_DIRECTIONS:
            n = grid.neighbour(c, direction)
            if n is None:
                continue
            x1, y1 = grid.center(n)
            nd = d + math.hypot(x1 - x0, y1 - y0)
            if nd < dist.get(n, math.inf):
                dist[n] = nd
                heapq.heappush(queue, (nd, n))
    return dist


def trip_lengths(grid: CellGrid, cell: int, motion: str = "trip") -> dict[int, float]:
    """The robot's trip length (m) from every cell's centre into ``cell``: cell moves
    centre to centre (``motion: cells``), or a trip straight to the nearest point
    ``TRIP_INSET_M`` inside (``trip``)."""
    if motion == "cells":
        return travel_m(grid, cell)
    out = {}
    for c in grid.cells:
        x, y = grid.center(c)
        out[c] = math.dist((x, y), grid.nearest_inside(cell, x, y, TRIP_INSET_M))
    return out


def trip_times(
    grid: CellGrid, restricted_cells: Iterable[int], speed_mps: float, motion: str = "trip"
) -> dict[int, dict[int, float]]:
    """``trip_s[c][w]``: the robot's trip time (s) from cell ``w`` into each restricted
    cell ``c`` at ``speed_mps`` (moves are symmetric)."""
    return {
        r: {c: m / speed_mps for c, m in trip_lengths(grid, r, motion).items()}
        for r in restricted_cells
    }


def expected_lateness(
    trip_s: Mapping[int, Mapping[int, float]], estimates: Sequence[IntentEstimate], cell: int
) -> float:
    """The robot's expected lateness (s) waiting in ``cell``: over the people's goal
    beliefs (``estimates``) and the restricted cells c, P(goal = c) times how much
    later than the person's predicted entry the robot's trip from ``cell`` into c
    (``trip_s[c][cell]``, s) would arrive, or nothing when it arrives first."""
    total = 0.0
    for est in estimates:
        for f in est.forecasts:
            late = trip_s[f.cell].get(cell, math.inf) - f.eta_s
            if late > 0 and f.probability > 0:
                total += f.probability * late
    return total


def entry_lateness(
    grid: CellGrid,
    trip_s: Mapping[int, Mapping[int, float]],
    exits: Sequence[tuple[float, float]],
    cell: int,
    speeds_mps: Sequence[float] = ENTRY_SPEEDS_MPS,
) -> float:
    """The expected lateness (s) of waiting in ``cell`` for a person who has just come
    in at one of ``exits`` (map points), heading for any restricted cell of ``trip_s``
    alike, straight at one of ``speeds_mps`` alike: the mean of how much later than
    the person the robot's trip from ``cell`` reaches their cell."""
    total, n = 0.0, 0
    for ex, ey in exits:
        for c, trips in trip_s.items():
            dist = math.dist((ex, ey), grid.nearest_inside(c, ex, ey, 0.0))
            trip = trips.get(cell, math.inf)
            for v in speeds_mps:
                total += max(0.0, trip - dist / v)
                n += 1
    return total / n if n else 0.0


def watch_cell(
    grid: CellGrid,
    restricted_cells: tuple[int, ...],
    exits: Sequence[tuple[float, float]] = (),
    speed_mps: float = 0.4,
    motion: str = "trip",
) -> int:
    """Where a guard waits (a task's ``rest_cell: auto``), among the cells not
    restricted: with the room's ``exits``, the cell of least :func:`entry_lateness` at
    the robot's trip ``speed_mps`` (in task r2 the door is beside cell 1: a person
    coming in reaches it in seconds, cell 12 only after crossing the room); then, and
    without exits, the cell whose longest trip to a restricted cell is shortest (the
    thesis's rest cell 7 is "equidistant" from task r2's cells 1 and 12), the shorter
    trips in total, the lowest cell number. With one restricted cell that is its
    nearest neighbour: a guard waiting there is one move from the cell, not three."""
    trips = {r: travel_m(grid, r) for r in restricted_cells}
    candidates = [c for c in grid.cells if c not in trips]
    if not candidates:
        raise ValueError("every cell is restricted: nowhere to wait")
    trip_s = trip_times(grid, restricted_cells, speed_mps, motion) if exits else {}

    def cost(c: int) -> tuple[float, float, float, int]:
        late = entry_lateness(grid, trip_s, exits, c) if exits else 0.0
        ds = [trips[r].get(c, math.inf) for r in restricted_cells]
        return (round(late, 3), round(max(ds), 9), round(sum(ds), 9), c)

    return min(candidates, key=cost)
