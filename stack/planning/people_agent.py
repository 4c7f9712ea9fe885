"""The planner at run time for a task with several people (issue 16): the online planner.

The n-person task's flat model is too large to solve offline (docs/MODEL.md), so
:class:`PeopleAgent` keeps the factored belief (:class:`~stack.planning.factored.PeopleBelief`)
and decides at every step with :class:`~stack.planning.online.OnlinePlanner`. It has the
interface of :class:`~stack.planning.agent.PlannerAgent` that the step machine
(:mod:`stack.planning.stepper`) and the planner node use: ``decide``, ``observe``,
``record``, ``save`` / ``restore``, ``step``, ``phase``, ``action``.

Observations: the robot's label, and one (person, velocity) label pair per person slot
(``Observed.people``, from the observations node's ``"people"``, slot 0 first; the
order is the perception's person slots, docs/PERCEPTION.md). Each person's factor is
updated with its slot's labels alone; a "No person" in a cell the camera could not
see (``Observed.hidden``) or "Unseen" is folded in as for one person
(:meth:`PlannerAgent.likelihood`). An observation without ``people`` (a one-person
observations node) feeds its person label to slot 0 and leaves the other slots
unobserved.

Same belief and step, same decision: the planner's sample stream is reseeded from
``seed`` and the step number before every decision (a restarted planner decides as
the one it replaces), and by default it searches to a fixed depth (no time limit).

Pure (no rclpy).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np

from stack.planning.agent import (
    ObservationError,
    Observed,
    hidden_person,
    parse_cell,
    parse_person,
)
from stack.planning.agent_state import (
    DO_NOTHING,
    RESTARTED_NOTE,
    AgentCore,
    StateFileError,
    beyond_move_note,
    direction_labelled,
    labelled,
)
from stack.planning.anticipate import PeopleAnticipator
from stack.planning.belief import ZeroProbabilityObservation
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.model import direction_index
from stack.planning.online import OnlineConfig, OnlinePlanner
from stack.vocabulary import NO_PERSON, NOT_MOVING, OUT_OF_MAP, UNSEEN, VELOCITIES


def people_fingerprint(pm: PeopleModel) -> str:
    """A short hash of the task (the state file's check)."""
    text = json.dumps(pm.task.to_dict(), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class PeopleAgent(AgentCore):
    """Factored belief and online decisions for one deployment with n >= 2 people.

    Args:
        pm: the task's per-person tables.
        initial: the belief before the first step (default: the task's).
        config: the online planner's settings.
        anticipator: the task's anticipation layer for its people (``person_model:
            goal``; :class:`stack.planning.anticipate.PeopleAnticipator`), or None.
    """

    def __init__(
        self,
        pm: PeopleModel,
        initial: PeopleBelief | None = None,
        config: OnlineConfig | None = None,
        anticipator: PeopleAnticipator | None = None,
    ):
        config = OnlineConfig() if config is None else config
        self.pm = pm
        self.anticipator = anticipator
        self.grid = pm.task.grid
        self.start()
        self.state_of = "task"
        self.config = config
        self.planner = OnlinePlanner(pm, config)
        self.belief = PeopleBelief.initial(pm) if initial is None else initial
        if self.belief.persons.shape != (pm.people, pm.n_person):
            raise ValueError(f"initial belief must be {pm.people} x {pm.n_person} probabilities")
        self.depth = 0
        self.fingerprint = people_fingerprint(pm)

    # -- deciding --------------------------------------------------------------------
    def search(self) -> tuple[int, Any]:
        """The online planner's action for the current belief, and the actions' values;
        the search's depth goes into the step's record."""
        self.planner.reset(self.config.seed * 1_000_003 + self.step)
        d = self.planner.decide(self.belief)
        self.depth = d.depth
        return d.action, d.values

    def update_belief(self, observed: Observed) -> str | None:
        """The belief after the action under way and the step's observations (see the
        module docstring), as :meth:`PlannerAgent.update_belief` for one person.

        Raises:
            ObservationError: a label the model does not know; the belief is unchanged.
        """
        assert self.action is not None
        cells = self.pm.task.grid.cells
        robot = parse_cell(observed.robot, OUT_OF_MAP, "robot cell", cells)
        slots = self.slot_labels(observed)
        lik = np.stack([self.likelihood(observed, p, v) for p, v in slots])
        note = None
        belief, action, r = self.belief, self.action, self.pm.model.robot_index(robot)
        if robot is not None and not self.pm.robot_T[action, belief.robot, r] > 0.0:
            # further than the action's one move (a trip): as PlannerAgent.update_belief
            belief, action = PeopleBelief(r, belief.persons), DO_NOTHING
            note = beyond_move_note(robot)
        try:
            self.belief = belief.update_likelihood(self.pm, action, r, lik)
        except ZeroProbabilityObservation:
            note = RESTARTED_NOTE
            persons = [parse_person(p, v, cells) for p, v in slots]
            self.belief = PeopleBelief.certain(self.pm, robot, persons)
        return note

    def slot_labels(self, observed: Observed) -> list[tuple[str, str]]:
        """(person, velocity) per slot, checked (an observation without ``people``:
        its person in slot 0, the others "Unseen")."""
        n = self.pm.people
        slots = list(observed.people) or [(observed.person, observed.velocity)]
        if len(slots) > n:
            raise ObservationError(f"observation has {len(slots)} people, the task {n}")
        slots += [(UNSEEN, NOT_MOVING)] * (n - len(slots))
        for p, v in slots:
            parse_person(p, v, self.pm.task.grid.cells)
        return slots

    def likelihood(self, observed: Observed, person: str, velocity: str) -> np.ndarray:
        """(n_person,): P(slot's labels | person state), with the camera's hidden cells
        folded in for "No person" and "Unseen" (as :meth:`PlannerAgent.likelihood`)."""
        pm, m = self.pm, self.pm.model
        z_v = VELOCITIES.index(velocity)
        if person not in (NO_PERSON, UNSEEN):
            return pm.observation_likelihood(m.position_index(int(person)), z_v)
        lik = pm.observation_likelihood(m.n_cells, z_v)
        hidden = hidden_person(m, person, velocity, observed.hidden)
        if hidden is None:
            return lik
        h, l_absent = hidden
        hs = np.repeat(h, 5)
        return (1.0 - hs) * lik + hs * l_absent

    # -- what the node publishes ------------------------------------------------------
    def marginals(self) -> dict[str, dict[str, float]]:
        """The robot's cell and each person's cell and direction (``person_1``, ...)."""
        m = self.pm.model
        out = {"robot": {m.robot_label(self.belief.robot): 1.0}}
        for i, row in enumerate(self.belief.persons):
            t = row.reshape(m.n_cells + 1, 5)
            out[f"person_{i + 1}"] = labelled(m.position_label, t.sum(axis=1))
            out[f"direction_{i + 1}"] = direction_labelled(t.sum(axis=0))
        return out

    def search_note(self) -> dict[str, Any]:
        """The record's note of the search: its depth."""
        return {"depth": self.depth}

    # -- persistence ------------------------------------------------------------------
    def belief_state(self) -> dict[str, Any]:
        return {"robot": self.belief.robot, "persons": self.belief.persons.tolist()}

    def read_belief(self, data: dict[str, Any]) -> PeopleBelief:
        persons = np.asarray(data["persons"], float)  # read before the robot, as ever
        return PeopleBelief(int(data["robot"]), persons)

    def check_belief(self, path: Path, belief: PeopleBelief, values: Any) -> list[float]:
        """The state file's belief, checked (see :meth:`restore`).

        Raises:
            StateFileError: not one distribution per person, or an unknown robot value.
        """
        pm, persons, robot = self.pm, belief.persons, belief.robot
        if persons.shape != (pm.people, pm.n_person) or not np.allclose(persons.sum(axis=1), 1):
            raise StateFileError(f"{path}: the belief is not one distribution per person")
        if not np.all(np.isfinite(persons)) or np.any(persons < 0):
            raise StateFileError(f"{path}: the belief holds negative or non-finite numbers")
        if not 0 <= robot < pm.n_robot:
            raise StateFileError(f"{path}: unknown robot value {robot}")
        return values


def initial_people_belief(
    pm: PeopleModel, robot: int | None, person: int | None, direction: str
) -> PeopleBelief:
    """Every person alike at ``person`` (None: nobody) with ``direction``."""
    direction_index(direction)  # a clear error for an unknown direction
    return PeopleBelief.certain(pm, robot, [(person, direction)] * pm.people)
