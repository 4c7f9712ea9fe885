"""From the planner's action to a navigation goal: one waypoint per cell.

Thesis 3.2.2 (table 3.2): the actions are North, South, East, West and Do nothing; a
move action takes the robot to the adjacent cell's waypoint (section 4.4), Do nothing
holds. The POMDP penalises leaving the map, so the planner should never choose such a
move; if it does, the action is refused here and the robot does not move.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass

from stack.cells import CellGrid, Direction
from stack.vocabulary import TRIP_INSET_M

_ACTION_NAMES = {
    "north": Direction.NORTH,
    "n": Direction.NORTH,
    "south": Direction.SOUTH,
    "s": Direction.SOUTH,
    "east": Direction.EAST,
    "e": Direction.EAST,
    "west": Direction.WEST,
    "w": Direction.WEST,
    "do nothing": Direction.NOT_MOVING,
    "donothing": Direction.NOT_MOVING,
    "do_nothing": Direction.NOT_MOVING,
    "not moving": Direction.NOT_MOVING,
    "not_moving": Direction.NOT_MOVING,
    "nothing": Direction.NOT_MOVING,
    "hold": Direction.NOT_MOVING,
    "stay": Direction.NOT_MOVING,
}


def parse_action(value: str | int) -> Direction:
    """Read an action as the planner sends it.

    Args:
        value: a name ("North", "east", "Do nothing", "N", ...) or the
            :class:`~stack.cells.Direction` integer (0 North .. 4 Do nothing).

    Returns:
        The action as a Direction (``NOT_MOVING`` is Do nothing).

    Raises:
        ValueError: the value names no action.
    """
    if isinstance(value, bool):
        raise ValueError(f"action {value!r} is not an action name or number")
    if isinstance(value, int):
        try:
            return Direction(value)
        except ValueError:
            raise ValueError(
                f"action number {value} is not one of {[int(d) for d in Direction]}"
            ) from None
    if isinstance(value, str):
        key = " ".join(value.strip().lower().split())
        if key in _ACTION_NAMES:
            return _ACTION_NAMES[key]
        if key.lstrip("-").isdigit():
            return parse_action(int(key))
    raise ValueError(
        f"action {value!r} is not one of North, South, East, West, Do nothing (or 0..4)"
    )


class ActionOutcome(enum.Enum):
    MOVE = "move"  # drive to the neighbouring cell's waypoint
    HOLD = "hold"  # Do nothing: stay where you are
    REFUSED = "refused"  # the move would leave the map: no motion


@dataclass(frozen=True)
class ActionTarget:
    """What an action means for the base.

    Attributes:
        outcome: move, hold or refused.
        action: the action.
        from_cell: the cell the robot is in.
        cell: the target cell (``from_cell`` for hold and refused).
        waypoint_m: map position (x, y) to drive to; None unless ``outcome`` is MOVE.
        reason: why the action was refused ("" otherwise).
    """

    outcome: ActionOutcome
    action: Direction
    from_cell: int
    cell: int
    waypoint_m: tuple[float, float] | None
    reason: str = ""


class CellWaypoints:
    """One waypoint per cell (the cell's centre), and the meaning of each action.

    Args:
        grid: the shared cell geometry.
    """

    def __init__(self, grid: CellGrid):
        self.grid = grid

    def waypoint(self, cell: int) -> tuple[float, float]:
        """Map position of a cell's waypoint [m].

        Raises:
            ValueError: the cell is not in the grid.
        """
        return self.grid.center(cell)

    def cell_of(self, x: float, y: float) -> int:
        """The cell the robot at (x, y) is in, or the nearest cell when it is outside."""
        cell = self.grid.cell_at(x, y)
        if cell is not None:
            return cell
        x0, y0 = self.grid.origin_m
        w, h = self.grid.size_m
        eps = 1e-9
        return self.grid.cell_at(min(max(x, x0), x0 + w - eps), min(max(y, y0), y0 + h - eps))  # type: ignore[return-value]

    def target(self, cell: int, action: Direction | str | int) -> ActionTarget:
        """The navigation target for ``action`` taken in ``cell``.

        Args:
            cell: the robot's current cell.
            action: the planner's action (parsed with :func:`parse_action` if not a Direction).

        Returns:
            MOVE with the neighbour's waypoint, HOLD for Do nothing, or REFUSED when the
            move would leave the map.

        Raises:
            ValueError: unknown cell or action.
        """
        action = action if isinstance(action, Direction) else parse_action(action)
        self.grid.rowcol(cell)  # validates the cell
        if action is Direction.NOT_MOVING:
            return ActionTarget(ActionOutcome.HOLD, action, cell, cell, None)
        nxt = self.grid.neighbour(cell, action)
        if nxt is None:
            return ActionTarget(
                ActionOutcome.REFUSED,
                action,
                cell,
                cell,
                None,
                f"{action.label} from cell {cell} leaves the map",
            )
        return ActionTarget(ActionOutcome.MOVE, action, cell, nxt, self.grid.center(nxt))


def entry_point(
    grid: CellGrid,
    cell: int,
    from_xy: tuple[float, float],
    people: Sequence[tuple[float, float]] = (),
    inset_m: float = TRIP_INSET_M,
    clearance_m: float = 0.6,
    step_m: float = 0.05,
) -> tuple[float, float]:
    """Where a trip into ``cell`` ends: the point of the cell ``inset_m`` inside its
    borders nearest ``from_xy`` among those at least ``clearance_m`` from every person
    (the cell is the target, not the person's spot: the robot enters where they are
    not); with no such point, the one farthest from the people.

    Raises:
        ValueError: the cell is not in the grid.
    """
    nearest = grid.nearest_inside(cell, from_xy[0], from_xy[1], inset_m)

    def room(x: float, y: float) -> float:  # distance to the nearest person, capped
        return min([clearance_m, *(math.hypot(x - px, y - py) for px, py in people)])

    if room(*nearest) >= clearance_m:
        return nearest
    x0, y0, x1, y1 = grid.bounds(cell)
    lo_x, lo_y = grid.nearest_inside(cell, x0, y0, inset_m)
    hi_x, hi_y = grid.nearest_inside(cell, x1, y1, inset_m)
    nx = max(1, round((hi_x - lo_x) / step_m))
    ny = max(1, round((hi_y - lo_y) / step_m))
    points = [
        (lo_x + (hi_x - lo_x) * i / nx, lo_y + (hi_y - lo_y) * j / ny)
        for i in range(nx + 1)
        for j in range(ny + 1)
    ]
    return min(points, key=lambda p: (-round(room(*p), 6), math.dist(p, from_xy)))
