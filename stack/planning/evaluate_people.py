"""Seeded episodes of the n-person task model, for any planner (issue 16).

An episode starts from the task file's ``initial`` section (every person alike),
then at each step asks the planner for an action from the factored belief, earns
the true state's reward (table 4.1: "guarded" when any person makes the robot's
restricted cell worth guarding), draws the robot's and every person's next state
and the observations from the model, and updates the belief exactly
(:class:`~stack.planning.factored.PeopleBelief`).

The people's moves and the camera's observations do not depend on the robot, so
they are drawn from their own random stream: for a seed, every planner meets the
same people and the same observations (common random numbers), and only the
robot's own moves differ. The planner's wall time per decision is recorded.

:func:`evaluate_planners` is the command's entry point (``vigil evaluate TASK
--planner NAME``).
"""

from __future__ import annotations

import json as jsonlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from stack.planning.baselines import GreedyPlanner, SinglePlanner, single_person_policy
from stack.planning.evaluate import default_horizon, mean_ci95, summary_of
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.online import OnlineConfig, OnlinePlanner
from stack.planning.task import Task, load_task
from stack.planning.threads import blas_threads
from stack.vocabulary import VELOCITIES

PLANNERS = ("online", "greedy", "single")
POLICY_CACHE = Path(__file__).resolve().parents[2] / "runs" / ".policies"


class Planner(Protocol):
    name: str

    def action(self, belief: PeopleBelief) -> int: ...


@dataclass(frozen=True)
class PeopleEvaluation:
    planner: str
    mean: float  # mean discounted return
    ci95: float  # half-width of the 95 % confidence interval of the mean
    episodes: int
    horizon: int
    decision_ms_median: float
    decision_ms_p99: float
    returns: tuple[float, ...]

    def summary(self) -> dict:
        return summary_of(self)

    def line(self) -> str:
        return (
            f"{self.planner:7s} mean discounted return {self.mean:8.3f} +- {self.ci95:.3f} "
            f"(95%, {self.episodes} episodes, horizon {self.horizon}); decision "
            f"{self.decision_ms_median:.2f} ms median, {self.decision_ms_p99:.2f} ms p99"
        )


class _Sampler:
    """Inverse-cdf draws from the rows of a stochastic matrix."""

    def __init__(self, M: np.ndarray):
        self.cdf = np.cumsum(M, axis=-1)

    def __call__(self, row: int, rng: np.random.Generator) -> int:
        c = self.cdf[row]
        return min(int(np.searchsorted(c, rng.random() * c[-1], side="right")), len(c) - 1)


def _reset(planner: Planner, seed: int) -> None:
    reset = getattr(planner, "reset", None)
    if reset is not None:
        reset(seed)


def run_episodes(
    pm: PeopleModel,
    planner: Planner,
    episodes: int,
    seed: int = 0,
    horizon: int | None = None,
) -> PeopleEvaluation:
    """Mean discounted return of ``planner`` over seeded episodes. Same seed, same
    episodes (and the same people and observations for every planner)."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    horizon = horizon or default_horizon(pm.task.discount)
    g = pm.task.discount
    V = len(VELOCITIES)
    robot = [_Sampler(pm.robot_T[a]) for a in range(pm.robot_T.shape[0])]
    person = _Sampler(pm.transition)
    observe = _Sampler(pm.observation_table)
    k_of = pm.restricted_of_robot
    guard = pm.guard.astype(bool)
    base = pm.robot_reward
    bonus = pm.guard_bonus
    b0 = PeopleBelief.initial(pm)
    s0 = [int(np.argmax(row)) for row in b0.persons]
    returns, times = [], []
    with blas_threads(1):
        for e in range(episodes):
            people_rng, robot_rng = (
                np.random.default_rng(s) for s in np.random.SeedSequence([seed, e]).spawn(2)
            )
            _reset(planner, seed * 1_000_003 + e)
            b, r, s = b0, b0.robot, list(s0)
            total, disc = 0.0, 1.0
            for _t in range(horizon):
                t0 = time.perf_counter()
                a = planner.action(b)
                times.append(time.perf_counter() - t0)
                rew = base[r, a]
                k = k_of[r]
                if k >= 0 and any(guard[k, si] for si in s):
                    rew += bonus
                total += disc * rew
                disc *= g
                r = robot[a](r, robot_rng)
                obs = [r]
                for i in range(len(s)):
                    s[i] = person(s[i], people_rng)
                    z = observe(s[i], people_rng)
                    obs += [z // V, z % V]
                b = b.update(pm, a, tuple(obs))
            returns.append(total)
    mean, ci = mean_ci95(returns)
    ms = np.asarray(times) * 1e3
    return PeopleEvaluation(
        planner.name,
        mean,
        ci,
        episodes,
        horizon,
        float(np.median(ms)),
        float(np.percentile(ms, 99)),
        tuple(float(v) for v in returns),
    )


def make_planner(
    name: str,
    pm: PeopleModel,
    config: OnlineConfig | None = None,
    cache_dir: str | Path | None = POLICY_CACHE,
) -> Planner:
    """A planner by name: ``online``, ``greedy`` or ``single``."""
    if name == "greedy":
        return GreedyPlanner(pm)
    config = config or OnlineConfig()
    if name == "single" or (name == "online" and config.leaf == "single"):
        policy = single_person_policy(pm.task, cache_dir)
        if name == "single":
            return SinglePlanner(pm, policy)
        return OnlinePlanner(pm, config, single=policy)
    if name == "online":
        return OnlinePlanner(pm, config)
    raise ValueError(f"unknown planner {name!r}; known: {', '.join(PLANNERS)}")


def evaluate_planners(
    task: str | Path | Task,
    planner: str | Sequence[str] = PLANNERS,
    episodes: int = 200,
    seed: int = 0,
    json: bool = False,
    horizon: int | None = None,
    config: OnlineConfig | None = None,
) -> str:
    """Evaluate one planner (or several) on the task's n-person model; the text to print.

    Args:
        task: a task file (``config/task-r2-n2.yaml``) or a Task.
        planner: ``online``, ``greedy``, ``single``, or a list of them.
        episodes, seed, horizon: the simulation (horizon: gamma^t down to 0.01).
        json: a JSON object (one planner: ``mean``, ``ci95``, ... at the top level;
            several: ``{"planners": [...]}``) instead of one line per planner.
        config: the online planner's settings (default :class:`OnlineConfig`).
    """
    t = task if isinstance(task, Task) else load_task(task)
    pm = PeopleModel.of(t)
    names = [planner] if isinstance(planner, str) else list(planner)
    results = [
        run_episodes(pm, make_planner(n, pm, config), episodes, seed, horizon) for n in names
    ]
    if json:
        if len(results) == 1:
            return jsonlib.dumps(results[0].summary())
        return jsonlib.dumps({"planners": [r.summary() for r in results]})
    return "\n".join(r.line() for r in results)
