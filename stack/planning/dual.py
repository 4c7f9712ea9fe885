"""An information-relaxation (dual) upper bound for exogenous-belief models (issue 12).

In the case study the person's dynamics and observations depend neither on the robot
nor on the action (:class:`~stack.planning.momdp_model.MixedModel`), so the person belief
b_t is an *exogenous* process, the same whatever the robot does; only the robot cell
x_t is controlled. That makes the information-relaxation duality of Brown, Smith and
Sun (Operations Research 58(4), 2010; for POMDPs Haugh and Lacedelli, IEEE TAC 2020)
cheap to apply:

- sample a path of the exogenous randomness: the person's states y_t, the camera's
  observations z_t (hence the beliefs b_t) and the uniform numbers u_t that decide
  each robot move;
- on that path, the best action sequence *knowing the future* is a deterministic
  dynamic programme over the 13 robot cells, backwards in t;
- to stop the clairvoyant from profiting from what it should not know, every step is
  charged a penalty with zero mean under any policy that does not look ahead:
  the reward given the belief, R(x, b_t, a), replaces the reward of the true state,
  and  gamma (F(x_{t+1}, b_{t+1}) - E[F(x_{t+1}, b_{t+1}) | b_t, x_t, a])  is
  subtracted, for a value function F;
- the path's value is the programme's value at (x_0, b_0); its mean over paths is an
  upper bound on V*(b_0) for *any* F (weak duality), and the tighter the closer F is
  to V* (with F = V* every path's value is V*(b_0) exactly). The horizon is cut at T
  with F as the terminal value, which keeps it an upper bound when F is one.

With F the fast informed bound (a supersolution: H F <= F), every path's value is at
most F(b_0) (induction over t), so the dual bound never exceeds it; on the task it is
much tighter (measured: r1 199.85 -> 194.96 +- 0.15, r2 316.9 -> 308.5 +- 0.2, against
lower bounds of 192.9-194.5 and 305.2-306.4; docs/BENCHMARKS.md).

The bound is *statistical*: a mean over sampled paths with a 95 % interval. The paths
come from a seeded generator, so the same model, seed and path count give the same
figure on any machine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from stack.planning.momdp_model import MixedModel
from stack.planning.policy import relative_gap

DUAL_BATCH = 16  # paths per batch of dual_batches (each batch seeded on its own)
DUAL_FIB_TOL = 1e-6  # the fast informed bound behind dual_batches' penalty


@dataclass(frozen=True)
class DualBound:
    """The dual bound's estimate: mean over paths, its 95 % half-width, the spread."""

    mean: float
    ci95: float
    sd: float
    paths: int
    horizon: int
    seconds: float
    penalty_value_b0: float  # F(x0, b0): the bound never exceeds it when F is a supersolution
    values: np.ndarray = field(repr=False, compare=False, default_factory=lambda: np.empty(0))

    @classmethod
    def of_paths(
        cls, values: np.ndarray, horizon: int, seconds: float, penalty_value_b0: float
    ) -> DualBound:
        """The estimate from every path's value (at least 2): mean, sd, and the 95 %
        half-width with Student's t."""
        n = len(values)
        sd = float(values.std(ddof=1))
        return cls(
            mean=float(values.mean()),
            ci95=t95(n - 1) * sd / math.sqrt(n),
            sd=sd,
            paths=n,
            horizon=horizon,
            seconds=seconds,
            penalty_value_b0=penalty_value_b0,
            values=values,
        )

    @property
    def upper(self) -> float:
        """The upper end of the 95 % interval: the figure to compare a lower bound with."""
        return self.mean + self.ci95

    def summary(self, lower_bound: float) -> dict:
        """The bound's figures in a solve's summary; ``dual_relative_gap`` is the
        summary's ``relative_gap`` with this bound as the upper one."""
        return {
            "dual_upper_mean": self.mean,
            "dual_upper_ci95": self.ci95,
            "dual_upper": self.upper,
            "dual_paths": self.paths,
            "dual_horizon": self.horizon,
            "dual_seconds": self.seconds,
            "dual_relative_gap": relative_gap(lower_bound, self.upper),
        }


def default_horizon(discount: float, tail: float = 0.01) -> int:
    """Steps until gamma^T falls below ``tail`` (459 for gamma = 0.99): the terminal
    value then weighs at most ``tail`` of its own looseness."""
    if not 0.0 < discount < 1.0:
        raise ValueError(f"the dual bound needs a discount in (0, 1), got {discount}")
    return max(1, math.ceil(math.log(tail) / math.log(discount)))


