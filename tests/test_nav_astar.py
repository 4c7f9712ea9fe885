"""A*: optimal against a Dijkstra reference, no corner cutting, NoPathError cases."""

import math

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from stack.nav.astar import (
    NoPathError,
    NoPathReason,
    astar_grid,
    path_cost_cells,
    plan,
    reachable,
)
from stack.nav.occupancy import OCCUPIED, OccupancyMap


def dijkstra_cost(blocked: np.ndarray, start, goal) -> float:
    """Reference: scipy's Dijkstra on the same 8-connected, no-corner-cutting graph."""
    h, w = blocked.shape
    idx = np.arange(h * w).reshape(h, w)
    rows, cols, costs = [], [], []
    for dr, dc in [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]:
        for r in range(h):
            for c in range(w):
                r2, c2 = r + dr, c + dc
                if not (0 <= r2 < h and 0 <= c2 < w) or blocked[r, c] or blocked[r2, c2]:
                    continue
                if dr and dc and (blocked[r, c2] or blocked[r2, c]):
                    continue
                rows.append(idx[r, c])
                cols.append(idx[r2, c2])
                costs.append(math.sqrt(2) if dr and dc else 1.0)
    graph = coo_matrix((costs, (rows, cols)), shape=(h * w, h * w)).tocsr()
    return float(dijkstra(graph, indices=idx[start])[idx[goal]])


def check_path(blocked, path, start, goal):
    cells = path.cells
    assert tuple(cells[0]) == tuple(start) and tuple(cells[-1]) == tuple(goal)
    assert not blocked[cells[:, 0], cells[:, 1]].any()
    steps = np.diff(cells, axis=0)
    assert (np.abs(steps).max(axis=1) == 1).all()  # 8-neighbours, no repeats
    for (r, c), (dr, dc) in zip(cells[:-1], steps, strict=True):
        if dr and dc:  # a diagonal passes between two free cells: no corner cutting
            assert not blocked[r + dr, c] and not blocked[r, c + dc]
    assert path.cost_cells == pytest.approx(path_cost_cells(cells))


@pytest.mark.parametrize("seed", range(12))
def test_astar_cost_matches_dijkstra_on_random_grids(seed):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(8, 25, size=2)
    blocked = rng.random((h, w)) < rng.uniform(0.1, 0.4)
    free = np.argwhere(~blocked)
    start, goal = (tuple(free[i]) for i in rng.choice(len(free), size=2, replace=False))
    ref = dijkstra_cost(blocked, start, goal)
    if math.isinf(ref):
        with pytest.raises(NoPathError) as err:
            astar_grid(blocked, start, goal)
        assert err.value.reason is NoPathReason.NO_CONNECTION
    else:
        path = astar_grid(blocked, start, goal)
        assert path.cost_cells == pytest.approx(ref, abs=1e-9)
        check_path(blocked, path, start, goal)


def test_no_corner_cutting_between_diagonal_obstacles():
    # two obstacles touching at a corner: the diagonal gap between them is closed
    blocked = np.zeros((4, 4), dtype=bool)
    blocked[1, 2] = blocked[2, 1] = True
    path = astar_grid(blocked, (2, 2), (1, 1))
    assert path.cost_cells == pytest.approx(6.0)  # around an arm: 2 + 2 + 2, no diagonal fits
    assert path.cost_cells == pytest.approx(dijkstra_cost(blocked, (2, 2), (1, 1)))
    check_path(blocked, path, (2, 2), (1, 1))
    # a fully closed anti-diagonal wall with only corner contacts is impassable
    wall = np.fliplr(np.eye(5, dtype=bool))
    with pytest.raises(NoPathError, match="no connection"):
        astar_grid(wall, (0, 0), (4, 4))


def test_open_grid_diagonal_cost_is_octile():
    path = astar_grid(np.zeros((10, 20), dtype=bool), (0, 0), (9, 19))
    assert path.cost_cells == pytest.approx(10 + 9 * math.sqrt(2))


@pytest.mark.parametrize(
    "start, goal, reason",
    [
        ((0, 0), (1, 1), NoPathReason.GOAL_BLOCKED),
        ((1, 1), (4, 4), NoPathReason.START_BLOCKED),
        ((-1, 0), (4, 4), NoPathReason.START_OUTSIDE),
        ((4, 4), (4, 9), NoPathReason.GOAL_OUTSIDE),
    ],
)
def test_no_path_error_for_bad_endpoints(start, goal, reason):
    blocked = np.zeros((5, 5), dtype=bool)
    blocked[1, 1] = True
    with pytest.raises(NoPathError) as err:
        astar_grid(blocked, start, goal)
    assert err.value.reason is reason
    assert reason.value in str(err.value)


def test_no_path_error_when_disconnected():
    blocked = np.zeros((6, 6), dtype=bool)
    blocked[:, 3] = True
    with pytest.raises(NoPathError) as err:
        astar_grid(blocked, (0, 0), (5, 5))
    assert err.value.reason is NoPathReason.NO_CONNECTION


def test_start_equals_goal_is_a_one_cell_path():
    path = astar_grid(np.zeros((3, 3), dtype=bool), (1, 1), (1, 1))
    assert path.cells.tolist() == [[1, 1]] and path.cost_cells == 0.0


def test_plan_in_map_coordinates_goes_around_a_wall():
    data = np.zeros((60, 80), dtype=np.int8)  # 4 m x 3 m at 5 cm
    data[:45, 40] = OCCUPIED  # a wall from the south edge, open at the north
    m = OccupancyMap(data, 0.05, (-1.0, -0.5))
    path = plan(m, (0.0, 0.0), (2.5, 0.0), inflation_radius_m=0.2)
    assert path.points_m[0] == pytest.approx(m.cell_to_world(*m.world_to_cell(0.0, 0.0)))
    assert path.points_m[-1] == pytest.approx((2.5, 0.0), abs=0.05)
    wall_x = -1.0 + 40.5 * 0.05
    crossing = path.points_m[np.argmin(np.abs(path.points_m[:, 0] - wall_x))]
    assert crossing[1] > -0.5 + 45 * 0.05 + 0.2  # passes north of the wall's end, inflated
    seg = np.hypot(*np.diff(path.points_m, axis=0).T).sum()
    assert path.cost_m == pytest.approx(seg)
    with pytest.raises(NoPathError, match="goal inside an obstacle"):
        plan(m, (0.0, 0.0), (wall_x, 0.0), inflation_radius_m=0.2)


def test_reachable_is_what_astar_can_reach_from_the_start():
    blocked = np.zeros((5, 7), dtype=bool)
    blocked[:, 3] = True  # a wall down the middle
    blocked[2, 3] = False  # with a one-cell gap
    blocked[0, 1] = blocked[1, 0] = True  # the corner cell (0, 0) only diagonally open
    region = reachable(blocked, (4, 0))
    for cell in np.ndindex(blocked.shape):
        try:
            astar_grid(blocked, (4, 0), cell)
            ok = True
        except NoPathError:
            ok = False
        assert region[cell] == ok, cell
    assert not region[0, 0] and region[0, 6]  # no corner cutting; through the gap
    assert not reachable(blocked, (0, 3)).any()  # from a blocked cell: nothing
    assert not reachable(blocked, (9, 9)).any()  # from outside: nothing
