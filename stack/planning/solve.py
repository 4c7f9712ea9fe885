"""Solving a POMDP end to end, and a report.

Two solvers: the belief-tree search of :mod:`stack.planning.sarsop` (the default:
refined upper bound, stops at a target gap or the time limit) and Perseus over a
sampled belief set (:mod:`stack.planning.pbvi`, the thesis's solver). Every solve
reports a lower bound (the policy's value at b0), an upper bound and their gap, and
shows progress at most once a second.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from stack.planning import clock
from stack.planning.bounds import blind_lower_bound, fast_informed_bound, plan_alphas, qmdp
from stack.planning.dual import DUAL_BATCH
from stack.planning.pbvi import IterationStats, perseus, sample_beliefs
from stack.planning.policy import AlphaPolicy, BoundedResult
from stack.planning.pomdp import POMDP
from stack.planning.threads import blas_threads

if TYPE_CHECKING:  # the task model (yaml, cells) is imported where a task is solved:
    # solving a .pomdp file does not load it (start-up, docs/BENCHMARKS.md)
    from stack.planning.model import FactoredModel

ALGORITHMS = ("sarsop", "perseus")
DUAL_SHARE = 0.1  # of a time limit, kept for the dual bound after the search (64 paths: ~3 s idle)


@dataclass(frozen=True)
class SolverConfig:
    """How to solve.

    ``algorithm="sarsop"`` is the belief-tree search (target_gap, relative_gap,
    trials); ``"perseus"`` the thesis's Symbolic Perseus settings (section 4.3:
    beliefs, iterations, explore, seed). The time limit is read on ``clock.now``
    (wall time, or the process's CPU time after ``clock.use_cpu_time``) from
    ``start`` (see :func:`solve`), checked before every backup by the search and by
    Perseus.
    """

    # sampled belief points (perseus; sarsop on a task model: person beliefs backed up
    # in rounds before the trials, see stack/planning/momdp.py)
    beliefs: int = 300
    iterations: int = 50  # Perseus iterations; rounds over those beliefs (task, sarsop)
    time_limit_s: float | None = None  # [s] on clock.now (wall, or CPU)
    fib_time_s: float = 0.0  # time for tightening QMDP with the fast informed bound
    explore: float = 0.3  # random-action share when sampling beliefs
    seed: int = 0
    algorithm: str = "sarsop"
    target_gap: float = 1e-3  # stop when UB - LB at b0 is at most this (sarsop)
    relative_gap: float = 0.0  # ... or at most this fraction of |V(b0)| (sarsop)
    trials: int | None = None  # stop after this many trials (sarsop; deterministic)
    write_s_per_value: float = 0.0  # [s] kept per vector entry for writing the policy
    # sarsop: share of the time limit (or, without one, Perseus iterations / 1000) spent
    # first on Perseus over sampled beliefs, whose vectors seed the search's lower bound
    perseus_share: float = 0.0
    # sarsop on a task model: search the mixed-observability form (robot cell observed,
    # beliefs over the person only; stack/planning/momdp.py) instead of the flat one;
    # on a .pomdpx model with fully observed variables, b0 within one of their values:
    # vectors per observed block (stack/planning/blocksearch.py)
    factored: bool = True
    # sarsop on a one-person task model: paths of the information-relaxation (dual)
    # upper bound at b0 (stack/planning/dual.py), a statistical bound reported beside
    # the search's; 0 = not computed. Under a time limit it gets DUAL_SHARE of it.
    dual_paths: int = 0
    # sarsop on a one-person task model, time limit >= delayed.DELAYED_MIN_S: the
    # certified delay-2 revelation upper bound (stack/planning/delayed.py) in a thread
    # beside the search, capping the roots' upper bounds when done (~2 GB)
    delayed_bound: bool = False

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"unknown solver {self.algorithm!r}; known: {', '.join(ALGORITHMS)}")
        for name in ("time_limit_s", "fib_time_s", "target_gap", "relative_gap"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v}")
        if self.beliefs < 1 or self.iterations < 1:
            raise ValueError(
                f"beliefs and iterations must be >= 1, got {self.beliefs}, {self.iterations}"
            )
        if not 0.0 <= self.perseus_share < 1.0:
            raise ValueError(f"perseus_share must be in [0, 1), got {self.perseus_share}")
        if self.trials is not None and self.trials < 1:
            raise ValueError(f"trials must be >= 1, got {self.trials}")
        if self.dual_paths < 0 or self.dual_paths % DUAL_BATCH:
            raise ValueError(
                f"dual_paths must be 0 (off) or a multiple of {DUAL_BATCH}, got {self.dual_paths}"
            )


@dataclass
class SolveResult(BoundedResult):
    dual: Any = None  # a DualBound at b0 (stack/planning/dual.py), when computed
    dual_note: str = ""  # why it was not, when asked for
    delayed: Any = None  # a DelayedResult (stack/planning/delayed.py), when computed
    delayed_note: str = ""  # why it was not, when asked for
    search_upper: float | None = None  # the search's own upper bound, when capped

    def summary(self) -> dict:
        out = super().summary()
        if self.dual is not None:
            out |= self.dual.summary(self.lower_bound)
        elif self.dual_note:
            out["dual_note"] = self.dual_note
        if self.delayed is not None:
            out |= self.delayed.summary()
            out["search_upper"] = self.search_upper
        elif self.delayed_note:
            out["delayed_note"] = self.delayed_note
        return out

    @property
    def n_iterations(self) -> int:
        return len(self.history)


def solve(
    pomdp: POMDP,
    config: SolverConfig = SolverConfig(),
    starts: Sequence[np.ndarray] | None = None,
    seed_alphas: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable | None = None,
    start: float | None = None,
) -> SolveResult:
    """Solve a flat POMDP between a blind/plan lower bound and an upper bound.

    Args:
        pomdp: the model; its b0 is where bounds are reported.
        config: solver settings.
        starts: beliefs the policy must be good at (default [b0]); the first is where
            values are reported.
        seed_alphas: extra (alphas, actions) added to the initial lower bound.
        progress: called at most once a second with the bounds, vectors and time.
        start: clock.now() when the time limit began (default: now); a
            command passes its own start so that reading the model counts once.
    """
    if config.algorithm == "sarsop":
        return _solve_search(pomdp, config, starts, seed_alphas, progress, start)
    t0 = clock.now() if start is None else start
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
        stats.elapsed_s = clock.now() - t0
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
        else config.time_limit_s - (clock.now() - t0),
        progress=report,
        b0=b0,
    )
    lower = policy.value(b0)
    result = SolveResult(policy, lower, upper, clock.now() - t0, history)
    policy.meta.update({"solver": "perseus", "config": asdict(config), **result.summary()})
    policy.meta["model_sha256"] = pomdp.fingerprint()
    return result


def _solve_search(pomdp, config, starts, seed_alphas, progress, start) -> SolveResult:
    from stack.planning.blocksearch import BlockTreeSearch, search_blocks
    from stack.planning.sarsop import BeliefTreeSearch

    starts = list(starts) if starts is not None else [pomdp.b0]
    t0 = clock.now() if start is None else start
    Q = qmdp(pomdp)  # once: the sampler's policy and the search's first upper bound
    if config.perseus_share > 0:
        # Perseus's vectors are backups of valid lower-bound vectors, so they are valid
        # seeds; they lift the lower bound of wide-belief models (Hallway2) quickly
        rng = np.random.default_rng(config.seed)
        until = (
            None if config.time_limit_s is None else t0 + config.perseus_share * config.time_limit_s
        )
        B = sample_beliefs(
            pomdp, starts, config.beliefs, rng, Q, explore=config.explore, deadline=until
        )
        budget = None if until is None else until - clock.now()
        iterations = config.iterations if budget is not None else max(1, config.iterations)
        closure: dict = {}
        # one BLAS thread, as the search: Hallway, 8 CPU-s of Perseus at load 7.6, 57
        # iterations against 53 with OpenBLAS's two (docs/BENCHMARKS.md)
        with blas_threads(1):
            perseus(
                pomdp,
                B,
                iterations=iterations,
                rng=rng,
                time_limit_s=budget,
                b0=starts[0],
                closure=closure,
                # a model the search solves at once (Tiger, 4x3) ends Perseus early
                tolerance=config.target_gap * (1 - pomdp.discount) / pomdp.discount
                if 0 < pomdp.discount < 1
                else None,
            )
        # Perseus's final vectors, and (archived, not searched with) the earlier ones
        # they lead to: with them the policy earns its bound (controller.py)
        closed = (closure["alphas"], closure["actions"], closure["successors"])
        if seed_alphas is None:
            seed_alphas = (*closed, closure["active"])
        else:  # the caller's seeds first: they are active, the closure's shift
            n = len(seed_alphas[0])
            seed_alphas = (
                np.vstack([seed_alphas[0], closed[0]]),
                np.concatenate([seed_alphas[1], closed[1]]),
                np.vstack(
                    [
                        np.full((n, pomdp.n_observations), -1),
                        np.where(closed[2] >= 0, closed[2] + n, -1),
                    ]
                ),
                n + closure["active"],
            )
    blocks = search_blocks(pomdp, starts[0]) if config.factored and len(starts) == 1 else None
    search: BeliefTreeSearch
    if blocks is not None:
        # a .pomdpx with fully observed variables: vectors per observed block; all the
        # active vectors written (pomdpsim's lookahead on RockSample_7_8: 21.26 with the
        # vectors reached only, 21.57 with all, docs/BENCHMARKS.md)
        search = BlockTreeSearch(
            pomdp,
            blocks,
            replace(_search_config(config), reached_only=False),
            seed_alphas=seed_alphas,
            start=t0,
            progress=progress,
            q_upper=Q,
            b0=starts[0],
        )
    else:
        search = BeliefTreeSearch(
            pomdp,
            _search_config(config),
            seed_alphas=seed_alphas,
            start=t0,
            progress=progress,
            b0=starts[0],
            extra_roots=starts[1:],
            q_upper=Q,
        )
    r = search.run()
    result = SolveResult(r.policy, r.lower_bound, r.upper_bound, r.seconds, r.history)
    r.policy.meta.update({"config": asdict(config), **result.summary(), **r.summary()})
    r.policy.meta["model_sha256"] = pomdp.fingerprint()
    return result


def _search_config(config: SolverConfig):
    """The belief-tree searches' settings from the solver's (flat and mixed alike)."""
    from stack.planning.search_base import SearchConfig

    return SearchConfig(
        time_limit_s=config.time_limit_s,
        target_gap=config.target_gap,
        relative_gap=config.relative_gap,
        max_trials=config.trials,
        write_s_per_value=config.write_s_per_value,
    )


def _solve_mixed(model, pomdp, config, seeds, progress, start) -> SolveResult:
    """The belief-tree search on the task's mixed-observability form, then (when
    ``config.dual_paths``) the dual upper bound at b0 in the time left."""
    from stack.planning.delayed import DelayedWorker
    from stack.planning.momdp import MixedSearch
    from stack.planning.momdp_model import mixed_from_task

    t0 = clock.now() if start is None else start
    alphas = np.vstack([blind_lower_bound(pomdp), seeds[0]])
    actions = np.concatenate([np.arange(pomdp.n_actions), seeds[1]])
    search_config = config
    if config.dual_paths and config.time_limit_s is not None:
        search_config = replace(config, time_limit_s=config.time_limit_s * (1 - DUAL_SHARE))
    m = mixed_from_task(model)
    search = MixedSearch(
        m,
        _search_config(search_config),
        (alphas, actions),
        task_starts(model, pomdp),
        start=t0,
        progress=progress,
        beliefs=config.beliefs,
        rounds=config.iterations,
        grow=config.time_limit_s is not None,
    )
    worker = (
        DelayedWorker.start(search, config.time_limit_s, progress) if config.delayed_bound else None
    )
    r = search.run()
    result = SolveResult(r.policy, r.lower_bound, r.upper_bound, r.seconds, r.history)
    result.delayed_note = search.delayed_note
    if worker is not None:
        result.delayed, result.delayed_note = worker.finish(search)
        if result.delayed is not None:
            result.search_upper = search.search_upper
            result.upper_bound = r.upper_bound = search.root.ub
            result.lower_bound = r.lower_bound = search.root.lb
    if config.dual_paths:
        from stack.planning.dual import dual_batches

        deadline = math.inf
        if config.time_limit_s is not None:
            # the time the search kept for writing the policy stays kept
            write_s = r.policy.alphas.size * search.write_seconds_per_value()
            deadline = t0 + config.time_limit_s - write_s
        x, b = m.split(pomdp.b0)
        with blas_threads(1):  # a second BLAS thread costs 2-6x on these small products
            result.dual, result.dual_note = dual_batches(
                m, search.Q_upper, x, b, config, deadline, progress
            )
        result.seconds = clock.now() - t0
    r.policy.meta.update({"config": asdict(config), **r.summary(), **result.summary()})
    r.policy.meta["model_sha256"] = pomdp.fingerprint()
    return result


def task_seed_alphas(model: FactoredModel, pomdp: POMDP) -> tuple[np.ndarray, np.ndarray]:
    """Lower-bound seeds for the task model: "walk to a cell and wait" plans."""
    from stack.planning.model import guard_plans

    plans, stay = guard_plans(model)
    alphas = plan_alphas(pomdp, plans, stay)
    actions = np.array([p[0] if p else stay for p in plans])
    return alphas, actions


def format_progress(stats) -> str:
    """One progress line for either solver's statistics (a text line passes as is)."""
    if isinstance(stats, str):
        return stats
    if not isinstance(stats, IterationStats):
        from stack.planning.search_base import format_search_progress

        return format_search_progress(stats)
    gap = "" if stats.gap is None else f"  gap {stats.gap:9.3f}"
    return (
        f"iter {stats.iteration:4d}  value(b0) {stats.value_b0:10.3f}{gap}  "
        f"alphas {stats.n_alphas:4d}  backups {stats.backups:6d}  {stats.elapsed_s:7.2f} s"
    )


