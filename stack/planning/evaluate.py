"""Policy evaluation by seeded simulation (the thesis's evalPOMDPpolicy, section 4.3)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from stack.planning import belief as belief_ops
from stack.planning.pbvi import draw, draw_row
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP
from stack.planning.threads import blas_threads


@dataclass(frozen=True)
class Evaluation:
    mean: float  # mean discounted return
    ci95: float  # half-width of the 95% confidence interval of the mean
    episodes: int
    horizon: int
    returns: tuple[float, ...]

    def summary(self) -> dict:
        return summary_of(self)


def summary_of(result: Any, exclude: Sequence[str] = ("returns",)) -> dict[str, Any]:
    """A result dataclass's fields by name, in their order, less ``exclude`` (by
    default the per-episode returns): the summary an evaluation prints as JSON."""
    return {f.name: getattr(result, f.name) for f in fields(result) if f.name not in exclude}


def mean_ci95(returns: Sequence[float]) -> tuple[float, float]:
    """The mean of the episodes' returns and the half-width of its 95 % confidence
    interval (1.96 standard errors; inf for a single episode)."""
    x = np.asarray(returns)
    ci = 1.96 * x.std(ddof=1) / math.sqrt(len(x)) if len(x) > 1 else float("inf")
    return float(x.mean()), float(ci)


def _update(pomdp: POMDP, OTa, b: np.ndarray, a: int, z: int) -> np.ndarray:
    """The exact belief update (eq. 2.14), reading O's column z as a row of O^T."""
    pred = pomdp.TT(a) @ b
    lo, hi = OTa.indptr[z], OTa.indptr[z + 1]
    post = np.zeros_like(pred)
    cols = OTa.indices[lo:hi]
    post[cols] = OTa.data[lo:hi] * pred[cols]
    total = post.sum()
    if not total > 0.0:
        raise belief_ops.ZeroProbabilityObservation(
            f"observation {pomdp.observations[z]!r} after {pomdp.actions[a]!r} has probability 0"
        )
    return post / total


def default_horizon(discount: float, tolerance: float = 0.01) -> int:
    """Steps after which gamma^t falls below ``tolerance``."""
    return int(math.ceil(math.log(tolerance) / math.log(discount))) if discount < 1 else 100


def evaluate(
    pomdp: POMDP,
    policy: AlphaPolicy,
    episodes: int = 100,
    horizon: int | None = None,
    seed: int = 0,
    b0: np.ndarray | None = None,
) -> Evaluation:
    """Mean discounted return of ``policy`` over simulated episodes from ``b0``.

    Each episode draws a start state from b0, then at every step takes the policy's
    action for the current belief, draws the next state and observation from the
    model, and updates the belief exactly. Same seed, same result.
    """
    with blas_threads(1):  # one small product per step: threads only cost here
        return _evaluate(pomdp, policy, episodes, horizon, seed, b0)


def _evaluate(pomdp, policy, episodes, horizon, seed, b0) -> Evaluation:
    rng = np.random.default_rng(seed)
    b0 = pomdp.b0 if b0 is None else b0
    horizon = horizon or default_horizon(pomdp.discount)
    T = [pomdp.T[a].tocsr() for a in range(pomdp.n_actions)]
    O = [pomdp.O[a].tocsr() for a in range(pomdp.n_actions)]
    OT = [pomdp.OT(a) for a in range(pomdp.n_actions)]  # rows: P(z | s') for one z
    # the vectors by state: a belief over few states (RockSample's rocks, the robot's
    # cell known) reads only their rows, K x |support| instead of K x S a step
    # (a block policy's vectors cover one observed block each: policy.action reads it)
    AT = np.ascontiguousarray(policy.alphas.T) if policy.blocks is None else None
    returns = []
    for _ in range(episodes):
        b = b0
        s = draw(np.arange(pomdp.n_states), b0, rng)
        total, g = 0.0, 1.0
        for _t in range(horizon):
            if AT is None:
                a = policy.action(b)
            else:
                nz = np.flatnonzero(b)
                a = int(policy.actions[int(np.argmax(b[nz] @ AT[nz]))])
            total += g * pomdp.R[s, a]
            g *= pomdp.discount
            s = draw_row(T[a], s, rng)
            z = draw_row(O[a], s, rng)
            b = _update(pomdp, OT[a], b, a, z)
        returns.append(total)
    mean, ci = mean_ci95(returns)
    return Evaluation(mean, ci, episodes, horizon, tuple(float(x) for x in returns))