def dual_upper_bound(
    m: MixedModel,
    Q: np.ndarray,
    x0: int,
    b0: np.ndarray,
    paths: int = 64,
    horizon: int | None = None,
    seed: int | tuple[int, ...] = 0,
    deadline: float = math.inf,
    progress: Callable[[str], None] | None = None,
    now: Callable[[], float] = time.perf_counter,
) -> DualBound:
    """The information-relaxation upper bound on V*(x0, b0), penalty from F.

    Args:
        m: the model; its hidden factor must be exogenous (TY, OY independent of x, a).
        Q: (X, Y, A) the table behind F(x, b) = max_a sum_y b(y) Q[x, y, a], and the
            terminal value; must be an upper bound of V* (e.g. the fast informed bound)
            for the result to be one.
        x0, b0: the start: robot cell and person belief (Y,).
        paths: sampled paths (all run at once, vectorised).
        horizon: steps per path (default :func:`default_horizon`).
        seed: the paths' random generator seed (an int, or a tuple such as (seed, batch)).
        deadline: ``now()`` past which it raises TimeoutError.
        now: the clock of ``deadline`` (the solvers' clock.now for a CPU-time limit).
        progress: called with a line about once a second.

    Raises:
        ValueError: shapes that do not match the model, a bad start, paths < 2.
        TimeoutError: the deadline passed before the paths were done.
    """
    X, Y, A = m.X, m.Y, m.A
    Q = np.asarray(Q, dtype=float)
    if Q.shape != (X, Y, A):
        raise ValueError(f"the penalty table has shape {Q.shape}, the model needs {(X, Y, A)}")
    if not 0 <= x0 < X:
        raise ValueError(f"start cell {x0} outside 0..{X - 1}")
    b0 = np.asarray(b0, dtype=float)
    if b0.shape != (Y,) or abs(b0.sum() - 1.0) > 1e-6 or (b0 < 0).any():
        raise ValueError(f"the start belief must be a distribution over {Y} values")
    if paths < 2:
        raise ValueError(f"the dual bound needs at least 2 paths, got {paths}")
    T = default_horizon(m.discount) if horizon is None else int(horizon)
    if T < 1:
        raise ValueError(f"horizon must be >= 1, got {T}")
    t_start = now()
    g = m.discount
    N = paths
    rng = np.random.default_rng(seed)
    # columns a * X + x, so the maximum over actions runs over contiguous blocks
    QF = np.ascontiguousarray(Q.transpose(1, 2, 0).reshape(Y, A * X))  # (Y, A*X)
    cTY = np.cumsum(m.TY, axis=1)
    cOY = np.cumsum(m.OY, axis=1)
    # next cell of every (x, a) for a uniform number u: searchsorted on P(x' | x, a)
    cTX = np.cumsum(m.TX, axis=2)  # (A, X, X')
    cTX /= cTX[:, :, -1:]  # rounding never sends u past the last likely cell
    cTX[:, :, -1] = 2.0
    cTXn = np.ascontiguousarray(cTX.transpose(1, 0, 2))[None]  # (1, X, A, X')
    RT = m.R  # (X, Y, A)
    OYT = np.ascontiguousarray(m.OY.T)  # (Z, Y)

    # the products over the Z posteriors of every step run in float32 (half the time):
    # the penalty subtracts exactly the mean of what it charges (both from the same
    # float32 products, accumulated in float64), so it keeps a zero mean; only the
    # terminal value and F(b0) use the float64 table
    QF32 = QF.astype(np.float32)
    OYT32 = OYT.astype(np.float32)

    def F(Bs: np.ndarray, table: np.ndarray = QF) -> np.ndarray:
        """F at (unnormalised) beliefs (n, Y) for every cell: (n, X), linear in b."""
        V = (Bs @ table).reshape(len(Bs), A, X)
        out = V[:, 0].copy()
        for a in range(1, A):
            np.maximum(out, V[:, a], out=out)
        return out

    F0 = float(F(b0[None])[0, x0])
    y = _draw(rng, np.broadcast_to(np.cumsum(b0), (N, Y)))
    B = np.tile(b0, (N, 1))
    term = np.empty((T, N, X, A))
    nxt = np.empty((T, N, X, A), dtype=np.intp)
    rows = np.arange(N)
    last = time.perf_counter()
    for t in range(T):
        pred = B @ m.TY  # (N, Y): the prior of y_{t+1}
        J = pred.astype(np.float32)[:, None, :] * OYT32[None]  # (N, Z, Y) joint of (z, y')
        # F is positively homogeneous, so sum_z P(z) F(b^z) = sum_z F(joint_z)
        FJ = F(J.reshape(-1, Y), QF32).reshape(N, -1, X)  # (N, Z, X')
        EF = np.einsum("axk,nk->nxa", m.TX, FJ.sum(axis=1, dtype=np.float64))
        u = rng.random(N)
        xn = (u[:, None, None, None] >= cTXn).sum(axis=3)  # (N, X, A)
        y = _draw(rng, cTY[y])
        z = _draw(rng, cOY[y])
        Jz = pred * OYT[z]  # (N, Y) in float64: P(z | history) exactly as z is drawn
        pz = Jz.sum(axis=1)
        Fnext = FJ[rows, z].astype(np.float64) / pz[:, None]  # (N, X') F at the posterior
        term[t] = (
            np.einsum("ny,xya->nxa", B, RT)
            + g * EF
            - g
            * np.take_along_axis(Fnext[:, None, :], xn.reshape(N, X * A)[:, None, :], 2).reshape(
                N, X, A
            )
        )
        nxt[t] = xn
        B = Jz / pz[:, None]
        if now() > deadline:
            raise TimeoutError(f"dual bound: the time limit passed at step {t + 1} of {T}")
        wall = time.perf_counter()
        if progress is not None and wall - last >= 1.0:
            progress(f"dual bound: step {t + 1}/{T} of {N} paths, {now() - t_start:.1f} s")
            last = wall
    V = F(B)  # (N, X): the terminal value
    for t in range(T - 1, -1, -1):
        V = (term[t] + g * np.take_along_axis(V, nxt[t].reshape(N, X * A), 1).reshape(N, X, A)).max(
            axis=2
        )
    return DualBound.of_paths(V[:, x0], T, now() - t_start, F0)


