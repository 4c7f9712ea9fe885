"""The ground truth of a run as cells over time: :class:`Timeline`, and
:func:`timeline_from_trace` to build it from ``trace.jsonl``.

The metrics (:mod:`vigil.report.metrics`) are computed on timelines. An instant's
cell holds from that trace record until the next one.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from stack.cells import CellGrid


@dataclass(frozen=True)
class Timeline:
    """Where robot and person were over time, as cells (one entry per trace record).

    Attributes:
        t: times [s], increasing.
        robot: the robot's cell (None: off the grid, or unknown where ``robot_known``
            is False).
        robot_known: whether the robot's position is known at that instant.
        person: the person's cell (None: not on the grid).
        present: whether the person is in the room (on the grid or elsewhere inside
            the walls).
        source: "ground truth", "odometry and camera" (no truth: hardware) or "none".
    """

    t: tuple[float, ...]
    robot: tuple[int | None, ...]
    robot_known: tuple[bool, ...]
    person: tuple[int | None, ...]
    present: tuple[bool, ...]
    source: str = "ground truth"
    # the person's cell, or just off the grid (within EDGE_M) the nearest one; () unknown
    person_edge: tuple[int | None, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in ("robot", "robot_known", "person", "present"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"timeline {name} has {len(getattr(self, name))} entries, t {n}")
        if self.person_edge and len(self.person_edge) != n:
            raise ValueError(f"timeline person_edge has {len(self.person_edge)} entries, t {n}")
        if any(b < a for a, b in zip(self.t, self.t[1:], strict=False)):
            raise ValueError("timeline times must not decrease")

    def __len__(self) -> int:
        return len(self.t)

    def index_at(self, t: float) -> int | None:
        """The last instant at or before ``t`` (None before the first)."""
        i = bisect.bisect_right(self.t, t + 1e-9) - 1
        return i if i >= 0 else None

    @classmethod
    def of(
        cls,
        t: Sequence[float],
        robot: Sequence[int | None],
        person: Sequence[int | None],
        present: Sequence[bool] | None = None,
    ) -> Timeline:
        """A ground-truth timeline from cell lists (tests, synthetic traces)."""
        pres = tuple(p is not None for p in person) if present is None else tuple(present)
        return cls(tuple(map(float, t)), tuple(robot), (True,) * len(t), tuple(person), pres)


def timeline_from_trace(
    trace: Iterable[dict],
    grid: CellGrid,
    room_m: tuple[float, float, float, float] | None = None,
    until_t: float | None = None,
    walker: int | None = None,
) -> Timeline:
    """The timeline of ``trace.jsonl`` records (see :mod:`vigil.report.records`).

    Cells come from the floor positions through ``grid`` (``stack.cells``), not from
    the records' own cell fields. Where a record has no ground truth (``robot`` null,
    hardware) the robot's cell is the odometry's and the person's the camera's.

    Args:
        trace: the records, sorted by ``t``.
        grid: the cell geometry.
        room_m: (x0, y0, x1, y1) of the room's inside; None: the grid's region.
        until_t: ignore records after this time (the last decision's stamp: after it
            the twin runs until a wall-clock stop, so the tail differs between runs).
        walker: with several walkers (records with ``people``, issue 16), the person
            is walker ``walker`` (0-based) instead of the first.
    """
    t, robot, known, person, present, sources = [], [], [], [], [], set()
    edge: list[int | None] = []
    for rec in trace:
        if until_t is not None and float(rec["t"]) > until_t + 1e-9:
            break
        if rec.get("robot") is not None:
            sources.add("ground truth")
            rx, ry = rec["robot"][:2]
            r_known, r_cell = True, grid.cell_at(rx, ry)
            p = rec.get("person")
            if walker is not None:
                people = rec.get("people") or []
                p = people[walker].get("position") if walker < len(people) else None
            p_cell = grid.cell_at(p[0], p[1]) if p is not None else None
            edge.append(None if p is None else grid.cell_near(p[0], p[1], EDGE_M))
            if p is None:
                here = False
            elif room_m is None:
                here = p_cell is not None
            else:
                here = room_m[0] <= p[0] <= room_m[2] and room_m[1] <= p[1] <= room_m[3]
        else:
            sources.add("odometry and camera")
            odom = rec.get("odom")
            r_known = odom is not None
            r_cell = grid.cell_at(odom[0], odom[1]) if odom is not None else None
            cam = rec.get("camera") or {}
            p_cell = cam.get("cell") if cam.get("status") == "person" else None
            here = p_cell is not None
            edge.append(p_cell)
        t.append(float(rec["t"]))
        robot.append(r_cell)
        known.append(r_known)
        person.append(p_cell)
        present.append(here)
    source = " + ".join(sorted(sources)) if sources else "none"
    return Timeline(
        tuple(t), tuple(robot), tuple(known), tuple(person), tuple(present), source, tuple(edge)
    )


EDGE_M = 0.3  # the observations node's border_margin_m: this close off the grid is its edge
