"""Exact Bayesian belief tracking (eq. 2.14).

    b'(s') = O(s', a, z) sum_s T(s, a, s') b(s) / P(z | b, a)

The update is a pure function: it returns a new normalised belief and never
touches the caller's. An observation the model says cannot happen raises
:class:`ZeroProbabilityObservation` instead of dividing by zero.
"""

from __future__ import annotations

import numpy as np

from stack.planning.pomdp import POMDP


class ZeroProbabilityObservation(ValueError):
    """The observation has probability zero under the model from this belief and action."""


def predict(pomdp: POMDP, belief: np.ndarray, action: int) -> np.ndarray:
    """The predicted next-state distribution sum_s T(s, a, s') b(s)."""
    return pomdp.TT(action) @ belief


def update(pomdp: POMDP, belief: np.ndarray, action: int, observation: int) -> np.ndarray:
    """The posterior belief after doing ``action`` and observing ``observation``.

    Args:
        pomdp: the model.
        belief: (S,) current belief; not modified.
        action, observation: indices.

    Returns:
        A new (S,) belief that sums to 1.

    Raises:
        ZeroProbabilityObservation: if P(observation | belief, action) is 0.
    """
    pred = predict(pomdp, belief, action)
    post = pomdp.O[action][:, observation].toarray().ravel() * pred
    total = post.sum()
    if not total > 0.0 or not np.isfinite(total):
        raise ZeroProbabilityObservation(
            f"observation {pomdp.observations[observation]!r} after action "
            f"{pomdp.actions[action]!r} has probability 0 under the model from this belief"
        )
    return post / total


def update_with_likelihood(
    pomdp: POMDP, belief: np.ndarray, action: int, likelihood: np.ndarray
) -> np.ndarray:
    """The posterior for an observation given as its likelihood over the states.

    ``update(pomdp, b, a, z)`` is this with ``likelihood = O[a][:, z]``; other
    likelihoods express observations the model's alphabet cannot (e.g. "no person
    seen" where the camera could see only part of the floor).

    Raises:
        ZeroProbabilityObservation: if the observation has probability 0.
    """
    post = np.asarray(likelihood, float) * predict(pomdp, belief, action)
    total = post.sum()
    if not total > 0.0 or not np.isfinite(total):
        raise ZeroProbabilityObservation(
            f"the observation after action {pomdp.actions[action]!r} has probability 0 "
            "under the model from this belief"
        )
    return post / total


def observation_probabilities(pomdp: POMDP, belief: np.ndarray, action: int) -> np.ndarray:
    """P(z | b, a) for every observation z, shape (Z,)."""
    return pomdp.O[action].T @ predict(pomdp, belief, action)


class FactoredBelief:
    """Exact belief over the task's state variables kept as a joint tensor.

    Used where the flat model is too large to build (n = 2 people on the 12-cell
    grid: 54,925 states, whose flat T would need ~10^9 entries): the update applies
    the per-variable tables of a :class:`~stack.planning.model.FactoredModel` one
    factor at a time, so the cost grows with the state count, not its square.

    The belief is a tensor over (R, P_1, D_1, ..., P_n, D_n).
    """

    def __init__(self, model, tensor: np.ndarray):
        if tensor.shape != model.state_shape:
            raise ValueError(f"belief shape {tensor.shape} != state shape {model.state_shape}")
        total = tensor.sum()
        if not np.isclose(total, 1.0, atol=1e-9):
            raise ValueError(f"belief sums to {total}, not 1")
        self.model = model
        self.tensor = tensor.copy()

    @classmethod
    def certain(cls, model, robot: int | None, persons: list[tuple[int | None, str]]):
        flat = model.initial_belief(robot, persons)
        return cls(model, flat.reshape(model.state_shape))

    def update(self, action: int, observation: tuple[int, ...]) -> FactoredBelief:
        """Posterior after ``action`` and the observation (z_R, z_P1, z_V1, ..., z_Pn, z_Vn).

        Returns a new FactoredBelief; this one is not modified.

        Raises:
            ZeroProbabilityObservation: if the observation has probability 0.
        """
        m = self.model
        n = m.people
        if len(observation) != 1 + 2 * n:
            raise ValueError(f"observation needs {1 + 2 * n} parts, got {len(observation)}")
        b = self.tensor
        # robot: R' = sum_R T[a, R, R'] b[R, ...]
        b = np.tensordot(m.robot_T[action], b, axes=([0], [0]))
        for i in range(n):
            ax_p, ax_d = 1 + 2 * i, 2 + 2 * i
            # joint person step: (P, D) -> (P', D') with P(P'|P,D) P(D'|D)
            kernel = m.position_T[:, :, :, None] * m.direction_T[None, :, None, :]
            b = np.tensordot(b, kernel, axes=([ax_p, ax_d], [0, 1]))
            # tensordot appends (P', D') at the end: move them back into place
            b = np.moveaxis(b, [-2, -1], [ax_p, ax_d])
        # observations
        z_r = observation[0]
        lik = np.zeros(m.n_cells + 1)
        lik[z_r] = 1.0  # the robot's cell is observed exactly (section 3.2.4)
        post = b * lik.reshape((-1,) + (1,) * (2 * n))
        for i in range(n):
            z_p, z_v = observation[1 + 2 * i], observation[2 + 2 * i]
            like = m.obs_position[:, z_p][:, None] * m.obs_velocity[:, :, z_v]  # (P', D')
            shape = [1] * (1 + 2 * n)
            shape[1 + 2 * i], shape[2 + 2 * i] = like.shape
            post = post * like.reshape(shape)
        total = post.sum()
        if not total > 0.0:
            raise ZeroProbabilityObservation(
                f"observation {observation} after action {action} has probability 0 under the model"
            )
        return FactoredBelief(m, post / total)

    def marginal(self, axis: int) -> np.ndarray:
        """Marginal distribution of one state variable (0: robot, 1: P_1, 2: D_1, ...)."""
        other = tuple(i for i in range(self.tensor.ndim) if i != axis)
        return self.tensor.sum(axis=other)

    def flat(self) -> np.ndarray:
        return self.tensor.ravel().copy()