_T95: tuple[float, ...] = (math.nan, 12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365)
_T95 += (2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145)


def t95(dof: int) -> float:
    """Student's t quantile 0.975 for ``dof`` degrees of freedom: the table below 15,
    then the Cornish-Fisher expansion about the normal's 1.96 (2.131 for 15, 2.040
    for 31, 1.998 for 63, each to 1e-4)."""
    if dof < 1:
        raise ValueError(f"t quantile needs dof >= 1, got {dof}")
    if dof < len(_T95):
        return _T95[dof]
    z = 1.959963984540054
    return (
        z
        + (z**3 + z) / (4 * dof)
        + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)
        + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * dof**3)
    )


def _draw(rng: np.random.Generator, cdf: np.ndarray) -> np.ndarray:
    """One index per row of the cumulative distributions ``cdf`` (n, k)."""
    u = rng.random(len(cdf))
    return np.minimum((u[:, None] >= cdf).sum(axis=1), cdf.shape[1] - 1)


def dual_batches(m: MixedModel, Q, x: int, b, config, deadline: float, progress):
    """The dual bound in batches of DUAL_BATCH paths (batch k seeded (config.seed, k))
    until config.dual_paths or the deadline; (DualBound or None, note). ``config`` is
    the solve's SolverConfig (dual_paths, seed)."""
    from stack.planning import clock
    from stack.planning.momdp_model import factored_fib

    t0 = clock.now()
    # the penalty's table: the search's fast informed bound iterated closer to its fixed
    # point (the closer the penalty is to V*, the tighter the bound; r1: 199.93 -> 199.85)
    Q = factored_fib(m, tol=DUAL_FIB_TOL, deadline=deadline, start=Q)
    values: list[np.ndarray] = []
    last = None
    for k in range(config.dual_paths // DUAL_BATCH):
        if clock.now() >= deadline:
            break
        try:
            last = dual_upper_bound(
                m,
                Q,
                x,
                b,
                paths=DUAL_BATCH,
                seed=(config.seed, k),
                deadline=deadline,
                now=clock.now,
                progress=progress,
            )
        except TimeoutError:
            break
        values.append(last.values)
        if progress is not None:
            progress(
                f"dual bound: {len(values) * DUAL_BATCH} paths, "
                f"mean {np.concatenate(values).mean():.3f}, {clock.now() - t0:.1f} s"
            )
    if last is None:
        return None, f"dual bound: not {DUAL_BATCH} paths within the time limit"
    bound = DualBound.of_paths(
        np.concatenate(values), last.horizon, clock.now() - t0, last.penalty_value_b0
    )
    return bound, ""
