"""The belief of the n-person task kept per person (issue 16).

The task model (chapter 3, :mod:`stack.planning.model`) lets every person move on
their own (P(P_i', D_i' | P_i, D_i), independent of the robot and of the other
people) and observes every person on their own (P(O_Pi, O_Vi | P_i', D_i')), while
the robot's cell is observed exactly (section 3.2.4). So a belief that starts as

    b(R, S_1, ..., S_n) = [R = r] b_1(S_1) ... b_n(S_n)        (S_i = (P_i, D_i))

stays one after every step: the robot's cell is the observed one and each person's
factor is updated with that person's observation alone. The product is the exact
joint belief, not an approximation, as long as the observations keep their person
slots (the perception's fixed order). It costs n x 65 numbers instead of the
joint's 13 x 65^n, and an update costs n small matrix-vector products.

:class:`PeopleBelief` is that belief; :class:`PeopleModel` holds the per-person
tables it and the planners of :mod:`stack.planning.online` read. Pure numpy, no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from stack.planning.belief import ZeroProbabilityObservation
from stack.planning.model import ACTION_DIRECTIONS, FactoredModel, build_model, direction_index
from stack.planning.task import Task


@dataclass(frozen=True, eq=False)
class PeopleModel:
    """The per-person tables of a task model, flattened for fast products.

    A person's state s = (P, D) has index ``P * 5 + D`` (Pn * 5 values, Pn = cells + 1).
    """

    model: FactoredModel

    @classmethod
    def of(cls, task: Task) -> PeopleModel:
        return cls(build_model(task))

    @property
    def task(self) -> Task:
        return self.model.task

    @property
    def people(self) -> int:
        return self.model.people

    @property
    def n_cells(self) -> int:
        return self.model.n_cells

    @property
    def n_robot(self) -> int:
        """Robot values: the cells and "out of the map" (the last)."""
        return self.model.n_cells + 1

    @property
    def n_person(self) -> int:
        """Values of one person's state (P, D)."""
        return (self.model.n_cells + 1) * 5

    @cached_property
    def transition(self) -> np.ndarray:
        """(n_person, n_person): P(s' | s) for one person."""
        return self.model.person_transition()

    @cached_property
    def robot_T(self) -> np.ndarray:
        """(A, n_robot, n_robot): P(R' | R, A)."""
        return self.model.robot_T

    @cached_property
    def guard(self) -> np.ndarray:
        """(K, n_person) as floats: 1 where the person makes restricted cell k worth
        guarding (table 4.1)."""
        return self.model.guard.reshape(len(self.task.restricted_cells), -1).astype(float)

    @cached_property
    def restricted_of_robot(self) -> np.ndarray:
        """(n_robot,) the restricted cell index k of each robot cell, -1 elsewhere."""
        out = np.full(self.n_robot, -1, dtype=int)
        for k, cell in enumerate(self.task.restricted_cells):
            out[self.model.robot_index(cell)] = k
        return out

    @cached_property
    def robot_reward(self) -> np.ndarray:
        """(n_robot, A): the reward of the robot's cell and action when nobody makes a
        restricted cell worth guarding (table 4.1's "idle" at restricted cells)."""
        rw = self.task.rewards
        base = np.full(self.n_robot, rw.other_cell)
        base[self.n_cells] = rw.out_of_map
        base[self.model.robot_index(self.task.rest_cell)] = rw.rest_cell
        base[self.restricted_of_robot >= 0] = rw.restricted_idle
        move = np.array([0.0 if d is None else rw.move for d in ACTION_DIRECTIONS])
        return base[:, None] + move[None, :]

    @property
    def guard_bonus(self) -> float:
        """Guarded minus idle reward at a restricted cell."""
        rw = self.task.rewards
        return rw.restricted_guarded - rw.restricted_idle

    def observation_likelihood(self, z_position: int, z_velocity: int) -> np.ndarray:
        """(n_person,): P(O_P = z_position, O_V = z_velocity | s') for one person."""
        m = self.model
        return (m.obs_position[:, z_position][:, None] * m.obs_velocity[:, :, z_velocity]).ravel()

    @cached_property
    def observation_table(self) -> np.ndarray:
        """(n_person, Pn * V): P(z | s') for one person, z = O_P * V + O_V."""
        return self.model.person_observation()

    def expected_reward(self, persons: np.ndarray) -> np.ndarray:
        """E[R(r, S, a)] for every robot cell r and action a under product beliefs.

        Args:
            persons: (..., n, n_person) per-person beliefs (any leading batch shape).

        Returns:
            (..., n_robot, A). At restricted cell k the reward is "guarded" when any
            person is guard-worthy for k: P = 1 - prod_i (1 - P_i(guard_k)).
        """
        g = persons @ self.guard.T  # (..., n, K)
        p_any = 1.0 - np.prod(1.0 - g, axis=-2)  # (..., K)
        k = self.restricted_of_robot
        bonus = np.zeros(persons.shape[:-2] + (self.n_robot,))
        at = k >= 0
        bonus[..., at] = self.guard_bonus * p_any[..., k[at]]
        return self.robot_reward + bonus[..., None]


