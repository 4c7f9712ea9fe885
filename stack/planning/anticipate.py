"""Anticipation: head for the restricted cell a person is walking to (issue 26).

The task policy (chapter 3's person model) reacts to the cell a person is *in*: it
moves once the person is next to a restricted cell, one cell per decision step, and
reaches the cell seconds after them. A task with ``person_model: goal`` adds this
layer: the person's observed floor positions feed Bayesian goal inference
(:mod:`stack.planning.intent`: a Boltzmann-rational walker heading for a restricted
cell or elsewhere), and while the person is believed to be heading for a restricted
cell the robot drives straight there at top speed (a navigation trip, "To 1"; or with
``motion: cells`` the first move of a shortest path of cell moves) instead of the
policy's action. While a person is seen and no cell is the target yet, the robot
stands by in the cell where its expected lateness is least (``standby``). The policy
decides everything else: waiting at rest, coming back, and whatever it does while
nobody is seen.

- heading for cell c starts when P(goal = c) reaches ``go_probability`` and stops
  when it falls under ``stay_probability`` (hysteresis: a person who pauses on the
  way does not make the robot turn back at once);
- a person seen *in* a restricted cell makes it the target whatever the goal belief
  (the trip there, not the policy's cell moves with a stop at each);
- with the robot in the target cell it waits there (the policy values the cell only
  with the person in it, and would leave);
- standing by: the cell, not restricted, that minimises the sum over the people seen
  and the restricted cells c of P(goal = c) times how much later than the person the
  robot would reach c from there (two restricted cells far apart: a person coming in
  at the door beside one draws the robot toward it before their goal is clear);
- a change of target or standby cell is an event: the planner decides again at once
  (:class:`stack.planning.stepper.DecisionSteps`), not at the end of the step.

Pure (numpy): the planner node and the in-process loop run it through
:class:`stack.planning.agent.PlannerAgent`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from stack.cells import MOVING_DIRECTIONS, CellGrid, first_move
from stack.config import Config, require
from stack.planning.intent import GoalInference, IntentConfig, IntentEstimate, TrackObservation
from stack.planning.standby import expected_lateness, trip_times
from stack.vocabulary import trip_command

PERSON_MODELS = ("thesis", "goal")
MOTIONS = ("trip", "cells")


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
    standby: while a person is seen and no restricted cell is the target yet, wait in
        the cell (not restricted) where the robot's expected lateness is least: the sum
        over people and restricted cells of P(goal = c) times how much later than the
        person the robot would reach c from there (:func:`expected_lateness`). With two
        restricted cells far apart, a person coming in at the door beside one draws the
        robot toward it before their goal is clear, and back as they head for the other.
    standby_margin_s: move to a better waiting cell only when it cuts the expected
        lateness by at least this (s): no back and forth on small changes of belief.
    serve_s: with several people, a visit the robot has been in for this long with the
        person inside (s; the warning heard: the speech node's ``confirm_s`` and the
        3 s warning) is warned: heading there is worth nothing more, and the guard
        moves on to a visitor nobody has warned yet.
    stay_mean_s: with several people, the mean of the exponential stay a visitor is
        assumed to make in a restricted cell (s): the chance that a visit the robot
        reaches ``x`` seconds after the entry is still under way is exp(-x / mean).
        5 s: the stays of 3.5-6.3 s people make at a machine or a door.
    switch_margin: with several people, the target in hand is kept while it is worth
        at least the best candidate's value less this (a share of a visit).
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
    standby: bool = True
    standby_margin_s: float = 0.3
    serve_s: float = 4.0
    stay_mean_s: float = 5.0
    switch_margin: float = 0.1
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
        require(0.0 <= self.standby_margin_s <= 60.0, "standby_margin_s",
                self.standby_margin_s, "must be in [0, 60] s")  # fmt: skip
        require(0.0 <= self.serve_s <= 600.0, "serve_s", self.serve_s,
                "must be in [0, 600] s")  # fmt: skip
        require(0.0 < self.stay_mean_s <= 600.0, "stay_mean_s", self.stay_mean_s,
                "must be in (0, 600] s")  # fmt: skip
        require(0.0 <= self.switch_margin <= 1.0, "switch_margin", self.switch_margin,
                "must be in [0, 1]")  # fmt: skip


class Anticipator:
    """Goal inference on one person's observed positions and the move it advises.

    Args:
        grid, restricted_cells: the task's.
        config: thresholds and the inference's parameters.
    """

    def __init__(
        self,
        grid: CellGrid,
        restricted_cells: tuple[int, ...],
        config: AnticipationConfig,
        home: int | None = None,
    ):
        self.grid, self.restricted, self.config = grid, tuple(restricted_cells), config
        self.home = home  # where the policy waits (the task's rest cell), if known
        self.inference = GoalInference(grid, restricted_cells, config.intent, config.exits_m)
        self.estimate: IntentEstimate | None = None
        self.target: int | None = None
        self.standby: int | None = None  # where to wait for the target (config.standby)
        self.stamp_s: float | None = None  # the last observation's time
        # trip times (s) from every cell into each restricted cell, at the trip speed
        self._trip_s = trip_times(grid, self.restricted, config.robot_speed_mps, config.motion)
        self._waits = tuple(c for c in grid.cells if c not in self.restricted)

    @classmethod
    def for_task(cls, task: Any) -> Anticipator | None:
        """The task's anticipator, or None for ``person_model: thesis``."""
        if getattr(task, "person_model", "thesis") != "goal":
            return None
        return cls(task.grid, task.restricted_cells, task.anticipation, task.rest_cell)

    def observe(
        self, t: float, position_m: tuple[float, float] | None, robot_cell: int | None = None
    ) -> bool:
        """Take the person's floor position at ``t`` (None: not seen) and the robot's
        cell (None: unknown); returns whether the target or the standby cell changed
        (an event worth a new decision)."""
        before, held = self.target, self.standby
        self.stamp_s = t
        self.track_goal(t, position_m, robot_cell)
        waiting = [] if self.target is not None else self.seen([self.estimate])
        self.standby = self.choose_standby(waiting, robot_cell, held)
        return self.target != before or self.standby != held

    def track_goal(
        self, t: float, position_m: tuple[float, float] | None, robot_cell: int | None
    ) -> None:
        """The goal inference's step and this person's target (no standby: with
        several people it is chosen over them all)."""
        if position_m is None:
            est = self.inference.predict(t)
        else:
            est = self.inference.update(TrackObservation(t, (position_m[0], position_m[1])))
        self.estimate = est
        cfg = self.config
        if not self.seen([est]):
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

    def seen(self, estimates: Sequence[IntentEstimate | None]) -> list[IntentEstimate]:
        """The estimates of people seen within ``max_unseen_s`` (unseen, a goal belief
        drifts back to its prior, which is no evidence of a visit)."""
        return [e for e in estimates if e is not None and e.age_s <= self.config.max_unseen_s]

    def lateness(self, estimates: Sequence[IntentEstimate], cell: int) -> float:
        """The robot's expected lateness (s) waiting in ``cell``, at its trip speed
        (:func:`expected_lateness`)."""
        return expected_lateness(self._trip_s, estimates, cell)

    def choose_standby(
        self, estimates: Sequence[IntentEstimate], robot_cell: int | None, held: int | None
    ) -> int | None:
        """Where to wait (``config.standby``) for the people seen (``estimates``; none:
        nowhere, the policy decides): the cell in hand (``held``, else the robot's) while
        no other cuts the expected lateness by ``standby_margin_s``, else the best one
        (ties: the nearer to the robot). None when there is nothing to wait for, or
        when the best cell cuts less than the margin off waiting at ``home`` (the
        policy's rest cell): a person who stopped or turned away no longer keeps the
        robot at a far corner."""
        if not self.config.standby or not estimates or robot_cell is None:
            return None
        # the robot's own cell counts even when restricted: a robot that has just
        # guarded a visit is not pulled out while the person may still be inside
        waits = self._waits if robot_cell in self._waits else (*self._waits, robot_cell)
        cost = {w: self.lateness(estimates, w) for w in waits}
        here = held if held is not None else robot_cell
        rx, ry = self.grid.center(robot_cell)
        best = min(
            self._waits,
            key=lambda w: (round(cost[w], 6), math.dist((rx, ry), self.grid.center(w)), w),
        )
        margin = self.config.standby_margin_s
        if self.home in cost and cost[self.home] - cost[best] < margin:
            return None
        if cost.get(here, math.inf) - cost[best] < margin:
            return held
        return best

    def trip_s(self, robot_cell: int | None, cell: int) -> float:
        """The robot's trip time (s) from ``robot_cell`` into restricted ``cell`` at the
        trip speed (0 with the robot's cell unknown)."""
        return 0.0 if robot_cell is None else self._trip_s[cell].get(robot_cell, 0.0)

    def _due(self, est: IntentEstimate, cell: int, robot_cell: int | None) -> bool:
        """The person may be in ``cell`` within the robot's trip there plus ``lead_s``
        (always, with the robot's cell unknown)."""
        if robot_cell is None:
            return True
        trip_s = self._trip_s[cell].get(robot_cell, math.inf)
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
            return self.move_to(robot_cell, self.target)
        return self.wait(robot_cell, self.standby, policy_action, [self.estimate])

    def wait(
        self,
        robot_cell: int,
        standby: int | None,
        policy_action: str | None,
        estimates: Sequence[IntentEstimate | None],
    ) -> str | None:
        """Without a target: the trip to the standby cell, or in it "Do nothing" (the
        policy's moves into a restricted cell still pass :meth:`hold_back`); without a
        standby cell, :meth:`hold_back`."""
        if standby is not None and robot_cell != standby:
            return self.move_to(robot_cell, standby)
        held = self.hold_back(robot_cell, policy_action, estimates)
        if held is not None or standby is None:
            return held
        return None if self.entering(robot_cell, policy_action) is not None else "Do nothing"

    def entering(self, robot_cell: int, action: str | None) -> int | None:
        """The restricted cell ``action`` (a move's name) takes the robot into from
        ``robot_cell``, else None."""
        direction = next((d for d in MOVING_DIRECTIONS if d.label == action), None)
        cell = None if direction is None else self.grid.neighbour(robot_cell, direction)
        return cell if cell in self.restricted else None

    def move_to(self, robot_cell: int, target: int) -> str:
        """The command toward ``target``: "Do nothing" in it, else the trip (or the
        first cell move with ``motion: cells``)."""
        if robot_cell == target:
            return "Do nothing"
        if self.config.motion == "trip":
            return trip_command(target)
        return first_move(self.grid, robot_cell, target) or "Do nothing"

    def hold_back(
        self,
        robot_cell: int,
        policy_action: str | None,
        estimates: Sequence[IntentEstimate | None],
    ) -> str | None:
        """ "Do nothing" instead of the policy's move into a restricted cell that none of
        the people seen (``estimates``, one per person) is heading for, while at least
        one of them is seen and none is in a restricted cell; else None."""
        fresh = self.seen(estimates)
        if policy_action is None or not fresh or any(e.inside is not None for e in fresh):
            return None
        entering = self.entering(robot_cell, policy_action)
        if entering is not None and all(
            e.p(entering) < self.config.enter_probability for e in fresh
        ):
            return "Do nothing"
        return None

    def note(self) -> dict[str, Any] | None:
        """For the step record: the target and the goal probabilities, as of the last
        observation (``at_s``; the record is written at the step's end, the note taken
        at the decision that began it)."""
        if self.estimate is None:
            return None
        return {
            "at_s": None if self.stamp_s is None else round(self.stamp_s, 3),
            "target": self.target,
            "standby": self.standby,
            "p_goal": {str(c): round(self.estimate.p(c), 3) for c in self.restricted},
        }


