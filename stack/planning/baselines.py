"""Baselines for the n-person task (issue 16), beside the online planner.

- :class:`GreedyPlanner`: nearest-threat greedy. The most likely intruder is the
  person most likely to make some restricted cell worth guarding (table 4.1); the
  robot walks to the restricted cell nearest that person's likeliest cell and waits
  there. When nobody is likely present it walks back to the rest cell.
- :class:`SinglePlanner`: the solved n = 1 policy applied to the most threatening
  person's belief (the same person as above), as the one-person agent would.

Both read the :class:`~stack.planning.factored.PeopleBelief` and answer in
microseconds. Pure numpy; no ROS.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np

from stack.cells import Direction
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.model import ACTION_DIRECTIONS, build_model
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP
from stack.planning.replay import TIE_TOLERANCE, policy_chooser
from stack.planning.solve import TASK_CONFIG, SolverConfig, solve_task
from stack.planning.task import Task
from stack.vocabulary import ACTIONS

STAY = ACTIONS.index("Do nothing")


def most_threatening(pm: PeopleModel, belief: PeopleBelief) -> int:
    """The person most likely to make a restricted cell worth guarding (ties: the
    first)."""
    return int(np.argmax(belief.guard_probabilities(pm).max(axis=1)))


def step_toward(pm: PeopleModel, robot: int, target: int) -> int:
    """The action of one step along a shortest route from robot value ``robot`` to
    cell ``target`` (rows first, then columns; "Do nothing" when there)."""
    g = pm.task.grid
    if robot >= pm.n_cells:  # out of the map: nothing helps
        return STAY
    here = g.cells[robot]
    (r0, c0), (r1, c1) = g.rowcol(here), g.rowcol(target)
    if r1 != r0:
        d = Direction.SOUTH if r1 > r0 else Direction.NORTH
    elif c1 != c0:
        d = Direction.EAST if c1 > c0 else Direction.WEST
    else:
        return STAY
    return ACTION_DIRECTIONS.index(d)


class GreedyPlanner:
    """Go to the restricted cell nearest the most likely intruder.

    Args:
        present: the probability of presence above which a person counts at all.
    """

    name = "greedy"

    def __init__(self, pm: PeopleModel, present: float = 0.5):
        self.pm, self.present = pm, present

    def target(self, belief: PeopleBelief) -> int:
        """The cell the robot heads for."""
        pm, task = self.pm, self.pm.task
        pos = np.stack([belief.position(pm, i) for i in range(pm.people)])  # (n, Pn)
        here = pos[:, : pm.n_cells].sum(axis=1)
        if not (here >= self.present).any():
            return task.rest_cell
        guard = belief.guard_probabilities(pm).max(axis=1)
        guard[here < self.present] = -1.0
        i = int(np.argmax(guard))
        cell = task.grid.cells[int(np.argmax(pos[i, : pm.n_cells]))]
        dist = [task.grid.chebyshev(cell, k) for k in task.restricted_cells]
        return task.restricted_cells[int(np.argmin(dist))]

    def action(self, belief: PeopleBelief) -> int:
        return step_toward(self.pm, belief.robot, self.target(belief))


class SinglePlanner:
    """The n = 1 policy on the most threatening person's belief.

    The action is the one-person agent's (:func:`stack.planning.replay.policy_chooser`
    with the one-step lookahead and its tie rule), computed on the factored model:
    the robot's cell is known, so the flat lookahead's sum over next states and
    observations splits into the robot's next cell r' and the person's (P, D) and
    labels, Q(a) = R(b, a) + gamma sum_r' T(r, a, r') sum_z max_k alpha_k[r'] .
    (b T_P * O_z), one dense product per reachable r' instead of sparse products over
    the flat model's 2,197 observations per action (``flat=True``: the flat one).

    Args:
        pm: the n-person task's tables.
        policy: alpha vectors of the one-person task (``task.replace(people=1)``).
        pomdp: that task's flat model (for ``flat=True``); built when not given.
        flat: use the flat model's lookahead (slow; the reference).
    """

    name = "single"

    def __init__(
        self,
        pm: PeopleModel,
        policy: AlphaPolicy,
        pomdp: POMDP | None = None,
        flat: bool = False,
        tie_tolerance: float = TIE_TOLERANCE,
    ):
        self.pm = pm
        n_states = pm.n_robot * pm.n_person
        if policy.n_states != n_states:
            raise ValueError(f"policy for {policy.n_states} states, model has {n_states}")
        self.flat = flat
        self.tie_tolerance = tie_tolerance
        self.alphas = policy.alphas.reshape(-1, pm.n_robot, pm.n_person)
        one = pm.task.replace(people=1)
        self.reward = build_model(one).reward_table().reshape(pm.n_robot, pm.n_person, -1)
        if flat:
            if pomdp is None:
                pomdp = build_model(one).flat()
            self.choose = policy_chooser(policy, pomdp, lookahead=True, tie_tolerance=tie_tolerance)

    def values(self, robot: int, person: np.ndarray) -> np.ndarray:
        """(A,) the one-step lookahead values of the one-person belief (robot, person)."""
        pm = self.pm
        pred = person @ pm.transition  # (n_person,)
        M = pred[:, None] * pm.observation_table  # (n_person, Z1)
        T = pm.robot_T[:, robot, :]  # (A, n_robot)
        G = {}
        for r2 in np.flatnonzero(T.any(axis=0)):
            G[int(r2)] = float((self.alphas[:, r2, :] @ M).max(axis=0).sum())
        future = np.array([sum(T[a, r2] * g for r2, g in G.items()) for a in range(len(T))])
        return person @ self.reward[robot] + pm.task.discount * future

    def action(self, belief: PeopleBelief) -> int:
        i = most_threatening(self.pm, belief)
        if self.flat:
            return int(self.choose(belief.person_flat(self.pm, i))[0])
        q = self.values(belief.robot, belief.persons[i])
        best = q.max()
        near = q >= best - self.tie_tolerance * max(abs(best), 1.0)
        return STAY if near[STAY] else int(np.flatnonzero(near)[0])


def single_person_policy(
    task: Task,
    cache_dir: str | Path | None = None,
    config: SolverConfig = TASK_CONFIG,
    say: Callable[[str], None] = lambda s: None,
) -> AlphaPolicy:
    """The solved policy of the task with one person (the deployed solver's settings),
    read from ``cache_dir`` when a solve of the same task and settings is there."""
    one = task.replace(people=1)
    key = hashlib.sha256(
        json.dumps([one.to_dict(), asdict(config)], sort_keys=True).encode()
    ).hexdigest()[:16]
    path = None if cache_dir is None else Path(cache_dir) / f"{one.name}-n1-{key}.npz"
    if path is not None and path.exists():
        return AlphaPolicy.load(path)
    say(f"solving the one-person task {one.name} ({config.algorithm}), once")
    policy = solve_task(one, config)
    if path is not None:
        policy.save(path)
    return policy
