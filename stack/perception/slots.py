"""Person slots (issue 16): which tracked person is "person 1", "person 2", ... of the
planner's n-person model, and what the perception reports for each slot.

Person slots. The n-person model is symmetric between people: every person has the
same transition and observation tables and the reward asks only whether *some*
person makes a restricted cell worth guarding, so permuting the people permutes the
belief's factors and changes no value. The order of the slots therefore carries no
meaning and needs only to be *consistent over time*: the factored belief keeps one
factor per slot, and a person must keep feeding the same factor. The rules:

1. a track keeps its slot for as long as it lives (through misses and crossings);
2. a slot whose track ended is free; it remembers where its person was last seen;
3. newly confirmed tracks fill free slots by a Hungarian assignment on the distance
   from the slot's last seen position (a slot never used, or whose person left,
   costs ``fresh_cost_m``): a person lost for a moment and found again near where
   they vanished gets their old slot, so their belief factor continues;
4. with more confirmed tracks than slots, the tracks already holding slots keep
   them; the others wait (oldest first) for a slot to free;
5. ties put the i-th waiting track in the i-th free slot, so the result is
   deterministic.

A free slot is observed as "No person" (or as hidden, when the camera could not
look); because of the symmetry it does not matter which free slot a new person
takes when none remembers a nearby person.

Pure: no ROS. :class:`stack.perception.multi.PeoplePerception` fills the slots.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from stack.cells import CellGrid, Direction
from stack.config import Config, require
from stack.perception.observation import speed_class
from stack.perception.tracker import TrackEstimate
from stack.vocabulary import NO_PERSON, NOT_MOVING, UNSEEN


@dataclass(frozen=True)
class SlotConfig(Config):
    """Attributes:
    slots: the number of people the planner's model has (the task's ``people``).
    fresh_cost_m: the cost of putting a new person in a slot that remembers nobody
        (never used, or its person left the map) [m]: a slot whose person vanished
        nearer than this to the new one is preferred.
    """

    section = "slots"

    slots: int = 2
    fresh_cost_m: float = 1.5

    def __post_init__(self) -> None:
        require(self.slots >= 1, "slots", self.slots, "must be >= 1")
        require(self.fresh_cost_m > 0, "fresh_cost_m", self.fresh_cost_m, "must be > 0")


class PersonSlots:
    """Which track is person 1, 2, ... (the rules in the module docstring).

    Args:
        config: the number of slots and the cost of a fresh slot.
        grid: when given, a slot whose person was last seen outside the region
            (left the map) remembers nobody.
    """

    def __init__(self, config: SlotConfig = SlotConfig(), grid: CellGrid | None = None):
        self.config = config
        self.grid = grid
        self._track: list[int | None] = [None] * config.slots
        self._last: list[tuple[float, float] | None] = [None] * config.slots

    @property
    def track_ids(self) -> tuple[int | None, ...]:
        """The track id in each slot (None: free)."""
        return tuple(self._track)

    def assign(self, tracks: Sequence[TrackEstimate]) -> tuple[TrackEstimate | None, ...]:
        """Update the slots with the live tracks.

        Args:
            tracks: the tracks after this frame (only confirmed ones take slots).

        Returns:
            The track in each slot, slot 0 first (None: nobody).
        """
        live = {t.track_id: t for t in tracks if t.confirmed}
        for k, tid in enumerate(self._track):
            if tid is not None and tid not in live:
                self._track[k] = None  # rule 2: the slot is free, _last remembers
        held = {tid for tid in self._track if tid is not None}
        free = [k for k, tid in enumerate(self._track) if tid is None]
        # rule 4: the oldest waiting tracks first (lowest id = created first)
        waiting = sorted(
            (t for tid, t in live.items() if tid not in held), key=lambda t: t.track_id
        )
        if free and waiting:
            cost = np.empty((len(waiting), len(free)))
            for i, t in enumerate(waiting):
                for j, k in enumerate(free):
                    last = self._last[k]
                    near = math.dist(last, t.position_m) if last is not None else math.inf
                    # rule 4: older waiting tracks cost less (1 mm per place in line);
                    # rule 5: ties put the i-th waiting track in the i-th free slot
                    cost[i, j] = min(near, self.config.fresh_cost_m) + 1e-3 * i + 1e-6 * abs(i - j)
            rows, cols = linear_sum_assignment(cost)
            for i, j in zip(rows, cols, strict=True):
                self._track[free[j]] = waiting[i].track_id
        out: list[TrackEstimate | None] = []
        for k, tid in enumerate(self._track):
            holder = live.get(tid) if tid is not None else None
            if holder is not None:
                inside = self.grid is None or self.grid.cell_at(*holder.position_m) is not None
                self._last[k] = holder.position_m if inside else None
            out.append(holder)
        return tuple(out)


@dataclass(frozen=True)
class SlotPerson:
    """What the perception reports for one person slot.

    Attributes:
        slot: 0-based slot index (person ``slot + 1`` of the model).
        track_id: the camera track in the slot; None: nobody.
        position_m: its map position [m].
        cell: the cell there; None outside the region (or nobody): "No person".
        direction: from the track's positions (thesis rule, per person).
        speed_mps: the associated laser track's speed (eq. 4.8); None without one.
        laser_track_id: that laser track's id; None without one.
        measured: the position was measured in this frame (by the camera, or the
            laser's legs of a person the camera missed), not the track's prediction
            while it coasts.
    """

    slot: int
    track_id: int | None = None
    position_m: tuple[float, float] | None = None
    cell: int | None = None
    direction: Direction = Direction.NOT_MOVING
    speed_mps: float | None = None
    laser_track_id: int | None = None
    measured: bool = True

    @property
    def velocity_label(self) -> str:
        """The model's velocity label, by the thesis's rules (4.5) for this person:
        "Not moving" outside the region or when the camera sees no movement; else the
        direction and the laser's speed class ("0-0.2" without a laser track)."""
        if self.cell is None or self.direction is Direction.NOT_MOVING:
            return NOT_MOVING
        return f"{self.direction.label} {speed_class(self.speed_mps or 0.0).label}"


def model_persons(people: Sequence[SlotPerson]) -> list[tuple[int | None, str]]:
    """The slots as ``FactoredModel.observation_index`` takes them: [(cell or None,
    velocity label)], slot 0 first (None: "No person")."""
    return [(p.cell, p.velocity_label) for p in sorted(people, key=lambda p: p.slot)]


def slot_labels(people: Sequence[SlotPerson], unseen: bool = False) -> list[dict[str, Any]]:
    """The slots as the observations message carries them (issue 16), slot 0 first:
    ``{"person": cell or "No person", "velocity": label, "position_m": [x, y] or
    None}`` each (the position also off the grid, for the goal inference of
    ``person_model: goal``; only a measured one: a track's prediction while it coasts
    is no evidence of where the person walks); every slot "Unseen" (velocity "Not
    moving", no position) when the camera could not look at all (``unseen``)."""
    out: list[dict[str, Any]] = []
    for p in sorted(people, key=lambda p: p.slot):
        if unseen:
            out.append({"person": UNSEEN, "velocity": NOT_MOVING, "position_m": None})
        else:
            label = NO_PERSON if p.cell is None else str(p.cell)
            pos = (
                None
                if p.position_m is None or not p.measured
                else [round(float(c), 4) for c in p.position_m]
            )
            out.append({"person": label, "velocity": p.velocity_label, "position_m": pos})
    return out