@dataclass(frozen=True, eq=False)
class PeopleBelief:
    """The robot's cell (known exactly) and one belief per person over (P, D).

    Attributes:
        robot: the robot's value index (``model.robot_index(cell)``).
        persons: (n, n_person) array; row i sums to 1.
    """

    robot: int
    persons: np.ndarray

    @classmethod
    def certain(
        cls, pm: PeopleModel, robot: int | None, persons: list[tuple[int | None, str]]
    ) -> PeopleBelief:
        """A belief certain of the robot's cell and of every person's cell and direction."""
        if len(persons) != pm.people:
            raise ValueError(f"the task has {pm.people} people, got {len(persons)}")
        b = np.zeros((pm.people, pm.n_person))
        for i, (cell, direction) in enumerate(persons):
            b[i, pm.model.position_index(cell) * 5 + direction_index(direction)] = 1.0
        return cls(pm.model.robot_index(robot), b)

    @classmethod
    def initial(cls, pm: PeopleModel) -> PeopleBelief:
        """The task file's ``initial`` section, for every person alike."""
        ini = pm.task.initial
        return cls.certain(pm, ini.robot, [(ini.person, ini.direction)] * pm.people)

    def predict(self, pm: PeopleModel) -> np.ndarray:
        """(n, n_person): every person's belief one step ahead, before observing."""
        return self.persons @ pm.transition

    def update(self, pm: PeopleModel, action: int, observation: tuple[int, ...]) -> PeopleBelief:
        """The posterior after ``action`` and (z_R, z_P1, z_V1, ..., z_Pn, z_Vn).

        Raises:
            ZeroProbabilityObservation: the robot cannot be in the observed cell after
                ``action``, or a person's observation has probability 0.
        """
        n = pm.people
        if len(observation) != 1 + 2 * n:
            raise ValueError(f"observation needs {1 + 2 * n} parts, got {len(observation)}")
        lik = np.stack(
            [
                pm.observation_likelihood(observation[1 + 2 * i], observation[2 + 2 * i])
                for i in range(n)
            ]
        )
        return self.update_likelihood(pm, action, int(observation[0]), lik)

    def update_likelihood(
        self, pm: PeopleModel, action: int, robot: int, likelihood: np.ndarray
    ) -> PeopleBelief:
        """The posterior for per-person likelihoods (n, n_person) of what was observed
        (e.g. with the camera's hidden cells folded in, as the agent does for n = 1)."""
        if not pm.robot_T[action, self.robot, robot] > 0.0:
            raise ZeroProbabilityObservation(
                f"robot value {robot} cannot follow {self.robot} after action {action}"
            )
        post = self.predict(pm) * likelihood
        total = post.sum(axis=1, keepdims=True)
        if not np.all(total > 0.0) or not np.all(np.isfinite(total)):
            bad = int(np.flatnonzero(~(total[:, 0] > 0.0))[0]) if np.any(total <= 0) else 0
            raise ZeroProbabilityObservation(
                f"person {bad + 1}'s observation after action {action} has probability 0"
            )
        return PeopleBelief(robot, post / total)

    # -- views ---------------------------------------------------------------------
    def joint(self, pm: PeopleModel) -> np.ndarray:
        """The joint belief as a tensor over the model's (R, P_1, D_1, ..., P_n, D_n)."""
        t = np.zeros(pm.n_robot)
        t[self.robot] = 1.0
        for row in self.persons:
            t = np.multiply.outer(t, row.reshape(pm.n_cells + 1, 5))
        return t

    def position(self, pm: PeopleModel, i: int) -> np.ndarray:
        """(Pn,): person i's cell marginal (the last entry: no person)."""
        return self.persons[i].reshape(pm.n_cells + 1, 5).sum(axis=1)

    def guard_probabilities(self, pm: PeopleModel) -> np.ndarray:
        """(n, K): P(person i makes restricted cell k worth guarding)."""
        return self.persons @ pm.guard.T

    def person_flat(self, pm: PeopleModel, i: int) -> np.ndarray:
        """Person i's belief as a flat belief of the one-person model (R, P, D)."""
        b = np.zeros((pm.n_robot, pm.n_person))
        b[self.robot] = self.persons[i]
        return b.ravel()
