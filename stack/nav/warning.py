"""When to warn: the speech node's decisions, apart from speaking (thesis 3.2.2, made timely).

- :func:`person_to_warn`: the person cell the warning is for, from an observation's
  labels (with several people, whoever stands in the robot's cell);
- :func:`approaching`: a person walking into the robot's cell from the next one;
- :class:`WarningGate`: when to start a warning and when to cut one short;
- :class:`WarningReactor`: the three on observation records, as the speech node
  (:mod:`stack.nav.node_speech`) and the in-process loop (:mod:`vigil.inprocess`) both
  run them. Speaking itself is :mod:`stack.nav.speech`.

Pure: no ROS, no clock of its own (times are passed in).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from stack.cells import MOVING_DIRECTIONS, CellGrid
from stack.nav.config import SpeechConfig


def person_to_warn(robot: str, person: str, people: object = None) -> int | None:
    """The person cell the warning gate is given, from an observation's labels.

    ``person`` is the one-person label; ``people`` (issue 16, two or more people) the
    per-slot ``[{"person": label, ...}, ...]``. With several people, whoever stands in
    the robot's cell is the one to warn; otherwise the first seen person's cell.
    Labels that are not cell numbers ("No person", "Unseen") are nobody.
    """
    labels = [person]
    if isinstance(people, list):
        labels += [str(p.get("person", "")) for p in people if isinstance(p, dict)]
    cells = [int(x) for x in labels if x.isdigit()]
    here = int(robot) if robot.isdigit() else None
    if here is not None and here in cells:
        return here
    return cells[0] if cells else None


def approaching(
    robot: str, person: str, velocity: str, grid: CellGrid, people: object = None
) -> bool:
    """Whether a person is about to walk into the robot's cell, from an observation's
    labels: in a cell sharing a side with it and moving towards that side (velocity
    "West 0.2-0.7" from the cell east of it). ``people``: the per-slot
    ``[{"person": label, "velocity": label}, ...]`` of two or more people; anyone
    approaching counts. Labels that are not cell numbers are nobody."""
    if not robot.isdigit() or int(robot) not in grid.cells:
        return False
    here = int(robot)
    pairs = [(person, velocity)]
    if isinstance(people, list):
        pairs += [
            (str(p.get("person", "")), str(p.get("velocity", "")))
            for p in people
            if isinstance(p, dict)
        ]
    for cell, vel in pairs:
        if not cell.isdigit() or int(cell) == here or int(cell) not in grid.cells:
            continue
        heading = next((d for d in MOVING_DIRECTIONS if vel.startswith(d.label + " ")), None)
        if heading is not None and grid.neighbour(int(cell), heading) == here:
            return True
    return False


class WarningReactor:
    """The speech node's decisions without ROS (the node and the in-process loop both
    run this): observation records in (:meth:`observe`, the observations node's JSON
    object), "say" / "stop" / None out (:meth:`decide`).

    Args:
        grid: the task's cells.
        config: the speech section (restricted cells, the gate's times).
    """

    def __init__(self, grid: CellGrid, config: SpeechConfig):
        self.grid = grid
        self.gate = WarningGate(
            config.restricted_cells, config.grace_s, config.repeat_s, config.confirm_s
        )
        self.robot_cell: int | None = None
        self.person_cell: int | None = None  # the person to warn (:func:`person_to_warn`)
        self.approaching = False  # someone walks into the robot's cell (:func:`approaching`)
        self.frame_stamp_s: float | None = None  # the latest observation's camera frame

    def observe(self, body: Mapping[str, Any]) -> None:
        """Take one observation record (``robot``, ``person``, ``velocity`` labels and,
        with several people, ``people``)."""
        robot, person = str(body["robot"]), str(body["person"])
        frame = body.get("frame_stamp_s")
        # the camera frame this observation comes from: a warning's latency starts there
        self.frame_stamp_s = float(frame) if isinstance(frame, int | float) else None
        self.robot_cell = int(robot) if robot.isdigit() else None
        self.person_cell = person_to_warn(robot, person, body.get("people"))
        self.approaching = approaching(
            robot, person, str(body.get("velocity", "")), self.grid, body.get("people")
        )

    def decide(self, now_s: float, speaking: bool) -> str | None:
        """:meth:`WarningGate.update` on the latest observation."""
        return self.gate.update(
            now_s, self.robot_cell, self.person_cell, speaking, self.approaching
        )


class WarningGate:
    """When to speak the warning (thesis 3.2.2, made timely).

    The robot warns while a person is in a restricted cell with it, or walks into it
    (``approaching``: from the next cell, towards it; a guard that got there first warns
    before the entry): the person's and the robot's cells are the same restricted cell,
    or the person approaches it, seen so for ``confirm_s`` (a person hesitating on the
    border flickers between cells: the warning waits until they are in or walking in).
    A warning starts only while that holds; while the person stays it is repeated every
    ``repeat_s``. Nothing is queued: a warning due while one is playing
    is not said, and one still playing ``grace_s`` after the person left is cut short
    (:meth:`update` returns "stop"), so no warning plays to an empty cell.

    Args:
        restricted_cells: the task's restricted cells.
        grace_s, repeat_s, confirm_s: as above [s].
    """

    def __init__(
        self,
        restricted_cells,
        grace_s: float = 2.0,
        repeat_s: float = 8.0,
        confirm_s: float = 0.5,
    ):
        self.restricted = frozenset(int(c) for c in restricted_cells)
        self.grace_s, self.repeat_s = float(grace_s), float(repeat_s)
        self.confirm_s = float(confirm_s)
        self._with_person_s = -math.inf  # last time a person was in a restricted cell with it
        self._together_since_s: float | None = None  # start of the current "together" run
        self._started_s = -math.inf  # last warning's start

    def update(
        self,
        now_s: float,
        robot_cell: int | None,
        person_cell: int | None,
        speaking: bool,
        approaching: bool = False,
    ) -> str | None:
        """Return "say" to start a warning now, "stop" to cut the current one, else None.
        ``approaching``: a person walks into the robot's cell (:func:`approaching`)."""
        together = robot_cell is not None and robot_cell in self.restricted
        together = together and (person_cell == robot_cell or approaching)
        if together:
            if now_s - self._with_person_s > self.grace_s:  # a new visit: warn at once
                self._started_s = -math.inf
            self._with_person_s = now_s
            if self._together_since_s is None:
                self._together_since_s = now_s
        else:
            self._together_since_s = None
        recent = now_s - self._with_person_s <= self.grace_s
        if speaking:
            return None if recent else "stop"
        since = now_s if self._together_since_s is None else self._together_since_s
        confirmed = together and now_s - since >= self.confirm_s  # (a start at t = 0 counts)
        if confirmed and now_s - self._started_s >= self.repeat_s:
            self._started_s = now_s
            return "say"
        return None