# -- the case study ---------------------------------------------------------------------

# The task models' solver settings: the belief-tree search on the mixed-observability
# form (stack/planning/momdp.py: the robot's cell observed, beliefs over the person):
# 300 person beliefs sampled from the starts (fixed seed) backed up in 20 rounds, then
# 100 trials, or a gap of 1 % (deterministic: the same policy on any machine, whatever
# its load). With the task files' second fit: r1 192.85 / 199.93, r2 305.23 / 316.94
# (docs/BENCHMARKS.md); `vigil replay --table all` replays 48/50 with it for every
# --seed (the policy's own action, plain argmax).
# Perseus as the thesis ran it (300 beliefs, 200 iterations) remains available as
# algorithm="perseus".
TASK_CONFIG = SolverConfig(
    algorithm="sarsop", trials=100, relative_gap=0.01, beliefs=300, iterations=20
)


class DegenerateSolveError(ValueError):
    """A solve whose value at b0 never rose above the initial (trivial) lower bound."""


@dataclass
class TaskSolution:
    """A solved task: the factored and flat model and the solve's result."""

    model: FactoredModel
    pomdp: POMDP
    result: SolveResult


def task_starts(model: FactoredModel, pomdp: POMDP) -> list[np.ndarray]:
    """The task's initial belief, then every chapter 5 start (the policy must cover the
    experiments the replay runs)."""
    from stack.planning.replay import TABLES

    starts = [pomdp.b0]
    for t in TABLES.values():
        b = model.initial_belief(t.robot, [(t.person, t.direction)])
        if not any((b == s).all() for s in starts):
            starts.append(b)
    return starts


