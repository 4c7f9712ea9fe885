"""What every planner agent shares: a step's progress, its record and the state file.

An agent (:class:`~stack.planning.agent.PlannerAgent` for one person,
:class:`~stack.planning.people_agent.PeopleAgent` for several) holds a belief and goes
through steps: ``decide`` chooses the step's action from the belief (phase "acting"),
``observe`` updates the belief with the observations that followed it (phase
"observing") and returns the step's record. :class:`AgentCore` does all of that but
the search and the belief update, which are the agents' own (``search``,
``update_belief``), and writes and reads the state file (belief, step, phase, last
action), written atomically after every change so that a restarted planner resumes
where it stopped instead of from the initial belief.

Pure (no rclpy).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from stack.config import read_text_capped
from stack.files import write_atomic
from stack.planning.anticipating import Anticipating
from stack.vocabulary import ACTIONS, DIRECTIONS

# the state file's fields every agent has, in the file's order (then its belief's)
PROGRESS = ("fingerprint", "step", "phase", "action", "command", "values")
# the belief update of a step whose robot went beyond its action's one move
DO_NOTHING = ACTIONS.index("Do nothing")
# the record's note when the belief restarts from an observation the model rules out
RESTARTED_NOTE = "observation impossible under the model: belief restarted from it"


class StateFileError(ValueError):
    """A planner state file that does not belong to this model or is unreadable."""


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


def beyond_move_note(robot: int) -> str:
    """The step record's note when the robot was seen beyond its action's one move."""
    return f"robot observed in cell {robot}, beyond the action's move: belief moved there"


def labelled(label: Callable[[int], str], p: np.ndarray) -> dict[str, float]:
    """A marginal as the record prints it: each value's label, its probability rounded."""
    return {label(i): round(float(v), 6) for i, v in enumerate(p)}


def direction_labelled(p: np.ndarray) -> dict[str, float]:
    """A person's direction marginal (5 values) as the record prints it."""
    return labelled(DIRECTIONS.__getitem__, p)


class AgentCore(Anticipating):
    """A planner agent's steps, record and state file, around its own belief.

    A subclass calls :meth:`start` in its constructor, sets ``belief``,
    ``fingerprint`` and ``state_of`` (what a foreign state file belongs to: "model",
    "task"), and gives:

    - ``search()``: the planner's action and the actions' values for the belief;
    - ``update_belief(observed)``: the belief after the action under way and
      ``observed``, returning the record's note (None: nothing to say);
    - ``marginals()``: the belief per variable, as the record prints it;
    - ``search_note()``: the record's fields about the search (between "values" and
      "note");
    - ``belief_state()``: the state file's belief fields; ``read_belief(data)``, the
      belief in a state file's ``data``; ``check_belief(path, belief, values)``, the
      state file's belief and values (``read_values(data)``), checked.
    """

    belief: Any
    fingerprint: str
    state_of = "model"
    n_actions = len(ACTIONS)

    def start(self) -> None:
        """No step yet: before the first decision."""
        self.robot_cell = None  # the last observed robot cell
        self.anticipated = None  # the last decision's layer note
        self.step = 0  # steps completed (observed)
        self.phase = "start"  # start | acting | observing | done
        self.action = None  # the action of the step under way (the model's)
        # what navigation is asked to do for it: the action's name, or a trip ("To 1")
        # whose first move is ``action``
        self.command = None
        self.values: list[float] = []

    # -- the agent's own ----------------------------------------------------------------
    def search(self) -> tuple[int, Any]:
        raise NotImplementedError

    def update_belief(self, observed: Any) -> str | None:
        raise NotImplementedError

    def marginals(self) -> dict[str, dict[str, float]]:
        raise NotImplementedError

    def search_note(self) -> dict[str, Any]:
        return {}

    def belief_state(self) -> dict[str, Any]:
        raise NotImplementedError

    def read_belief(self, data: dict[str, Any]) -> Any:
        raise NotImplementedError

    def read_values(self, data: dict[str, Any]) -> Any:
        return [float(v) for v in data.get("values", [])]

    def check_belief(self, path: Path, belief: Any, values: Any) -> list[float]:
        raise NotImplementedError

    # -- a step -----------------------------------------------------------------------
    def decide(self) -> int:
        """Choose the next action from the current belief; the step is now under way."""
        a, values = self.search()
        self.action, self.values = self.advised(int(a)), [float(v) for v in values]
        self.phase = "acting"
        return self.action

    def observe(self, observed: Any) -> dict[str, Any]:
        """Update the belief with the observations that followed the current action.

        Returns:
            The step's record (see :meth:`record`).

        Raises:
            ObservationError: a label the model does not know; the belief is unchanged.
            RuntimeError: no action is under way.
        """
        if self.action is None:
            raise RuntimeError("observe() without an action under way; call decide() first")
        note = self.update_belief(observed)
        self.step += 1
        record = self.record(observed, note)
        self.phase = "observing"  # until the next decide()
        return record

    def record(self, observed: Any, note: str | None = None) -> dict[str, Any]:
        """The step's record: step, action, observations, belief after them, values."""
        out = {
            "step": self.step,
            "action": ACTIONS[self.action] if self.action is not None else None,
            "observation": observed.to_dict() if observed else None,
            "belief": self.marginals(),
            "values": [round(v, 4) for v in self.values],
            **self.search_note(),
            "note": note,
        }
        if self.anticipated is not None:  # person_model: goal only (other records unchanged)
            out["anticipation"] = self.anticipated
        return out

    # -- persistence ------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """The state file's content: ``PROGRESS``, then the agent's belief fields."""
        return {key: getattr(self, key) for key in PROGRESS} | self.belief_state()

    def save(self, path: str | Path) -> None:
        """Write the state atomically (a crash mid-write leaves the old file intact)."""
        save_state(path, self.state())

    def restore(self, path: str | Path) -> bool:
        """Resume from a state file; False when there is none.

        Raises:
            StateFileError: unreadable, or written for another model or task.
        """
        path = Path(path)
        data = read_state(path)
        if data is None:
            return False
        try:
            belief = self.read_belief(data)
            step, phase, action = int(data["step"]), str(data["phase"]), data["action"]
            values = self.read_values(data)
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise StateFileError(f"{path}: unreadable planner state ({err})") from None
        if data.get("fingerprint") != self.fingerprint:
            raise StateFileError(f"{path}: planner state of another {self.state_of}")
        values = self.check_belief(path, belief, values)
        check_progress(path, step, phase, action, self.n_actions)
        self.belief, self.step, self.phase = belief, step, phase
        self.action = None if action is None else int(action)
        self.restore_command(data.get("command"))
        self.values = values
        return True
