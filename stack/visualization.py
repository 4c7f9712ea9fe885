"""What RViz and Foxglove draw of a run: markers of the grid, the restricted cells, the
belief and the people (issue 14). Pure data: no rclpy.

:func:`scene_markers` returns :class:`MarkerSpec` values whose fields are those of
``visualization_msgs/Marker`` (a node copies them into messages and publishes a
``MarkerArray``). Markers are grouped by namespace so that a viewer can toggle them:

- ``grid``: one outlined square per cell, ``LINE_STRIP``, grey;
- ``restricted``: the restricted cells filled red, translucent;
- ``cell_labels``: the cell numbers (``TEXT_VIEW_FACING``);
- ``belief``: each cell filled blue with opacity proportional to P(person in the cell)
  (the most likely cell at full opacity), and a text marker with P(no person);
- ``people``: a cylinder per detected person (position in the map frame);
- ``robot_cell``: the robot's most likely cell outlined green.

Ids are stable per namespace and cell, so that a viewer replaces a marker instead of
piling up copies; every marker lives in the ``map`` frame, z = 0 (the floor).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from stack.cells import CellGrid
from stack.vocabulary import NO_PERSON

# visualization_msgs/Marker type and action constants
CUBE, CYLINDER, LINE_STRIP, TEXT_VIEW_FACING = 1, 3, 4, 9
ADD, DELETEALL = 0, 3
FRAME = "map"

Colour = tuple[float, float, float, float]  # r, g, b, a in [0, 1]
GREY: Colour = (0.6, 0.6, 0.6, 1.0)
RED: Colour = (0.9, 0.1, 0.1, 0.35)
BLUE: Colour = (0.1, 0.3, 0.9, 1.0)
GREEN: Colour = (0.1, 0.8, 0.2, 1.0)
WHITE: Colour = (1.0, 1.0, 1.0, 1.0)
ORANGE: Colour = (1.0, 0.6, 0.0, 0.9)


@dataclass(frozen=True)
class MarkerSpec:
    """The fields of one ``visualization_msgs/Marker`` (map frame)."""

    ns: str
    id: int
    type: int
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    colour: Colour = GREY
    points: tuple[tuple[float, float, float], ...] = field(default=())
    text: str = ""
    action: int = ADD
    frame_id: str = FRAME


def _outline(grid: CellGrid, cell: int, z: float) -> tuple[tuple[float, float, float], ...]:
    x0, y0, x1, y1 = grid.bounds(cell)
    corners = ((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))
    return tuple((float(x), float(y), z) for x, y in corners)


def _tile(grid: CellGrid, ns: str, cell: int, colour: Colour, z: float) -> MarkerSpec:
    x0, y0, x1, y1 = grid.bounds(cell)
    return MarkerSpec(
        ns,
        cell,
        CUBE,
        position=((x0 + x1) / 2, (y0 + y1) / 2, z),
        scale=(x1 - x0, y1 - y0, 0.01),
        colour=colour,
    )


def grid_markers(grid: CellGrid, restricted: Iterable[int] = ()) -> list[MarkerSpec]:
    """The static part: cell outlines, numbers and the restricted cells."""
    out = []
    for cell in grid.cells:
        out.append(
            MarkerSpec(
                "grid", cell, LINE_STRIP, scale=(0.02, 0.0, 0.0), points=_outline(grid, cell, 0.005)
            )  # fmt: skip
        )
        x, y = grid.center(cell)
        out.append(
            MarkerSpec(
                "cell_labels",
                cell,
                TEXT_VIEW_FACING,
                position=(x, y, 0.3),
                scale=(0.0, 0.0, 0.25),
                colour=WHITE,
                text=str(cell),
            )  # fmt: skip
        )
    for cell in restricted:
        if cell not in grid.cells:
            raise ValueError(f"restricted cell {cell} is not a cell of the grid")
        out.append(_tile(grid, "restricted", cell, RED, 0.002))
    return out


def _probability(p: object) -> float | None:
    """A probability from a message field (None when it is not one)."""
    try:
        v = float(p)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return v if 0.0 <= v <= 1.0 else None


def belief_markers(grid: CellGrid, person: Mapping[str, float]) -> list[MarkerSpec]:
    """Cells shaded by P(person there) (``person``: the planner's marginal, labels
    "1".."n" and "No person"); unknown labels and non-finite values are ignored."""
    probs = {}
    for label, p in person.items():
        v = _probability(p)
        if str(label).isdigit() and int(label) in grid.cells and v is not None:
            probs[int(label)] = v
    top = max(probs.values(), default=0.0)
    out = []
    for cell in grid.cells:
        a = probs.get(cell, 0.0) / top if top > 0 else 0.0
        out.append(_tile(grid, "belief", cell, (*BLUE[:3], round(0.8 * a, 4)), 0.004))
    none = _probability(person.get(NO_PERSON))
    x0 = min(grid.bounds(c)[0] for c in grid.cells)
    x1 = max(grid.bounds(c)[2] for c in grid.cells)
    y1 = max(grid.bounds(c)[3] for c in grid.cells)
    text = "P(no person) ?" if none is None else f"P(no person) {none:.2f}"
    out.append(
        MarkerSpec(
            "belief",
            0,
            TEXT_VIEW_FACING,
            position=((x0 + x1) / 2, y1 + 0.3, 0.3),
            scale=(0.0, 0.0, 0.25),
            colour=WHITE,
            text=text,
        )  # fmt: skip
    )
    return out


def people_markers(
    people_xy: Sequence[tuple[float, float]], max_people: int = 8
) -> list[MarkerSpec]:
    """A cylinder per person; ids 0..max_people-1, absent ones deleted by a viewer's
    DELETEALL of the namespace before (see :func:`scene_markers`)."""
    out = []
    for i, (x, y) in enumerate(people_xy[:max_people]):
        out.append(
            MarkerSpec(
                "people",
                i,
                CYLINDER,
                position=(float(x), float(y), 0.85),
                scale=(0.5, 0.5, 1.7),
                colour=ORANGE,
            )  # fmt: skip
        )
    return out


def robot_cell_marker(grid: CellGrid, robot: Mapping[str, float]) -> list[MarkerSpec]:
    """The robot's most likely cell outlined (none when the marginal names no cell)."""
    cells = [
        (v, int(c))
        for c, p in robot.items()
        if str(c).isdigit() and int(c) in grid.cells and (v := _probability(p)) is not None
    ]
    if not cells:
        return []
    _, cell = max(cells)
    return [
        MarkerSpec(
            "robot_cell",
            0,
            LINE_STRIP,
            scale=(0.06, 0.0, 0.0),
            colour=GREEN,
            points=_outline(grid, cell, 0.01),
        )  # fmt: skip
    ]


def scene_markers(
    grid: CellGrid,
    restricted: Iterable[int],
    belief: Mapping[str, Mapping[str, float]] | None = None,
    people_xy: Sequence[tuple[float, float]] = (),
) -> list[MarkerSpec]:
    """Everything, in publishing order: a DELETEALL first (stale people vanish), then
    the grid, the belief (``{"person": {...}, "robot": {...}}``) and the people."""
    out = [MarkerSpec("", 0, CUBE, action=DELETEALL)]
    out += grid_markers(grid, restricted)
    if belief:
        out += belief_markers(grid, belief.get("person", {}))
        out += robot_cell_marker(grid, belief.get("robot", {}))
    out += people_markers(people_xy)
    return out