class PeopleAnticipator:
    """The anticipation layer for several people (a task's ``people`` >= 2): one
    :class:`Anticipator` per person slot, and one target for the robot, chosen by
    expected loss among the people's targets (a visit under way, or a likely one):
    the cell with the most visits the robot would reach while they last
    (:meth:`values`: the goal's probability times the chance the stay outlasts the
    robot's lateness; a visit the robot has warned counts no more, so a guard who has
    warned one visitor moves on to one nobody has warned). The target in hand is kept
    while it stays a candidate and is worth at least the best less ``switch_margin``
    (a warned visit: while no other is worth anything).

    The interface of :class:`Anticipator` as the agents use it: :meth:`observe` takes
    one floor position (or None) per person slot.
    """

    def __init__(
        self,
        grid: CellGrid,
        restricted_cells: tuple[int, ...],
        config: AnticipationConfig,
        people: int,
        home: int | None = None,
    ):
        if people < 1:
            raise ValueError(f"people must be >= 1, got {people}")
        self.slots = [Anticipator(grid, restricted_cells, config, home) for _ in range(people)]
        self.config = config
        self.target: int | None = None
        self.standby: int | None = None
        self.stamp_s: float | None = None  # the last observation's time
        # per slot: (cell, since when the robot is in it with the person), and the
        # cell of the person's visit under way that the robot has warned
        self._with: list[tuple[int, float] | None] = [None] * people
        self._served: list[int | None] = [None] * people

    @classmethod
    def for_task(cls, task: Any) -> PeopleAnticipator | None:
        """The task's layer, or None for ``person_model: thesis``."""
        if getattr(task, "person_model", "thesis") != "goal":
            return None
        return cls(task.grid, task.restricted_cells, task.anticipation, task.people, task.rest_cell)

    def observe(
        self,
        t: float,
        positions_m: Sequence[tuple[float, float] | None],
        robot_cell: int | None = None,
    ) -> bool:
        """Each slot's floor position at ``t`` (None: not seen; missing slots are not
        seen); returns whether the robot's target changed."""
        self.stamp_s = t
        for k, slot in enumerate(self.slots):
            slot.track_goal(t, positions_m[k] if k < len(positions_m) else None, robot_cell)
            self._note_served(k, t, robot_cell)
        before, held = self.target, self.standby
        self.target = self._choose(robot_cell)
        first = self.slots[0]
        waiting = [] if self.target is not None else first.seen([s.estimate for s in self.slots])
        self.standby = first.choose_standby(waiting, robot_cell, held)
        return self.target != before or self.standby != held

    def _note_served(self, k: int, t: float, robot_cell: int | None) -> None:
        """Slot ``k``'s visit under way is warned once the robot has been in its cell
        with the person ``serve_s``; a new visit (another cell, or out and in again)
        is not."""
        est = self.slots[k].estimate
        inside = None if est is None else est.inside
        if inside is None or inside != self._served[k]:
            self._served[k] = None
        if inside is None or robot_cell != inside:
            self._with[k] = None
            return
        with_k = self._with[k]
        if with_k is None or with_k[0] != inside:
            self._with[k] = with_k = (inside, t)
        if t - with_k[1] >= self.config.serve_s:
            self._served[k] = inside

    def _choose(self, robot_cell: int | None) -> int | None:
        values = self.values(robot_cell)
        if not values:
            return None
        best = max(values, key=lambda c: (values[c], -c))
        held = self.target
        if held in values:  # kept within the margin; a warned visit only when no other
            v, top = values[held], values[best]  # is worth anything either
            if v == top or (v > 0 and v >= top - self.config.switch_margin):
                return held
        return best

    def values(self, robot_cell: int | None) -> dict[int, float]:
        """What heading for each candidate cell (a person's target: a visit under way
        or a likely one) is worth: the chance of a visit there that the robot reaches
        while it lasts, summed over the people. A person's term is P(goal = c) times
        the chance their stay outlasts the robot's lateness (its trip time into c minus
        the person's time to entry, 0 for a visit under way) under an exponential stay
        of mean ``stay_mean_s``; nothing for a visit the robot has warned (``serve_s``
        with them in the cell)."""
        cfg, first = self.config, self.slots[0]
        values: dict[int, float] = {}
        for k, slot in enumerate(self.slots):
            est, c = slot.estimate, slot.target
            if c is None or est is None:
                continue
            under_way = est.inside == c
            if under_way and self._served[k] == c:
                values.setdefault(c, 0.0)
                continue
            late = first.trip_s(robot_cell, c) - (0.0 if under_way else est.forecast(c).eta_s)
            reach = 1.0 if late <= 0 else math.exp(-late / cfg.stay_mean_s)
            values[c] = values.get(c, 0.0) + est.p(c) * reach
        return values

    def advise(self, robot_cell: int | None, policy_action: str | None = None) -> str | None:
        """As :meth:`Anticipator.advise`, for the chosen target; without one, the
        policy's move into a restricted cell is held back when none of the people seen
        is heading there."""
        if robot_cell is None:
            return None
        first = self.slots[0]
        if self.target is not None:
            return first.move_to(robot_cell, self.target)
        estimates = [s.estimate for s in self.slots]
        return first.wait(robot_cell, self.standby, policy_action, estimates)

    def note(self) -> dict[str, Any] | None:
        """For the step record: the target and each slot's goal probabilities, as of the
        last observation (``at_s``)."""
        notes = [s.note() for s in self.slots]
        if all(n is None for n in notes):
            return None
        return {
            "at_s": None if self.stamp_s is None else round(self.stamp_s, 3),
            "target": self.target,
            "standby": self.standby,
            "p_goal": [None if n is None else n["p_goal"] for n in notes],
        }
