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
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stack.config import read_text_capped
from stack.files import write_atomic
from stack.planning import belief as belief_ops
from stack.planning.anticipate import Anticipating, Anticipator, PeopleAnticipator
from stack.planning.model import FactoredModel
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP
from stack.planning.replay import TIE_TOLERANCE, policy_chooser
from stack.vocabulary import (
    ACTIONS,
    DIRECTIONS,
    NO_PERSON,
    NOT_MOVING,
    OUT_OF_MAP,
    UNSEEN,
    VELOCITIES,
    parse_hidden,
)


class ObservationError(ValueError):
    """An observation the planner cannot use (unknown label), named in the message."""


class StateFileError(ValueError):
    """A planner state file that does not belong to this model or is unreadable."""


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


def save_state(path: str | Path, state: dict[str, Any]) -> None:
    """Write a planner's state atomically (a crash mid-write leaves the old file intact)."""
    write_atomic(path, json.dumps(state))


def read_state(path: Path) -> dict[str, Any] | None:
    """A planner's state file as a JSON object; None when there is none.

    Raises:
        StateFileError: unreadable, or not a JSON object.
    """
    if not path.exists():
        return None
    try:
        data = json.loads(read_text_capped(path))
    except (OSError, ValueError) as err:
        raise StateFileError(f"{path}: unreadable planner state ({err})") from None
    if not isinstance(data, dict):
        raise StateFileError(f"{path}: unreadable planner state (not a JSON object)")
    return data


def check_progress(path: Path, step: int, phase: str, action: Any, n_actions: int) -> None:
    """The step, phase and action of a state file (both agents' states share them).

    Raises:
        StateFileError: naming the bad field.
    """
    if phase not in ("start", "acting", "observing", "done"):
        raise StateFileError(f"{path}: unknown phase {phase!r}")
    if step < 0:
        raise StateFileError(f"{path}: negative step {step}")
    if action is not None and (
        isinstance(action, bool) or not isinstance(action, int) or not 0 <= action < n_actions
    ):
        raise StateFileError(f"{path}: unknown action {action!r}")


