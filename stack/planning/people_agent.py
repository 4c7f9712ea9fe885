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
    StateFileError,
    beyond_move_note,
    check_progress,
    parse_cell,
    read_state,
    save_state,
)
from stack.planning.anticipate import Anticipating, PeopleAnticipator
from stack.planning.belief import ZeroProbabilityObservation
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.model import direction_index
from stack.planning.online import OnlineConfig, OnlinePlanner
from stack.vocabulary import (
    ACTIONS,
    DIRECTIONS,
    NO_PERSON,
    NOT_MOVING,
    OUT_OF_MAP,
    UNSEEN,
    VELOCITIES,
)


def people_fingerprint(pm: PeopleModel) -> str:
    """A short hash of the task (the state file's check)."""
    text = json.dumps(pm.task.to_dict(), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class PeopleAgent(Anticipating):
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
        self.robot_cell: int | None = None
        self.anticipated: dict[str, Any] | None = None
        self.command: str | None = None
        self.config = config
        self.planner = OnlinePlanner(pm, config)
        self.belief = PeopleBelief.initial(pm) if initial is None else initial
        if self.belief.persons.shape != (pm.people, pm.n_person):
            raise ValueError(f"initial belief must be {pm.people} x {pm.n_person} probabilities")
        self.step = 0
        self.phase = "start"
        self.action: int | None = None
        self.values: list[float] = []
        self.depth = 0
        self.fingerprint = people_fingerprint(pm)

    # -- deciding --------------------------------------------------------------------
    def decide(self) -> int:
        """The next action from the current belief; the step is now under way."""
        self.planner.reset(self.config.seed * 1_000_003 + self.step)
        d = self.planner.decide(self.belief)
        self.action = self.advised(int(d.action))
        self.values, self.depth = [float(v) for v in d.values], d.depth
        self.phase = "acting"
        return self.action

    def observe(self, observed: Observed) -> dict[str, Any]:
        """Update the belief with the step's observations (see the module docstring).

        Returns:
            The step's record.

        Raises:
            ObservationError: a label the model does not know; the belief is unchanged.
            RuntimeError: no action is under way.
        """
        if self.action is None:
            raise RuntimeError("observe() without an action under way; call decide() first")
        cells = self.pm.task.grid.cells
        robot = parse_cell(observed.robot, OUT_OF_MAP, "robot cell", cells)
        slots = self.slot_labels(observed)
        lik = np.stack([self.likelihood(observed, p, v) for p, v in slots])
        note = None
        belief, action, r = self.belief, self.action, self.pm.model.robot_index(robot)
        if robot is not None and not self.pm.robot_T[action, belief.robot, r] > 0.0:
            # further than the action's one move (a trip): as PlannerAgent.observe
            belief, action = PeopleBelief(r, belief.persons), ACTIONS.index("Do nothing")
            note = beyond_move_note(robot)
        try:
            self.belief = belief.update_likelihood(self.pm, action, r, lik)
        except ZeroProbabilityObservation:
            note = "observation impossible under the model: belief restarted from it"
            persons = []
            for p, v in slots:
                cell = None if p in (NO_PERSON, UNSEEN) else int(p)
                persons.append((cell, v.split(" ")[0] if v != NOT_MOVING else NOT_MOVING))
            self.belief = PeopleBelief.certain(self.pm, robot, persons)
        self.step += 1
        record = self.record(observed, note)
        self.phase = "observing"
        return record

    def slot_labels(self, observed: Observed) -> list[tuple[str, str]]:
        """(person, velocity) per slot, checked (an observation without ``people``:
        its person in slot 0, the others "Unseen")."""
        n = self.pm.people
        slots = list(observed.people) or [(observed.person, observed.velocity)]
        if len(slots) > n:
            raise ObservationError(f"observation has {len(slots)} people, the task {n}")
        slots += [(UNSEEN, NOT_MOVING)] * (n - len(slots))
        cells = self.pm.task.grid.cells
        for p, v in slots:
            if p != UNSEEN:
                parse_cell(p, NO_PERSON, "person cell", cells)
            if v not in VELOCITIES:
                raise ObservationError(f"unknown velocity {v!r}; known: {VELOCITIES}")
        return slots

    def likelihood(self, observed: Observed, person: str, velocity: str) -> np.ndarray:
        """(n_person,): P(slot's labels | person state), with the camera's hidden cells
        folded in for "No person" and "Unseen" (as :meth:`PlannerAgent.likelihood`)."""
        pm, m = self.pm, self.pm.model
        absent = m.n_cells
        z_v = VELOCITIES.index(velocity)
        if person not in (NO_PERSON, UNSEEN):
            return pm.observation_likelihood(m.position_index(int(person)), z_v)
        lik = pm.observation_likelihood(absent, z_v)
        h = np.zeros(m.n_cells + 1)
        if person == UNSEEN:
            h[: m.n_cells] = 1.0
        for cell, frac in observed.hidden:
            if cell in pm.task.grid.cells:
                k = m.position_index(cell)
                h[k] = max(h[k], frac)
        if not h.any():
            return lik
        l_absent = float(m.obs_position[absent, absent] * m.obs_velocity[absent, 0, z_v])
        hs = np.repeat(h, 5)
        return (1.0 - hs) * lik + hs * l_absent

    # -- what the node publishes ------------------------------------------------------
    def marginals(self) -> dict[str, dict[str, float]]:
        """The robot's cell and each person's cell and direction (``person_1``, ...)."""
        m = self.pm.model
        out = {"robot": {m.robot_label(self.belief.robot): 1.0}}
        for i, row in enumerate(self.belief.persons):
            t = row.reshape(m.n_cells + 1, 5)
            out[f"person_{i + 1}"] = {
                m.position_label(k): round(float(v), 6) for k, v in enumerate(t.sum(axis=1))
            }
            out[f"direction_{i + 1}"] = {
                DIRECTIONS[k]: round(float(v), 6) for k, v in enumerate(t.sum(axis=0))
            }
        return out

    def record(self, observed: Observed | None, note: str | None = None) -> dict[str, Any]:
        """The step's record (as :meth:`PlannerAgent.record`, with the search's depth)."""
        return {
            "step": self.step,
            "action": ACTIONS[self.action] if self.action is not None else None,
            "observation": observed.to_dict() if observed else None,
            "belief": self.marginals(),
            "values": [round(v, 4) for v in self.values],
            "depth": self.depth,
            "note": note,
        } | ({} if self.anticipated is None else {"anticipation": self.anticipated})

    # -- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "fingerprint": self.fingerprint,
            "step": self.step,
            "phase": self.phase,
            "action": self.action,
            "command": self.command,
            "values": self.values,
            "robot": self.belief.robot,
            "persons": self.belief.persons.tolist(),
        }

    def save(self, path: str | Path) -> None:
        """Write the state atomically."""
        save_state(path, self.state())

    def restore(self, path: str | Path) -> bool:
        """Resume from a state file; False when there is none.

        Raises:
            StateFileError: unreadable, or written for another task.
        """
        path = Path(path)
        data = read_state(path)
        if data is None:
            return False
        try:
            persons = np.asarray(data["persons"], float)
            robot, step = int(data["robot"]), int(data["step"])
            phase, action = str(data["phase"]), data["action"]
            values = [float(v) for v in data.get("values", [])]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise StateFileError(f"{path}: unreadable planner state ({err})") from None
        if data.get("fingerprint") != self.fingerprint:
            raise StateFileError(f"{path}: planner state of another task")
        pm = self.pm
        if persons.shape != (pm.people, pm.n_person) or not np.allclose(persons.sum(axis=1), 1):
            raise StateFileError(f"{path}: the belief is not one distribution per person")
        if not np.all(np.isfinite(persons)) or np.any(persons < 0):
            raise StateFileError(f"{path}: the belief holds negative or non-finite numbers")
        if not 0 <= robot < pm.n_robot:
            raise StateFileError(f"{path}: unknown robot value {robot}")
        check_progress(path, step, phase, action, len(ACTIONS))
        self.belief = PeopleBelief(robot, persons)
        self.step, self.phase, self.values = step, phase, values
        self.action = None if action is None else int(action)
        self.restore_command(data.get("command"))
        return True


def initial_people_belief(
    pm: PeopleModel, robot: int | None, person: int | None, direction: str
) -> PeopleBelief:
    """Every person alike at ``person`` (None: nobody) with ``direction``."""
    direction_index(direction)  # a clear error for an unknown direction
    return PeopleBelief.certain(pm, robot, [(person, direction)] * pm.people)
