"""Anticipation: head for the restricted cell a person is walking to (issue 26).

The task policy (chapter 3's person model) reacts to the cell a person is *in*: it
moves once the person is next to a restricted cell, one cell per decision step, and
reaches the cell seconds after them. A task with ``person_model: goal`` adds this
layer: the person's observed floor positions feed Bayesian goal inference
(:mod:`stack.planning.intent`: a Boltzmann-rational walker heading for a restricted
cell or elsewhere), and while the person is believed to be heading for a restricted
cell the robot drives straight there at top speed (a navigation trip, "To 1"; or with
``motion: cells`` the first move of a shortest path of cell moves) instead of the
policy's action. The policy decides everything else: waiting at rest, coming back, and
whatever it does while the person is not seen.

- heading for cell c starts when P(goal = c) reaches ``go_probability`` and stops
  when it falls under ``stay_probability`` (hysteresis: a person who pauses on the
  way does not make the robot turn back at once);
- a person seen *in* a restricted cell makes it the target whatever the goal belief
  (the trip there, not the policy's cell moves with a stop at each);
- with the robot in the target cell it waits there (the policy values the cell only
  with the person in it, and would leave);
- a change of target is an event: the planner decides again at once
  (:class:`stack.planning.stepper.DecisionSteps`), not at the end of the step.

Pure (numpy): the planner node and the in-process loop run it through
:class:`stack.planning.agent.PlannerAgent`.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from stack.cells import MOVING_DIRECTIONS, CellGrid
from stack.config import Config, require
from stack.planning.intent import GoalInference, IntentConfig, IntentEstimate, TrackObservation
from stack.vocabulary import trip_command

PERSON_MODELS = ("thesis", "goal")
MOTIONS = ("trip", "cells")
TRIP_INSET_M = 0.35  # how far inside the cell a trip ends (navigation's trip_inset_m)


@dataclass(frozen=True)
class AnticipationConfig(Config):
    """Attributes:
    go_probability: head for a restricted cell once the person's goal is it with at
        least this probability.
    stay_probability: keep heading there while the probability stays above this.
    motion: how the robot heads for the target: ``trip`` (one navigation trip
        straight into the cell at top speed, "To 1") or ``cells`` (the thesis's cell
        moves, one per decision step).
    robot_speed_mps: the robot's mean speed over a trip (acceleration, and for cell
        moves the stops and decisions, included; cell moves average 0.41 m/s in the
        twin).
    lead_s: heading for a cell starts once the person's predicted time to entry is
        within the robot's trip time plus this (the intent's ``eta_s``): the robot
        still arrives first, and a person who turns away before has not sent it.
    enter_probability: without a target, the policy's move into a restricted cell is
        held back for a person seen outside it whose goal is that cell with less than
        this probability (a decoy turning away, a passer-by, a person leaving).
    max_unseen_s: and while the person was seen within this long (unseen, the goal
        belief drifts back to its prior, which is no evidence of a visit).
    exits_m: the room's doorways (map points, m): a person walking out is heading for
        one of them, not for the restricted cell on the way (without them a walk to a
        door beside a restricted cell looks like a visit).
    intent: the goal inference (:class:`stack.planning.intent.IntentConfig`).
    """

    section = "anticipation"

    go_probability: float = 0.6
    stay_probability: float = 0.35
    motion: str = "trip"
    robot_speed_mps: float = 0.4
    lead_s: float = 1.5
    enter_probability: float = 0.6
    max_unseen_s: float = 2.0
    exits_m: tuple[tuple[float, float], ...] = ()
    intent: IntentConfig = field(default_factory=IntentConfig)

    def __post_init__(self) -> None:
        require(0.0 < self.go_probability <= 1.0, "go_probability", self.go_probability,
                "must be in (0, 1]")  # fmt: skip
        require(0.0 <= self.stay_probability <= self.go_probability, "stay_probability",
                self.stay_probability, "must be in [0, go_probability]")  # fmt: skip
        require(self.motion in MOTIONS, "motion", self.motion, f"must be one of {MOTIONS}")
        require(0.0 < self.robot_speed_mps <= 5.0, "robot_speed_mps", self.robot_speed_mps,
                "must be in (0, 5] m/s")  # fmt: skip
        require(0.0 <= self.lead_s <= 60.0, "lead_s", self.lead_s, "must be in [0, 60] s")
        require(0.0 <= self.enter_probability <= 1.0, "enter_probability",
                self.enter_probability, "must be in [0, 1]")  # fmt: skip
        require(0.0 < self.max_unseen_s < 60.0, "max_unseen_s", self.max_unseen_s,
                "must be in (0, 60) s")  # fmt: skip


def first_move(grid: CellGrid, start: int, goal: int) -> str | None:
    """The first action ("North", ...) of a shortest path of cell moves from ``start``
    to ``goal`` (ties: the order of :data:`MOVING_DIRECTIONS`); None when there."""
    if start == goal:
        return None
    first: dict[int, str] = {start: ""}
    queue = deque([start])
    while queue:
        c = queue.popleft()
        for d in MOVING_DIRECTIONS:
            n = grid.neighbour(c, d)
            if n is None or n in first:
                continue
            first[n] = first[c] or d.label
            if n == goal:
                return first[n]
            queue.append(n)
    return None


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


def watch_cell(grid: CellGrid, restricted_cells: tuple[int, ...]) -> int:
    """Where a guard waits (a task's ``rest_cell: auto``): the cell, not restricted,
    whose longest trip to a restricted cell is shortest (the thesis's rest cell 7 is
    "equidistant" from task r2's cells 1 and 12); ties go to the shorter trips in
    total, then to the lowest cell number. With one restricted cell it is the nearest
    neighbour: a guard waiting there is one move from the cell, not three."""
    trips = {r: travel_m(grid, r) for r in restricted_cells}
    candidates = [c for c in grid.cells if c not in trips]
    if not candidates:
        raise ValueError("every cell is restricted: nowhere to wait")

    def cost(c: int) -> tuple[float, float, int]:
        ds = [trips[r].get(c, math.inf) for r in restricted_cells]
        return (round(max(ds), 9), round(sum(ds), 9), c)

    return min(candidates, key=cost)


class Anticipator:
    """Goal inference on one person's observed positions and the move it advises.

    Args:
        grid, restricted_cells: the task's.
        config: thresholds and the inference's parameters.
    """

    def __init__(
        self, grid: CellGrid, restricted_cells: tuple[int, ...], config: AnticipationConfig
    ):
        self.grid, self.restricted, self.config = grid, tuple(restricted_cells), config
        self.inference = GoalInference(grid, restricted_cells, config.intent, config.exits_m)
        self.estimate: IntentEstimate | None = None
        self.target: int | None = None
        # trip lengths from every cell to each restricted cell (moves are symmetric;
        # a trip: straight from the cell's centre to the nearest point inside)
        self._trip_m = {r: self.trip_lengths(grid, r, config.motion) for r in self.restricted}

    @staticmethod
    def trip_lengths(grid: CellGrid, cell: int, motion: str) -> dict[int, float]:
        """The robot's trip length (m) from every cell's centre into ``cell``: cell moves
        centre to centre, or a trip straight to the nearest point ``TRIP_INSET_M`` inside."""
        if motion == "cells":
            return travel_m(grid, cell)
        out = {}
        for c in grid.cells:
            x, y = grid.center(c)
            out[c] = math.dist((x, y), grid.nearest_inside(cell, x, y, TRIP_INSET_M))
        return out

    @classmethod
    def for_task(cls, task: Any) -> Anticipator | None:
        """The task's anticipator, or None for ``person_model: thesis``."""
        if getattr(task, "person_model", "thesis") != "goal":
            return None
        return cls(task.grid, task.restricted_cells, task.anticipation)

    def observe(
        self, t: float, position_m: tuple[float, float] | None, robot_cell: int | None = None
    ) -> bool:
        """Take the person's floor position at ``t`` (None: not seen) and the robot's
        cell (None: unknown); returns whether the target changed (an event worth a new
        decision)."""
        if position_m is None:
            est = self.inference.predict(t)
        else:
            est = self.inference.update(TrackObservation(t, (position_m[0], position_m[1])))
        self.estimate = est
        before = self.target
        cfg = self.config
        unseen = est.age_s > cfg.max_unseen_s
        if unseen:
            self.target = None
        elif est.inside is not None:
            self.target = est.inside  # in a restricted cell: be there, now, at top speed
        else:
            if self.target is not None and est.p(self.target) < cfg.stay_probability:
                self.target = None
            best = max(self.restricted, key=est.p)
            if est.p(best) >= cfg.go_probability and (
                best == self.target or self._due(est, best, robot_cell)
            ):
                self.target = best
        return self.target != before

    def _due(self, est: IntentEstimate, cell: int, robot_cell: int | None) -> bool:
        """The person may be in ``cell`` within the robot's trip there plus ``lead_s``
        (always, with the robot's cell unknown)."""
        if robot_cell is None:
            return True
        trip_s = self._trip_m[cell].get(robot_cell, math.inf) / self.config.robot_speed_mps
        return est.forecast(cell).eta_s <= trip_s + self.config.lead_s

    def advise(self, robot_cell: int | None, policy_action: str | None = None) -> str | None:
        """The trip to the target cell ("To 1"; with ``motion: cells`` the first move
        toward it), "Do nothing" in it (wait there for the
        person: the policy, which values the cell only with the person in it, would
        leave), or None (the policy decides). Without a target, a policy move *into* a
        restricted cell the person is seen and not heading for (goal probability under
        ``stay_probability``; a decoy turning away, a passer-by, a person standing
        next to it; ``enter_probability``) is held back ("Do nothing"): the thesis's
        model enters on the person's cell and direction alone, a needless trip when
        they do not come.
        The policy decides while the person is unseen."""
        if robot_cell is None:
            return None
        if self.target is not None:
            if robot_cell == self.target:
                return "Do nothing"
            if self.config.motion == "trip":
                return trip_command(self.target)
            return first_move(self.grid, robot_cell, self.target) or "Do nothing"
        est = self.estimate
        if (
            policy_action is None
            or est is None
            or est.inside is not None
            or est.age_s > self.config.max_unseen_s
        ):
            return None
        direction = next((d for d in MOVING_DIRECTIONS if d.label == policy_action), None)
        entering = None if direction is None else self.grid.neighbour(robot_cell, direction)
        if entering in self.restricted and est.p(entering) < self.config.enter_probability:
            return "Do nothing"
        return None

    def note(self) -> dict[str, Any] | None:
        """For the step record: the target and the goal probabilities."""
        if self.estimate is None:
            return None
        return {
            "target": self.target,
            "p_goal": {str(c): round(self.estimate.p(c), 3) for c in self.restricted},
        }
