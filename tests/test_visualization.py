"""Markers of the grid, restricted cells, belief and people (issue 14)."""

import math

import pytest

from stack.cells import CellGrid
from stack.visualization import (
    CUBE,
    DELETEALL,
    LINE_STRIP,
    belief_markers,
    grid_markers,
    people_markers,
    scene_markers,
)

GRID = CellGrid()


def test_every_cell_is_outlined_and_labelled_and_restricted_cells_filled():
    ms = grid_markers(GRID, [1, 12])
    outlines = [m for m in ms if m.ns == "grid"]
    assert sorted(m.id for m in outlines) == sorted(GRID.cells)
    for m in outlines:
        assert m.type == LINE_STRIP and m.points[0] == m.points[-1]  # closed
        xs = [p[0] for p in m.points]
        ys = [p[1] for p in m.points]
        x0, y0, x1, y1 = GRID.bounds(m.id)
        assert (min(xs), min(ys), max(xs), max(ys)) == pytest.approx((x0, y0, x1, y1))
    labels = {m.id: m.text for m in ms if m.ns == "cell_labels"}
    assert labels == {c: str(c) for c in GRID.cells}
    filled = [m for m in ms if m.ns == "restricted"]
    assert sorted(m.id for m in filled) == [1, 12]
    assert filled[0].position[:2] == pytest.approx(GRID.center(filled[0].id))
    with pytest.raises(ValueError, match="99"):
        grid_markers(GRID, [99])


def test_belief_shades_cells_by_probability_and_ignores_junk():
    ms = belief_markers(GRID, {"1": 0.6, "2": 0.3, "3": math.nan, "x": 0.5, "No person": 0.1})
    tiles = {m.id: m for m in ms if m.type == CUBE}
    assert set(tiles) == set(GRID.cells)
    assert tiles[1].colour[3] == pytest.approx(0.8)  # the most likely cell: full shade
    assert tiles[2].colour[3] == pytest.approx(0.4)
    assert tiles[3].colour[3] == 0.0 and tiles[4].colour[3] == 0.0
    (text,) = [m for m in ms if m.text]
    assert text.text == "P(no person) 0.10"
    empty = belief_markers(GRID, {"No person": "junk"})
    assert all(m.colour[3] == 0.0 for m in empty if m.type == CUBE)
    assert [m.text for m in empty if m.text] == ["P(no person) ?"]


def test_the_scene_starts_with_deleteall_and_keeps_ids_stable():
    belief = {"person": {"5": 1.0}, "robot": {"7": 0.9, "5": 0.1}}
    a = scene_markers(GRID, [1], belief, [(2.5, 0.7), (4.0, 2.0)])
    b = scene_markers(GRID, [1], belief, [(2.6, 0.7)])
    assert a[0].action == DELETEALL and b[0].action == DELETEALL
    key = lambda ms: {(m.ns, m.id) for m in ms}  # noqa: E731
    assert key(b) <= key(a)  # one person fewer: the same ids otherwise
    (robot,) = [m for m in a if m.ns == "robot_cell"]
    assert min(p[0] for p in robot.points) == pytest.approx(GRID.bounds(7)[0])
    assert len(people_markers([(0.0, 0.0)] * 20)) == 8


def test_the_foxglove_layout_names_panels_and_topics_that_exist():
    import json
    from pathlib import Path

    from stack import topics

    layout = json.loads(
        (Path(__file__).resolve().parents[1] / "config" / "foxglove-layout.json").read_text()
    )
    known = {v for k, v in vars(topics).items() if k.isupper() and isinstance(v, str)}

    def panels(node):
        if isinstance(node, str):
            return [node]
        return panels(node["first"]) + panels(node["second"])

    used = panels(layout["layout"])
    assert sorted(used) == sorted(layout["configById"])
    cfg = layout["configById"]
    named = set(cfg["3D!vigil"]["topics"])
    named |= {cfg["Image!camera"]["imageMode"]["imageTopic"]}
    named |= {c["topicPath"] for k, c in cfg.items() if k.startswith("RawMessages")}
    assert named <= known, named - known
