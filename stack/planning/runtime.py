"""The planner's agent for a deployment, made the same way by the ROS node and the
in-process loop (:mod:`stack.planning.node_planner`, :mod:`vigil.inprocess`).

One person: the offline policy (alpha vectors of ``policy_file``) on the flat model's
exact belief, with the task's anticipation layer (:class:`PlannerAgent`). Two or more:
the online planner on the factored belief (:class:`PeopleAgent`, issue 16; no policy
file). The models and the policy are read once per process for the same files (a
Monte-Carlo worker runs hundreds of episodes of one task; none of them changes).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from stack.cells import ConfigError
from stack.memo import Memo, file_version
from stack.planning.agent import PlannerAgent
from stack.planning.anticipate import Anticipator, PeopleAnticipator
from stack.planning.factored import PeopleModel
from stack.planning.model import FactoredModel, build_model
from stack.planning.online import OnlineConfig
from stack.planning.people_agent import PeopleAgent, initial_people_belief
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP
from stack.planning.task import Task, load_task


@dataclass(frozen=True)
class PlannerStart:
    """Where the planner starts (the node's ``initial_*`` parameters).

    Attributes:
        robot_cell: the robot's cell (0: the task's).
        person_cell: the person's cell (-1: the task's, 0: nobody).
        direction: the person's direction ("": the task's).
    """

    robot_cell: int = 0
    person_cell: int = -1
    direction: str = ""


@dataclass(frozen=True)
class PlannerSetup:
    """The agent, the person the step machine starts from, and a line saying what plans."""

    agent: PlannerAgent | PeopleAgent
    first_person: int | None
    description: str


ONLINE_DEFAULTS = {"online_depth": 2, "online_samples": 32, "online_time_limit_s": 0.0}


def online_config(params: Mapping[str, Any]) -> OnlineConfig:
    """The online planner's search from the planner's parameters (:data:`ONLINE_DEFAULTS`
    for those not given; a time limit of 0: none, so that a run is repeatable)."""
    p = {**ONLINE_DEFAULTS, **{k: v for k, v in params.items() if k in ONLINE_DEFAULTS}}
    return OnlineConfig(
        depth=int(p["online_depth"]),
        samples=int(p["online_samples"]),
        time_limit_s=float(p["online_time_limit_s"]) or None,
    )


_CACHE = Memo(9)  # a process plans for one or two tasks


def _cached(key: tuple, make):
    return _CACHE.get(key, make)


def _one_person(task_file: str, policy_file: str) -> tuple[FactoredModel, POMDP, AlphaPolicy]:
    def make():
        model = task_model(task_file)
        pomdp = model.flat()
        policy = AlphaPolicy.load(policy_file, pomdp.n_states, model_hash=pomdp.fingerprint())
        return model, pomdp, policy

    return _cached(("one", *file_version(task_file, policy_file)), make)


def task_of(task_file: str) -> Task:
    """The task file's task, read once (again when the file changes)."""
    return _cached(("task", *file_version(task_file)), lambda: load_task(task_file))


def task_model(task_file: str) -> FactoredModel:
    """The task's factored model (its grid, restricted cells and rewards), read once."""
    return _cached(("model", *file_version(task_file)), lambda: build_model(task_of(task_file)))


def _people_model(task_file: str) -> PeopleModel:
    return _cached(("people", *file_version(task_file)), lambda: PeopleModel.of(task_of(task_file)))


def make_planner(
    task_file: str,
    policy_file: str = "",
    start: PlannerStart = PlannerStart(),
    online: OnlineConfig | None = None,
) -> PlannerSetup:
    """The agent for ``task_file`` from where ``start`` says.

    Raises:
        ConfigError: no task file, or a one-person task without a policy file.
    """
    if not task_file:
        raise ConfigError("task_file", task_file, "is needed")
    task = task_of(task_file)
    if task.people >= 2:  # issue 16: the online planner on the factored belief
        pm = _people_model(task_file)
        ini = task.initial
        first = _first_person(ini.person, start)
        online = online or OnlineConfig()
        b = initial_people_belief(
            pm, start.robot_cell or ini.robot, first, start.direction or ini.direction
        )
        return PlannerSetup(
            PeopleAgent(pm, b, online, anticipator=PeopleAnticipator.for_task(task)),
            first,
            f"online planner (depth {online.depth}, {online.samples} samples)",
        )
    if not policy_file:
        raise ConfigError("policy_file", policy_file, "is needed for one person")
    model, pomdp, policy = _one_person(task_file, policy_file)
    ini = model.task.initial
    first = _first_person(ini.person, start)
    b0 = model.initial_belief(
        start.robot_cell or ini.robot, [(first, start.direction or ini.direction)] * model.people
    )
    agent = PlannerAgent(model, pomdp, policy, b0, anticipator=Anticipator.for_task(model.task))
    return PlannerSetup(agent, first, f"{len(policy.alphas)} vectors")


def _first_person(task_person: int | None, start: PlannerStart) -> int | None:
    return task_person if start.person_cell < 0 else (start.person_cell or None)
