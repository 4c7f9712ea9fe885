"""The planner at run time: a policy, a belief, and one decision per step (section 4.3).

Pure (no rclpy): :mod:`stack.planning.node_planner` adapts it to ROS.

A step is: choose an action from the current belief, let the robot carry it out,
read the observations (robot cell, person cell, person velocity), update the belief.
The agent's whole state (belief, step, phase, last action) is a small JSON document
that is written atomically after every change, so a restarted planner resumes where
it stopped instead of from the initial belief.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stack.planning import belief as belief_ops
from stack.planning.agent_state import (
    DO_NOTHING,
    RESTARTED_NOTE,
    AgentCore,
    beyond_move_note,
    direction_labelled,
    labelled,
)
from stack.planning.agent_state import StateFileError as StateFileError
from stack.planning.agent_state import read_state as read_state
from stack.planning.anticipate import Anticipator, PeopleAnticipator
from stack.planning.model import FactoredModel
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP
from stack.planning.replay import TIE_TOLERANCE, policy_chooser
from stack.vocabulary import NO_PERSON, NOT_MOVING, OUT_OF_MAP, UNSEEN, VELOCITIES, parse_hidden


class ObservationError(ValueError):
    """An observation the planner cannot use (unknown label), named in the message."""


@dataclass(frozen=True)
class Observed:
    """One step's observations as labels (as the thesis's tables print them).

    ``hidden`` maps cells the camera could not see at this step to the fraction of the
    cell hidden (the robot's shadow, the image edge); a person label "Unseen" means
    the camera could not look at all. Both say what "No person" is worth: nothing,
    where the camera could not have seen the person.
    """

    robot: str  # "1".."12" or "Out of the map"
    person: str  # "1".."12", "No person" or "Unseen"
    velocity: str  # "Not moving" or "East higher", ...
    hidden: tuple[tuple[int, float], ...] = ()
    source: str = ""
    people: tuple[tuple[str, str], ...] = ()  # (person, velocity) per person slot (issue 16)
    position_m: tuple[float, float] | None = None  # the person's floor point, when measured
    # each slot's floor point (None: not measured), slot 0 first; () without slots
    people_positions_m: tuple[tuple[float, float] | None, ...] = ()
    # the stamp of the camera frame the labels come from (None: none): the latency
    # from camera to decision in the step's record
    frame_stamp_s: float | None = None

    @classmethod
    def from_dict(cls, data: Any) -> Observed:
        """Parse the observations node's JSON object.

        Raises:
            ObservationError: a missing key or a label of the wrong type.
        """
        if not isinstance(data, dict):
            raise ObservationError(f"observation must be an object, got {type(data).__name__}")
        try:
            labels = {k: data[k] for k in ("robot", "person", "velocity")}
        except KeyError as err:
            raise ObservationError(f"observation without {err.args[0]!r}: {data}") from None
        if not all(isinstance(v, str) for v in labels.values()):
            raise ObservationError(f"observation labels must be strings: {labels}")
        try:
            parsed = parse_hidden(data.get("hidden"))
        except ValueError as err:
            raise ObservationError(str(err)) from None
        source = data.get("source", "")
        frame = data.get("frame_stamp_s")
        frame_s = float(frame) if isinstance(frame, int | float) and math.isfinite(frame) else None
        return cls(
            labels["robot"], labels["person"], labels["velocity"], parsed,
            source if isinstance(source, str) else "", _people(data.get("people")),
            _position(data.get("person_position_m")),
            tuple(_position(p.get("position_m")) for p in data.get("people") or ()),
            frame_s,
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "robot": self.robot,
            "person": self.person,
            "velocity": self.velocity,
        }
        if self.hidden:
            out["hidden"] = {str(c): round(f, 3) for c, f in self.hidden}
        if self.source:
            out["source"] = self.source
        if self.people:
            out["people"] = [{"person": p, "velocity": v} for p, v in self.people]
        if self.frame_stamp_s is not None:
            out["frame_stamp_s"] = round(self.frame_stamp_s, 6)
        return out


def _people(data: Any) -> tuple[tuple[str, str], ...]:
    """The observation's ``people`` list (absent: ()).

    Raises:
        ObservationError: not a list of {"person": str, "velocity": str} objects.
    """
    if data is None:
        return ()
    if not isinstance(data, list):
        raise ObservationError(f"observation 'people' must be a list, got {type(data).__name__}")
    out = []
    for i, item in enumerate(data):
        if not isinstance(item, dict) or not all(
            isinstance(item.get(k), str) for k in ("person", "velocity")
        ):
            raise ObservationError(
                f"observation 'people' entry {i + 1} must have string 'person' and 'velocity'"
            )
        out.append((item["person"], item["velocity"]))
    return tuple(out)


def _position(value: Any) -> tuple[float, float] | None:
    """A floor point [x, y] of finite numbers, else None (no position is no evidence)."""
    if not isinstance(value, list | tuple) or len(value) != 2:
        return None
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
        return None
    x, y = float(value[0]), float(value[1])
    return (x, y) if np.isfinite(x) and np.isfinite(y) else None


def parse_cell(label: str, none_label: str, what: str, cells: tuple[int, ...]) -> int | None:
    if label == none_label:
        return None
    if label.isdigit() and int(label) in cells:
        return int(label)
    raise ObservationError(
        f"unknown {what} {label!r}: a cell {cells[0]}..{cells[-1]} or {none_label!r}"
    )


def parse_person(person: str, velocity: str, cells: tuple[int, ...]) -> tuple[int | None, str]:
    """A person's labels, checked: the person's cell (None: "No person" or "Unseen") and
    the direction of the velocity ("Not moving", "East", ...).

    Raises:
        ObservationError: an unknown person cell or velocity.
    """
    cell = None if person == UNSEEN else parse_cell(person, NO_PERSON, "person cell", cells)
    if velocity not in VELOCITIES:
        raise ObservationError(f"unknown velocity {velocity!r}; known: {VELOCITIES}")
    return cell, velocity.split(" ")[0] if velocity != NOT_MOVING else NOT_MOVING


def hidden_person(
    model: FactoredModel, person: str, velocity: str, hidden: tuple[tuple[int, float], ...]
) -> tuple[np.ndarray, float] | None:
    """What the camera could not see of a person it labelled ``person``, for every agent
    (:meth:`PlannerAgent.likelihood`): None when the label is a cell or the camera saw
    every cell; else the fraction h of each person position hidden (``hidden``, and 1
    everywhere for "Unseen"), and P("No person", ``velocity`` | the person absent)."""
    if person not in (NO_PERSON, UNSEEN):
        return None
    h = np.zeros(model.n_cells + 1)
    if person == UNSEEN:
        h[: model.n_cells] = 1.0
    for cell, frac in hidden:
        if cell in model.task.grid.cells:
            k = model.position_index(cell)
            h[k] = max(h[k], frac)
    if not h.any():
        return None
    absent = model.n_cells
    # the same for every direction
    v = VELOCITIES.index(velocity)
    return h, float(model.obs_position[absent, absent] * model.obs_velocity[absent, 0, v])


def model_fingerprint(pomdp: POMDP) -> str:
    """A short hash of the model's reward and initial belief sizes (state file check)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(pomdp.R).tobytes())
    h.update(str((pomdp.n_states, pomdp.n_actions, pomdp.n_observations)).encode())
    return h.hexdigest()[:16]


class PlannerAgent(AgentCore):
    """Belief tracking and action choice for one deployment.

    Args:
        model, pomdp: the factored and flat task model.
        policy: alpha vectors for ``pomdp``.
        initial_belief: the belief before the first step (default: the task's).
        tie_tolerance: actions within this fraction of the best are ties; ties prefer
            "Do nothing" (see :func:`stack.planning.replay.policy_chooser`).
        anticipator: the task's anticipation layer (``person_model: goal``;
            :mod:`stack.planning.anticipate`), or None: the policy alone.
    """

    def __init__(
        self,
        model: FactoredModel,
        pomdp: POMDP,
        policy: AlphaPolicy,
        initial_belief: np.ndarray | None = None,
        tie_tolerance: float = TIE_TOLERANCE,
        anticipator: Anticipator | None = None,
    ):
        self.model, self.pomdp, self.policy = model, pomdp, policy
        self.anticipator: Anticipator | PeopleAnticipator | None = anticipator
        self.grid = model.task.grid
        self.start()
        self.n_actions = pomdp.n_actions
        self._choose = policy_chooser(
            policy, pomdp, lookahead=True, tie_tolerance=tie_tolerance, blocks=model.robot_blocks()
        )
        b0 = pomdp.b0 if initial_belief is None else np.asarray(initial_belief, float)
        if b0.shape != (pomdp.n_states,) or not np.isclose(b0.sum(), 1.0):
            raise ValueError(f"initial belief must be {pomdp.n_states} probabilities summing to 1")
        self.belief = b0.copy()
        self.fingerprint = model_fingerprint(pomdp)
        idx = np.unravel_index(np.arange(pomdp.n_states), model.state_shape)
        self._robot_of_state = idx[0]
        self._person_of_state = idx[1] if model.people >= 1 else np.zeros_like(idx[0])

    # -- deciding --------------------------------------------------------------------
    def search(self) -> tuple[int, Any]:
        """The policy's action for the current belief, and every action's value."""
        return self._choose(self.belief)

    def update_belief(self, observed: Observed) -> str | None:
        """The belief after the action under way and ``observed`` (see :meth:`observe`).

        An observation the model gives zero probability (e.g. the person seen two cells
        from where it could be) does not stop the robot: the belief restarts from what
        was observed, and the record says so.

        Raises:
            ObservationError: a label the model does not know; the belief is unchanged.
        """
        assert self.action is not None
        z, robot, person, direction = self._observation_index(observed)
        if robot is None and self._robot_probability(None) == 0.0:
            raise ObservationError(
                "robot 'Out of the map' is impossible from this belief: observation ignored"
            )
        note = None
        belief, action = self.belief, self.action
        if robot is not None and self._robot_probability(robot) == 0.0:
            # the robot went further than the action's one move (a trip crossing cells,
            # a push): it is observed exactly and the people move whatever it does, so
            # the belief moves it to where it is and the update is Do nothing's
            belief, action = self._relocated(robot), DO_NOTHING
            note = beyond_move_note(robot)
        try:
            lik = self.likelihood(observed, z)
            self.belief = belief_ops.update_with_likelihood(self.pomdp, belief, action, lik)
        except belief_ops.ZeroProbabilityObservation:
            note = RESTARTED_NOTE
            self.belief = self.model.initial_belief(
                robot, [(person, direction)] * self.model.people
            )
        return note

    def _relocated(self, robot: int) -> np.ndarray:
        """The belief with all its robot mass in ``robot``'s cell."""
        t = self.belief.reshape(self.model.state_shape)
        out = np.zeros_like(t)
        out[self.model.robot_index(robot)] = t.sum(axis=0)
        return out.ravel()

    def _robot_probability(self, cell: int | None) -> float:
        """P(robot in ``cell`` after the action under way | belief): the robot's
        marginal through the robot's own transition (people do not move it)."""
        assert self.action is not None
        robot = self.belief.reshape(self.model.state_shape[0], -1).sum(axis=1)
        return float(robot @ self.model.robot_T[self.action][:, self.model.robot_index(cell)])

    def likelihood(self, observed: Observed, z: int | None = None) -> np.ndarray:
        """P(observation | state) over the flat states, with the camera's blind cells.

        A person in a cell the camera could not see (fraction h of the cell hidden)
        gives "No person" as often as an absent person does: the likelihood there is
        (1 - h) P(z | s) + h P(z | s with the person absent). "Unseen" is h = 1
        everywhere: only the robot's cell is observed and the person's belief follows
        the transition alone. docs/MODEL.md, "What the camera could not see".
        """
        if self.action is None:
            raise RuntimeError("likelihood() without an action under way")
        if z is None:
            z = self._observation_index(observed)[0]
        lik = self.pomdp.O[self.action][:, z].toarray().ravel()
        hidden = (
            None
            if self.model.people != 1
            else hidden_person(self.model, observed.person, observed.velocity, observed.hidden)
        )
        if hidden is None:
            return lik
        h, l_absent = hidden
        # the robot's cell is observed exactly
        robot_ok = self._robot_of_state == np.unravel_index(z, self.model.obs_shape)[0]
        hs = h[self._person_of_state]
        return (1.0 - hs) * lik + hs * l_absent * robot_ok

    def _observation_index(self, o: Observed) -> tuple[int, int | None, int | None, str]:
        cells = self.model.task.grid.cells
        robot = parse_cell(o.robot, OUT_OF_MAP, "robot cell", cells)
        person, direction = parse_person(o.person, o.velocity, cells)
        z = self.model.observation_index(robot, [(person, o.velocity)] * self.model.people)
        return z, robot, person, direction

    # -- what the node publishes ------------------------------------------------------
    def marginals(self) -> dict[str, dict[str, float]]:
        """The belief per variable: robot cell, and each person's cell and direction."""
        t = self.belief.reshape(self.model.state_shape)
        axes = range(t.ndim)
        out = {"robot": self._labelled(t.sum(axis=tuple(a for a in axes if a != 0)), "robot")}
        for i in range(self.model.people):
            suffix = "" if self.model.people == 1 else f"_{i + 1}"
            pa, da = 1 + 2 * i, 2 + 2 * i
            out["person" + suffix] = self._labelled(
                t.sum(axis=tuple(a for a in axes if a != pa)), "person"
            )
            d = t.sum(axis=tuple(a for a in axes if a != da))
            out["direction" + suffix] = direction_labelled(d)
        return out

    def _labelled(self, p: np.ndarray, what: str) -> dict[str, float]:
        label = self.model.robot_label if what == "robot" else self.model.position_label
        return labelled(label, p)

    # -- persistence ------------------------------------------------------------------
    def belief_state(self) -> dict[str, Any]:
        return {"belief": [float(v) for v in self.belief]}

    def read_belief(self, data: dict[str, Any]) -> np.ndarray:
        return np.asarray(data["belief"], float)

    def read_values(self, data: dict[str, Any]) -> Any:
        return data.get("values", [])

    def check_belief(self, path: Path, belief: np.ndarray, values: Any) -> list[float]:
        """The state file's belief and values, checked (see :meth:`restore`).

        Raises:
            StateFileError: not a distribution over the states, or values not numbers.
        """
        if belief.shape != (self.pomdp.n_states,) or not np.isclose(belief.sum(), 1.0):
            raise StateFileError(f"{path}: the belief is not a distribution over the states")
        if not np.all(np.isfinite(belief)) or np.any(belief < 0):
            raise StateFileError(f"{path}: the belief holds negative or non-finite numbers")
        if not isinstance(values, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in values
        ):
            raise StateFileError(f"{path}: values must be a list of numbers")
        return [float(v) for v in values]
