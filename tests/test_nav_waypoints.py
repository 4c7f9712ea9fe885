"""Cell waypoints and the meaning of each action (thesis table 3.2)."""

import math

import pytest

from stack.cells import CellGrid, Direction
from stack.nav.waypoints import ActionOutcome, CellWaypoints, parse_action

GRID = CellGrid()  # 12 10 8 6 4 2 / 11 9 7 5 3 1, 1 m x 1.5 m cells
WP = CellWaypoints(GRID)


@pytest.mark.parametrize(
    "cell, action, expected",
    [(7, "North", 8), (8, "South", 7), (7, "East", 5), (7, "West", 9), (1, "West", 3)],
)
def test_move_action_targets_the_neighbours_waypoint(cell, action, expected):
    t = WP.target(cell, action)
    assert t.outcome is ActionOutcome.MOVE and t.cell == expected
    assert t.waypoint_m == GRID.center(expected)


def test_do_nothing_holds():
    t = WP.target(7, "Do nothing")
    assert t.outcome is ActionOutcome.HOLD and t.cell == 7 and t.waypoint_m is None


@pytest.mark.parametrize("cell", GRID.cells)
@pytest.mark.parametrize(
    "action", [Direction.NORTH, Direction.SOUTH, Direction.EAST, Direction.WEST]
)
def test_actions_leaving_the_map_are_refused(cell, action):
    t = WP.target(cell, action)
    leaves = GRID.neighbour(cell, action) is None
    assert (t.outcome is ActionOutcome.REFUSED) == leaves
    if leaves:
        assert t.cell == cell and t.waypoint_m is None
        assert f"from cell {cell} leaves the map" in t.reason


def test_parse_action_names_and_numbers():
    assert parse_action("  east ") is Direction.EAST
    assert parse_action("Do  Nothing") is Direction.NOT_MOVING
    assert parse_action(0) is Direction.NORTH
    assert parse_action("3") is Direction.WEST
    for bad in ("up", "", 7, True, None):
        with pytest.raises(ValueError, match="not"):
            parse_action(bad)


def test_cell_of_clamps_positions_outside_the_region():
    assert WP.cell_of(*GRID.center(7)) == 7
    assert WP.cell_of(100.0, -5.0) == 1  # far south-east: the south-east cell
    with pytest.raises(ValueError, match="not in the grid"):
        WP.target(13, "North")


def test_trip_commands_and_entry_points():
    from stack.nav.waypoints import entry_point
    from stack.vocabulary import parse_trip, trip_command

    assert parse_trip("To 1") == 1 and parse_trip(" to  12 ") == 12 and trip_command(3) == "To 3"
    assert parse_trip("East") is None and parse_trip("To") is None and parse_trip("To x") is None
    grid = CellGrid()  # cell 1: x 5-6, y 0-1.5
    assert entry_point(grid, 1, (3.5, 0.75)) == pytest.approx((5.35, 0.75))
    assert entry_point(grid, 1, (9.0, 9.0)) == pytest.approx((5.65, 1.15))
    # a person in the south of the cell: the nearest point 0.6 m from them, north-west
    x, y = entry_point(grid, 1, (3.5, 0.75), people=[(5.5, 0.5)])
    assert math.hypot(x - 5.5, y - 0.5) >= 0.6 and x < 5.45 and y > 1.0
    # nowhere clear (a person in the middle of the small cell): the farthest point
    x, y = entry_point(grid, 1, (3.5, 0.75), people=[(5.5, 0.75)], clearance_m=2.0)
    assert math.hypot(x - 5.5, y - 0.75) == pytest.approx(math.hypot(0.15, 0.4))  # a corner
    assert x == pytest.approx(5.35)  # of the two west ones, nearer the robot
