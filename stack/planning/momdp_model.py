"""The mixed-observability model of the task and its fast informed bound.

In the case study the robot's cell x is observed exactly; only the person factor y
(position and direction, 65 values on the 12-cell grid) is hidden. :class:`MixedModel`
holds the task in that form (Ong, Png, Hsu and Lee 2010), with the structure the task
has and the mixed search (:mod:`stack.planning.momdp`) uses:

- the person's dynamics P(y' | y) and observation P(z | y') depend neither on the
  robot nor on the action;
- the robot's dynamics P(x' | x, a) do not depend on the person.

:func:`mixed_from_task` makes it from the task's factored model (one person);
:func:`factored_fib` is the fast informed bound computed on the factors (a sweep is
one (X, Y, Y) x (Y, Z) product per action, milliseconds, against a second for the flat
form), started from the fully observable MDP's values (:func:`mdp_start`). The
delayed-revelation and dual bounds (``delayed.py``, ``dual.py``) read the same model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stack.planning import clock


@dataclass(frozen=True, eq=False)
class MixedModel:
    """A model with an observed factor x and a hidden factor y.

    Attributes:
        TX: (A, X, X) P(x' | x, a), independent of y.
        TY: (Y, Y) P(y' | y), independent of x and a.
        OY: (Y, Z) P(z | y'), independent of x' and a; x' is observed exactly.
        R: (X, Y, A) reward.
        discount: gamma < 1.
    Flat state index: x * Y + y (the task model's order, robot slowest).
    """

    TX: np.ndarray
    TY: np.ndarray
    OY: np.ndarray
    R: np.ndarray
    discount: float

    @property
    def X(self) -> int:
        return self.TX.shape[1]

    @property
    def Y(self) -> int:
        return self.TY.shape[0]

    @property
    def A(self) -> int:
        return self.TX.shape[0]

    def split(self, b: np.ndarray) -> tuple[int, np.ndarray]:
        """(x, person belief) of a flat belief that is certain about x."""
        t = np.asarray(b, dtype=float).reshape(self.X, self.Y)
        mass = t.sum(axis=1)
        x = int(mass.argmax())
        if mass[x] < 1.0 - 1e-9:
            raise ValueError("the belief is not certain about the observed factor")
        return x, t[x] / mass[x]


def mixed_from_task(model) -> MixedModel:
    """The task's factored model (one person) as a :class:`MixedModel`."""
    if model.people != 1:
        raise ValueError("the mixed-observability search handles one person")
    X = model.n_cells + 1
    R = model.reward_table().reshape(X, -1, model.reward_table().shape[-1])
    return MixedModel(
        TX=np.asarray(model.robot_T, dtype=float),
        TY=model.person_transition(),
        OY=model.person_observation(),
        R=R,
        discount=model.task.discount,
    )


def mdp_start(m: MixedModel, deadline: float, sweeps: int = 4000) -> np.ndarray:
    """A start for the fast informed bound: value iteration of the fully observable
    MDP down from max R / (1 - gamma) (a sweep costs ~0.1 ms against ~10 ms for the
    fast informed bound's). Every iterate Q satisfies M(Q) <= Q for the MDP operator M,
    and the fast informed bound's operator H lies below M, so H(Q) <= Q: the start is
    above the fast informed bound's fixed point, as its iteration needs."""
    g = m.discount
    Q = np.full(m.R.shape, float(m.R.max()) / (1 - g))
    TYT = m.TY
    for i in range(sweeps):
        U = Q.max(axis=2) @ TYT.T  # (X', Y): sum_y' P(y'|y) max_a' Q(x', y', a')
        new = np.minimum(m.R + g * np.einsum("axk,ky->xya", m.TX, U), Q)
        done = float((Q - new).max()) < 1e-9
        Q = new
        if done or (i % 100 == 0 and clock.now() > deadline):
            break
    return Q


def factored_fib(
    m: MixedModel,
    tol: float = 1e-3,
    max_iterations: int = 5000,
    deadline: float = math.inf,
    start: np.ndarray | None = None,
) -> np.ndarray:
    """The fast informed bound on the factors, Q (X, Y, A).

    H(Q)(x,y,a) = R(x,y,a) + gamma sum_x' P(x'|x,a) sum_z max_a' sum_y' P(y'|y) P(z|y') Q(x',y',a')

    H is monotone and a contraction, so any Q with H(Q) <= Q lies above the fixed point
    (H^n(Q) decreases to it). The iteration starts from the MDP's values (QMDP) and, as
    gamma = 0.99 makes plain iteration slow (~600 sweeps), extrapolates each step
    along the last decrease (Q - beta (Q_prev - Q)) and keeps the extrapolated table
    only where that check H(Q) <= Q holds for the whole table; otherwise beta halves.
    Every accepted table is an upper bound, so stopping at the deadline is safe.
    ``start``: a table from an earlier call (H(Q) <= Q holds for it), to go on from it
    to a smaller ``tol`` instead of starting again from the MDP's values.
    """
    g = m.discount

    def H(Q: np.ndarray) -> np.ndarray:
        # W[x', y, z, a'] = sum_y' TY[y, y'] OY[y', z] Q[x', y', a']
        W = np.einsum("yk,kz,xka->xyza", m.TY, m.OY, Q, optimize=True)
        U = W.max(axis=3).sum(axis=2)  # (X', Y)
        return m.R + g * np.einsum("axk,ky->xya", m.TX, U)

    Q = mdp_start(m, deadline) if start is None else np.array(start, dtype=float)
    HQ = np.minimum(H(Q), Q)  # H(Q) <= Q holds
    beta = 1.0
    for _ in range(max_iterations):
        step = Q - HQ  # >= 0
        if step.max() < tol or clock.now() > deadline:
            return HQ
        Qe = HQ - beta * step
        HQe = H(Qe)
        if (HQe <= Qe + 1e-12 * np.abs(Qe)).all():
            Q, HQ = Qe, np.minimum(HQe, Qe)
            beta = min(2.0 * beta, 1e4)
        else:
            HH = np.minimum(H(HQ), HQ)
            Q, HQ = HQ, HH
            beta = max(beta / 4.0, 1.0)
    return HQ
