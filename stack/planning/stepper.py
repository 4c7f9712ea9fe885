"""When a decision step ends: the planner's step machine, pure (no rclpy, no clock).

A step is: decide an action, let navigation carry it out, read the observations,
update the belief (section 4.3). What vigil adds to the thesis's cadence:

- a **move** ends when navigation reports the robot in its target cell (it keeps
  driving to the waypoint meanwhile); **Do nothing** (and a refused move) lasts at least
  ``min_step_s``, about one cell's move, since the model's steps are of one length;
- a step ends early, at least ``min_event_step_s`` after it began, when the
  observations show the person in a cell other than at the last step (the person
  entered the room, a restricted cell, any new cell): the robot reacts to a walker
  instead of finishing a move first;
- a missing navigation result (``nav_timeout_s``) or observation (``obs_timeout_s``)
  is logged and the step goes on.

:class:`DecisionSteps` is driven by three calls, each returning what to do as a list of
:class:`Command`: :meth:`~DecisionSteps.tick` (periodically), :meth:`~DecisionSteps.on_nav_result`
and :meth:`~DecisionSteps.on_observation`. The planner node
(:mod:`stack.planning.node_planner`) turns the commands into messages; an in-process
loop can drive the same machine.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

from stack.planning.agent import ObservationError, Observed
from stack.vocabulary import ACTIONS


@dataclass(frozen=True)
class StepTiming:
    """Attributes (seconds):
    start_delay_s: the first decision waits this long after start.
    min_step_s: a Do nothing (or refused) step lasts at least this long.
    min_event_step_s: a person event ends a step no sooner (0: no events).
    nav_timeout_s: no navigation result for this long: read the observations anyway.
    obs_timeout_s: no observation this long after asking: ask again.
    resume_wait_s: after a restart in the middle of an action, wait this long for it.
    max_steps: stop after this many steps (0: never).
    """

    start_delay_s: float = 1.0
    min_step_s: float = 0.0
    min_event_step_s: float = 0.0
    nav_timeout_s: float = 60.0
    obs_timeout_s: float = 5.0
    resume_wait_s: float = 3.0
    max_steps: int = 0


@dataclass(frozen=True)
class Command:
    """What the machine asks for.

    kind: "act" (publish ``action`` as navigation goal ``goal_id``), "request" (ask for
    observations), "record" (a step is complete: ``record`` holds it), "done" (the
    run's steps are over), "log" (a warning in ``text``).
    """

    kind: str
    action: str = ""
    record: dict[str, Any] | None = None
    text: str = ""
    goal_id: int = 0


class Agent(Protocol):
    """What the machine needs of an agent (:class:`~stack.planning.agent.PlannerAgent`,
    or :class:`~stack.planning.people_agent.PeopleAgent` for several people)."""

    step: int
    phase: str
    action: int | None
    # and optionally ``command``: what navigation is asked to do, the action's name or a
    # trip ("To 1"); without it the action's name

    def decide(self) -> int: ...

    def observe(self, observed: Observed) -> dict[str, Any]: ...

    def track(self, t: float, observed: Observed) -> str | None: ...


@dataclass
class DecisionSteps:
    """The step machine around a :class:`PlannerAgent`.

    Args:
        agent: belief and policy.
        timing: the cadence.
        first_person: the person's cell in the initial belief (None: nobody), the
            reference for the first step's person event.
        resumed: the agent was restored from a state file (recorded on the next step).
        origin_s: the clock's reading when the machine was made, from which
            ``start_delay_s`` counts: 0 on a simulated clock that starts with the run,
            the node's clock at start on a real one (an epoch time).
    """

    agent: Agent
    timing: StepTiming = field(default_factory=StepTiming)
    first_person: int | None = None
    resumed: bool = False
    origin_s: float = 0.0
    waiting: str = ""  # "" | "nav" | "hold" (min_step_s) | "obs"
    started: bool = False
    since_s: float = 0.0
    step_start_s: float = 0.0
    hold_until_s: float = 0.0
    requests: int = 0
    sent_action: str = ""
    sent_goal_id: int = 0  # the goal the step's action went out as (its step number)
    last_nav: dict[str, Any] | None = None
    last_person: str = field(init=False)
    intent_event: str | None = None  # the anticipation layer's event during this step

    def __post_init__(self) -> None:
        self.last_person = "" if self.first_person is None else str(self.first_person)

    # -- inputs ---------------------------------------------------------------------
    def tick(self, now_s: float) -> list[Command]:
        """Time passes: start, end a hold, or give up waiting."""
        t = self.timing
        if not self.started:
            if now_s - self.origin_s < t.start_delay_s:
                return []
            self.started = True
            return self._start(now_s)
        if self.waiting == "hold" and now_s >= self.hold_until_s:
            return self._request(now_s)
        if self.waiting == "nav" and now_s - self.since_s > t.nav_timeout_s:
            self.last_nav = {"result": "timeout"}
            return [
                Command("log", text=f"no navigation result for {t.nav_timeout_s:g} s: "
                        "reading observations"),
                *self._request(now_s),
            ]  # fmt: skip
        if self.waiting == "obs" and now_s - self.since_s > t.obs_timeout_s:
            return [
                Command("log", text=f"no observations {t.obs_timeout_s:g} s after request "
                        f"{self.requests}: asking again"),
                *self._request(now_s),
            ]  # fmt: skip
        return []

    def on_nav_result(self, now_s: float, body: Any) -> list[Command]:
        """Navigation's result (a dict; anything else is kept as its text).

        A result is matched to the goal by its ``goal_id``: a late result of an earlier
        goal (one that timed out, or a superseded move) is ignored, never taken for the
        step's own. A result without a ``goal_id`` key (an older navigation) is matched
        by its action's name.
        """
        if self.waiting != "nav":
            return []  # a result nobody waits for (e.g. after a timeout)
        if isinstance(body, dict):
            if "goal_id" in body:
                if body["goal_id"] != self.sent_goal_id:
                    return []  # another goal's result (late, or not the planner's)
            elif body.get("action") not in (None, self.sent_action):
                return []  # the result of an earlier action, superseded
        self.last_nav = body if isinstance(body, dict) else {"result": str(body)}
        self.hold_until_s = self.step_start_s + self.timing.min_step_s
        moved = self.sent_action != "Do nothing" and self.last_nav.get("result") == "succeeded"
        # A move ends on arrival; one that "arrived" the instant it was sent (navigation
        # already saw the robot in the target cell, the observation did not) is held
        # like Do nothing: ending it at once looped decide-act-arrive-observe forever
        # without time passing (seen in a Monte-Carlo episode with the robot on the
        # border of cells 3 and 1).
        moved = moved and now_s > self.step_start_s
        if moved or now_s >= self.hold_until_s:
            return self._request(now_s)
        self.waiting = "hold"
        return []

    def on_observation(self, now_s: float, observed: Observed) -> list[Command]:
        """The observations node's latest; ends the step when asked for or on an event.

        Raises:
            ObservationError: the agent cannot use it (the step goes on).
        """
        if self.waiting not in ("obs", "nav", "hold"):
            return []
        trigger = "step"
        # the anticipation layer's target changed now, or earlier within this step
        changed = self.agent.track(now_s, observed)
        heading = changed or self.intent_event
        if self.waiting != "obs":  # an event: the person shows up in a new cell
            person = _event_key(observed)
            elapsed = now_s - self.step_start_s
            moved = bool(person) and person != self.last_person
            if not (
                self.timing.min_event_step_s > 0
                and (moved or heading)
                and elapsed >= self.timing.min_event_step_s
            ):
                self.intent_event = heading  # decide on it once the step is long enough
                return self._revise(now_s) if changed else []  # but drive there now
            trigger = f"person in {person}" if moved else str(heading)
            if self.last_nav is None:
                self.last_nav = {"result": "in progress", "action": self.sent_action}
        record = self.agent.observe(observed)
        self.intent_event = None
        self.last_person = _event_key(observed)
        record.update(
            stamp_s=round(now_s, 6),
            nav=self.last_nav,
            resumed=self.resumed,
            trigger=trigger,
            goal_id=self.sent_goal_id,
        )
        self.resumed = False
        self.waiting = ""
        return [Command("record", record=record), *self._act(now_s)]

    # -- the machine ----------------------------------------------------------------
    def _start(self, now_s: float) -> list[Command]:
        phase = self.agent.phase
        if phase == "done":
            return self._finish()
        if phase == "acting":  # the action's result may have been lost while down
            self.waiting = "nav"
            self.since_s = now_s - self.timing.nav_timeout_s + self.timing.resume_wait_s
            self.step_start_s = now_s
            if self.agent.action is not None:
                self.sent_action = (
                    getattr(self.agent, "command", None) or ACTIONS[self.agent.action]
                )
            self.sent_goal_id = goal_id_of(self.agent.step + 1)
            return [Command("log", text=f"resumed during step {self.agent.step + 1}")]
        return self._act(now_s)

    def _act(self, now_s: float) -> list[Command]:
        if self.timing.max_steps and self.agent.step >= self.timing.max_steps:
            return self._finish()
        a = self.agent.decide()
        self.waiting, self.since_s, self.last_nav = "nav", now_s, None
        self.step_start_s = now_s
        self.sent_action = getattr(self.agent, "command", None) or ACTIONS[a]
        self.sent_goal_id = goal_id_of(self.agent.step + 1)
        return [Command("act", action=self.sent_action, goal_id=self.sent_goal_id)]

    def _revise(self, now_s: float) -> list[Command]:
        """A new target mid-step: the agent's revised command (a trip) goes out at once
        under the step's goal id, and the step waits for its arrival; the belief keeps
        the step's cadence (the model's steps are of one length)."""
        revise = getattr(self.agent, "revise", None)
        command = revise() if revise is not None else None
        if not command or command == self.sent_action:
            return []
        self.sent_action = command
        self.waiting, self.since_s, self.last_nav = "nav", now_s, None
        return [Command("act", action=command, goal_id=self.sent_goal_id)]

    def _request(self, now_s: float) -> list[Command]:
        self.waiting, self.since_s = "obs", now_s
        self.requests += 1
        return [Command("request")]

    def _finish(self) -> list[Command]:
        self.agent.phase = "done"
        self.waiting = ""
        return [Command("done")]


def goal_id_of(step: int) -> int:
    """The navigation goal id of a step's action: the step's number (1, 2, ...), so a
    planner resumed from its state file expects the id its predecessor sent, and no two
    steps share one."""
    return int(step)


def _person_key(label: str) -> str:
    return label if label.isdigit() else ""


def _event_key(observed: Observed) -> str:
    """The person's cell ("" for none); with person slots (issue 16) every slot's
    cell, joined by "," ("" when nobody is in a cell): any of them moving is an event."""
    if not observed.people:
        return _person_key(observed.person)
    keys = [_person_key(p) for p, _ in observed.people]
    return ",".join(keys) if any(keys) else ""


__all__ = ["Command", "DecisionSteps", "ObservationError", "StepTiming", "goal_id_of"]
