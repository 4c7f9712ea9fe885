"""The anticipation layer inside a planner agent (issue 26): the layer's advice over
the planner's action, the trip that goes out in the middle of a step, and the track the
layer reads at every observation. :class:`Anticipating` is a mixin of
:class:`~stack.planning.agent_state.AgentCore`, so one agent and several people's agent
run the same code; the layer itself is :mod:`stack.planning.anticipate`.
"""

from __future__ import annotations

from typing import Any

from stack.cells import CellGrid, first_move
from stack.planning.anticipate import Anticipator, PeopleAnticipator
from stack.vocabulary import ACTIONS, parse_trip


class Anticipating:
    """The anticipation layer in an agent (:class:`PlannerAgent`, and
    :class:`~stack.planning.people_agent.PeopleAgent` for several people): the layer's
    advice over the planner's action, the trip that goes out mid-step, and the track
    the layer reads at every observation. The agent sets ``anticipator`` (None: the
    planner alone) and ``grid``."""

    anticipator: Anticipator | PeopleAnticipator | None
    grid: CellGrid
    robot_cell: int | None
    anticipated: dict[str, Any] | None
    action: int | None
    command: str | None
    phase: str

    def advised(self, a: int) -> int:
        """The step's model action from the planner's ``a`` and the layer's advice;
        sets ``command`` (what navigation is sent: the action's name or a trip, which
        the model counts as its first move) and ``anticipated`` (the record's note)."""
        self.anticipated = None
        move: str | None = None
        if self.anticipator is not None:
            move = self.anticipator.advise(self.robot_cell, ACTIONS[a])
            note = self.anticipator.note()
            if note is not None:
                self.anticipated = {**note, "policy": ACTIONS[a], "move": move}
            if move is not None:
                dest = parse_trip(move)
                if dest is None:
                    a = ACTIONS.index(move)
                else:
                    start = self.robot_cell
                    first = None if start is None else first_move(self.grid, start, dest)
                    a = ACTIONS.index(first or "Do nothing")
        self.command = move if move is not None else ACTIONS[a]
        return a

    def revise(self) -> str | None:
        """The anticipation layer's new trip for the step under way (its target changed
        since the decision), or None: the step's command stands. Only a trip is revised
        mid-step (going there now); the rest waits for the step's end."""
        if self.anticipator is None or self.action is None or self.phase != "acting":
            return None
        policy = (self.anticipated or {}).get("policy", ACTIONS[self.action])
        move = self.anticipator.advise(self.robot_cell, policy)
        if move is None or parse_trip(move) is None or move == self.command:
            return None
        self.command = move
        if self.anticipated is None:  # no estimate yet at the decision
            self.anticipated = {**(self.anticipator.note() or {}), "policy": policy, "move": None}
        self.anticipated["revised"] = move
        return move

    def restore_command(self, command: Any) -> None:
        """``command`` from a state file, once ``action`` is restored: a trip survives a
        restart; anything else is the action's own name."""
        trip = isinstance(command, str) and parse_trip(command) in self.grid.cells
        self.command = command if trip else None if self.action is None else ACTIONS[self.action]

    def track(self, t: float, observed: Any) -> str | None:
        """Every observation (a :class:`stack.planning.agent.Observed`), step end or
        not: the robot's cell and the anticipation layer's goal inference. Returns the
        event when the layer's target changed ("heading for 1", "heading for none"),
        else None."""
        self.robot_cell = int(observed.robot) if observed.robot.isdigit() else None
        if self.anticipator is None:
            return None
        if isinstance(self.anticipator, PeopleAnticipator):
            changed = self.anticipator.observe(t, observed.people_positions_m, self.robot_cell)
        else:
            changed = self.anticipator.observe(t, observed.position_m, self.robot_cell)
        if not changed:
            return None
        target, standby = self.anticipator.target, self.anticipator.standby
        if target is None and standby is not None:
            return f"standing by in {standby}"
        return f"heading for {'none' if target is None else target}"