def solve_task_model(
    task,
    config: SolverConfig = TASK_CONFIG,
    progress: Callable | None = None,
    start: float | None = None,
    require_progress: bool = True,
) -> TaskSolution:
    """Build a task's model and solve it.

    Args:
        require_progress: raise when V(b0) did not rise above the initial bound
            (off only for quick test solves that never run a robot).

    Raises:
        DegenerateSolveError: V(b0) stayed at the initial lower bound (the blind and
            "walk to a cell and wait" policies): no policy worth running was found.
    """
    from stack.planning.model import build_model

    model = build_model(task)
    pomdp = model.flat()
    seeds = task_seed_alphas(model, pomdp)
    if config.algorithm == "sarsop" and config.factored and model.people == 1:
        result = _solve_mixed(model, pomdp, config, seeds, progress, start)
    else:
        result = solve(pomdp, config, task_starts(model, pomdp), seeds, progress, start)
        if config.dual_paths:
            result.dual_note = "dual bound: only for one-person tasks searched by sarsop"
    initial = float((np.vstack([blind_lower_bound(pomdp), seeds[0]]) @ pomdp.b0).max())
    if require_progress and result.lower_bound <= initial + 1e-9 * max(1.0, abs(initial)):
        raise DegenerateSolveError(
            f"task {task.name}: the solve left V(b0) = {result.lower_bound:.4f} at its "
            f"initial lower bound {initial:.4f}; give it more iterations or time"
        )
    result.policy.meta["task"] = task.name
    return TaskSolution(model, pomdp, result)


def solve_task(task, config: SolverConfig = TASK_CONFIG, progress: Callable | None = None):
    """The policy of a task (a :class:`~stack.planning.task.Task`).

    Returns:
        The :class:`AlphaPolicy`; its ``meta`` holds the bounds and the model's hash.
    """
    return solve_task_model(task, config, progress).result.policy