def model_fingerprint(pomdp: POMDP) -> str:
    """A short hash of the model's reward and initial belief sizes (state file check)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(pomdp.R).tobytes())
    h.update(str((pomdp.n_states, pomdp.n_actions, pomdp.n_observations)).encode())
    return h.hexdigest()[:16]


def beyond_move_note(robot: int) -> str:
    """The step record's note when the robot was seen beyond its action's one move."""
    return f"robot observed in cell {robot}, beyond the action's move: belief moved there"


class PlannerAgent(Anticipating):
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
        self.robot_cell: int | None = None  # the last observed robot cell
        self.anticipated: dict[str, Any] | None = None  # the last decision's layer note
        self._choose = policy_chooser(
            policy, pomdp, lookahead=True, tie_tolerance=tie_tolerance, blocks=model.robot_blocks()
        )
        b0 = pomdp.b0 if initial_belief is None else np.asarray(initial_belief, float)
        if b0.shape != (pomdp.n_states,) or not np.isclose(b0.sum(), 1.0):
            raise ValueError(f"initial belief must be {pomdp.n_states} probabilities summing to 1")
        self.belief = b0.copy()
        self.step = 0  # steps completed (observed)
        self.phase = "start"  # start | acting | observing | done
        self.action: int | None = None  # the action of the step under way (the model's)
        # what navigation is asked to do for it: the action's name, or a trip ("To 1")
        # whose first move is ``action``
        self.command: str | None = None
        self.values: list[float] = []
        self.fingerprint = model_fingerprint(pomdp)
        idx = np.unravel_index(np.arange(pomdp.n_states), model.state_shape)
        self._robot_of_state = idx[0]
        self._person_of_state = idx[1] if model.people >= 1 else np.zeros_like(idx[0])

    # -- deciding --------------------------------------------------------------------
    def decide(self) -> int:
        """Choose the next action from the current belief; the step is now under way."""
        a, q = self._choose(self.belief)
        self.action, self.values = self.advised(int(a)), [float(v) for v in q]
        self.phase = "acting"
        return self.action

    def observe(self, observed: Observed) -> dict[str, Any]:
        """Update the belief with the observations that followed the current action.

        An observation the model gives zero probability (e.g. the person seen two cells
        from where it could be) does not stop the robot: the belief restarts from what
        was observed, and the record says so.

        Returns:
            The step's record (see :meth:`record`).

        Raises:
            ObservationError: a label the model does not know; the belief is unchanged.
            RuntimeError: no action is under way.
        """
        if self.action is None:
            raise RuntimeError("observe() without an action under way; call decide() first")
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
            belief, action = self._relocated(robot), ACTIONS.index("Do nothing")
            note = beyond_move_note(robot)
        try:
            lik = self.likelihood(observed, z)
            self.belief = belief_ops.update_with_likelihood(self.pomdp, belief, action, lik)
        except belief_ops.ZeroProbabilityObservation:
            note = "observation impossible under the model: belief restarted from it"
            self.belief = self.model.initial_belief(
                robot, [(person, direction)] * self.model.people
            )
        self.step += 1
        record = self.record(observed, note)
        self.phase = "observing"  # until the next decide()
        return record

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
        if observed.person not in (NO_PERSON, UNSEEN) or self.model.people != 1:
            return lik
        cells = self.model.task.grid.cells
        h = np.zeros(self.model.n_cells + 1)
        if observed.person == UNSEEN:
            h[: self.model.n_cells] = 1.0
        for cell, frac in observed.hidden:
            if cell in cells:
                h[self.model.position_index(cell)] = max(h[self.model.position_index(cell)], frac)
        if not h.any():
            return lik
        absent = self.model.n_cells
        # P(No person, velocity | person absent) (the same for every direction)
        l_absent = float(
            self.model.obs_position[absent, absent]
            * self.model.obs_velocity[absent, 0, VELOCITIES.index(observed.velocity)]
        )
        # the robot's cell is observed exactly
        robot_ok = self._robot_of_state == np.unravel_index(z, self.model.obs_shape)[0]
        hs = h[self._person_of_state]
        return (1.0 - hs) * lik + hs * l_absent * robot_ok

    def _observation_index(self, o: Observed) -> tuple[int, int | None, int | None, str]:
        cells = self.model.task.grid.cells
        robot = parse_cell(o.robot, OUT_OF_MAP, "robot cell", cells)
        person = (
            None if o.person == UNSEEN else parse_cell(o.person, NO_PERSON, "person cell", cells)
        )
        if o.velocity not in VELOCITIES:
            raise ObservationError(f"unknown velocity {o.velocity!r}; known: {VELOCITIES}")
        direction = o.velocity.split(" ")[0] if o.velocity != NOT_MOVING else NOT_MOVING
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
            out["direction" + suffix] = {DIRECTIONS[k]: round(float(d[k]), 6) for k in range(5)}
        return out

    def _labelled(self, p: np.ndarray, what: str) -> dict[str, float]:
        label = self.model.robot_label if what == "robot" else self.model.position_label
        return {label(i): round(float(v), 6) for i, v in enumerate(p)}

    def record(self, observed: Observed | None, note: str | None = None) -> dict[str, Any]:
        """The step's record: step, action, observations, belief after them, values."""
        out = {
            "step": self.step,
            "action": ACTIONS[self.action] if self.action is not None else None,
            "observation": observed.to_dict() if observed else None,
            "belief": self.marginals(),
            "values": [round(v, 4) for v in self.values],
            "note": note,
        }
        if self.anticipated is not None:  # person_model: goal only (other records unchanged)
            out["anticipation"] = self.anticipated
        return out

    # -- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "fingerprint": self.fingerprint,
            "step": self.step,
            "phase": self.phase,
            "action": self.action,
            "command": self.command,
            "values": self.values,
            "belief": [float(v) for v in self.belief],
        }

    def save(self, path: str | Path) -> None:
        """Write the state atomically (a crash mid-write leaves the old file intact)."""
        save_state(path, self.state())

    def restore(self, path: str | Path) -> bool:
        """Resume from a state file; False when there is none.

        Raises:
            StateFileError: unreadable, or written for another model.
        """
        path = Path(path)
        data = read_state(path)
        if data is None:
            return False
        try:
            belief = np.asarray(data["belief"], float)
            step, phase, action = int(data["step"]), str(data["phase"]), data["action"]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise StateFileError(f"{path}: unreadable planner state ({err})") from None
        if data.get("fingerprint") != self.fingerprint:
            raise StateFileError(f"{path}: planner state of another model")
        if belief.shape != (self.pomdp.n_states,) or not np.isclose(belief.sum(), 1.0):
            raise StateFileError(f"{path}: the belief is not a distribution over the states")
        check_progress(path, step, phase, action, self.pomdp.n_actions)
        if not np.all(np.isfinite(belief)) or np.any(belief < 0):
            raise StateFileError(f"{path}: the belief holds negative or non-finite numbers")
        values = data.get("values", [])
        if not isinstance(values, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in values
        ):
            raise StateFileError(f"{path}: values must be a list of numbers")
        self.belief, self.step, self.phase = belief, step, phase
        self.action = None if action is None else int(action)
        self.restore_command(data.get("command"))
        self.values = [float(v) for v in values]
        return True
