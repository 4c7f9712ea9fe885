"""Solving a POMDP end to end: bounds, belief sampling, Perseus, and a report.

Every solve reports a lower bound (the policy's value at b0), an upper bound (QMDP,
optionally tightened by the fast informed bound) and their gap, and shows progress
per iteration.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from stack.planning.bounds import blind_lower_bound, fast_informed_bound, plan_alphas, qmdp
from stack.planning.model import FactoredModel, guard_plans
from stack.planning.pbvi import IterationStats, perseus, sample_beliefs
from stack.planning.policy import AlphaPolicy
from stack.planning.pomdp import POMDP


@dataclass(frozen=True)
class SolverConfig:
    """How to solve (defaults: the thesis's Symbolic Perseus settings, section 4.3)."""

    beliefs: int = 300  # sampled belief points
    iterations: int = 50  # Perseus iterations
    time_limit_s: float | None = None  # stop after the iteration that passes this
    fib_time_s: float = 0.0  # time for tightening QMDP with the fast informed bound
    explore: float = 0.3  # random-action share when sampling beliefs
    seed: int = 0


@dataclass
class SolveResult:
    policy: AlphaPolicy
    lower_bound: float
    upper_bound: float
    seconds: float
    history: list[IterationStats] = field(default_factory=list)

    @property
    def gap(self) -> float:
        return self.upper_bound - self.lower_bound

    @property
    def relative_gap(self) -> float:
        return self.gap / max(abs(self.lower_bound), abs(self.upper_bound), 1e-12)

    def summary(self) -> dict:
        return {
            "lower_bound": self.lower_bound,
            "upper_bound": self.upper_bound,
            "gap": self.gap,
            "relative_gap": self.relative_gap,
            "value_b0": self.lower_bound,
            "alpha_vectors": int(self.policy.alphas.shape[0]),
            "iterations": len(self.history),
            "seconds": self.seconds,
        }


def solve(
    pomdp: POMDP,
    config: SolverConfig = SolverConfig(),
    starts: Sequence[np.ndarray] | None = None,
    seed_alphas: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[IterationStats], None] | None = None,
) -> SolveResult:
    """Solve a flat POMDP with Perseus between a blind/plan lower bound and QMDP/FIB.

    Args:
        pomdp: the model; its b0 is where bounds are reported.
        config: solver settings.
        starts: beliefs to sample from (default [b0]); the first is where values are
            reported.
        seed_alphas: extra (alphas, actions) added to the initial lower bound.
        progress: called after each iteration with value at b0, vectors, gap, time.
    """
    t0 = time.perf_counter()
    rng = np.random.default_rng(config.seed)
    starts = list(starts) if starts is not None else [pomdp.b0]
    b0 = starts[0]
    Q = qmdp(pomdp)
    if config.fib_time_s > 0:
        Q = fast_informed_bound(pomdp, Q, time_limit_s=config.fib_time_s)
    upper = float((Q.T @ b0).max())
    alphas = blind_lower_bound(pomdp)
    actions = np.arange(pomdp.n_actions)
    if seed_alphas is not None:
        alphas = np.vstack([alphas, seed_alphas[0]])
        actions = np.concatenate([actions, seed_alphas[1]])
    initial = AlphaPolicy(alphas, actions)
    B = sample_beliefs(pomdp, starts, config.beliefs, rng, Q, explore=config.explore)

    def report(stats: IterationStats) -> None:
        stats.upper_b0 = upper
        stats.elapsed_s = time.perf_counter() - t0
        if progress:
            progress(stats)

    policy, history = perseus(
        pomdp,
        B,
        iterations=config.iterations,
        rng=rng,
        initial=initial,
        time_limit_s=None
        if config.time_limit_s is None
        else config.time_limit_s - (time.perf_counter() - t0),
        progress=report,
        b0=b0,
    )
    lower = policy.value(b0)
    result = SolveResult(policy, lower, upper, time.perf_counter() - t0, history)
    policy.meta.update({"solver": "perseus", "config": asdict(config), **result.summary()})
    return result


def task_seed_alphas(model: FactoredModel, pomdp: POMDP) -> tuple[np.ndarray, np.ndarray]:
    """Lower-bound seeds for the task model: "walk to a cell and wait" plans."""
    plans, stay = guard_plans(model)
    alphas = plan_alphas(pomdp, plans, stay)
    actions = np.array([p[0] if p else stay for p in plans])
    return alphas, actions


def format_progress(stats: IterationStats) -> str:
    gap = "" if stats.gap is None else f"  gap {stats.gap:9.3f}"
    return (
        f"iter {stats.iteration:4d}  value(b0) {stats.value_b0:10.3f}{gap}  "
        f"alphas {stats.n_alphas:4d}  backups {stats.backups:6d}  {stats.elapsed_s:7.2f} s"
    )
