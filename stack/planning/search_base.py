"""What the belief-tree searches share: settings, progress reports, result, stopping rules.

Two searches of the HSVI2 / SARSOP family live in this package: the flat one
(:class:`stack.planning.sarsop.BeliefTreeSearch`, any ``.pomdp``; its block form
:class:`stack.planning.blocksearch.BlockTreeSearch`) and the mixed-observability one
(:class:`stack.planning.momdp.MixedSearch`, the robot's task). Their beliefs, nodes
and vectors differ; what is the same is written once here:

- :class:`SearchConfig`, the settings (time limit, gaps, trial budget, pruning);
- :class:`SearchStats`, one progress report, and :func:`format_search_progress`;
- :class:`SearchResult`, what ``run()`` returns;
- :func:`child_targets`, SARSOP's target levels carried down a trial;
- :class:`StoppingRules`, when a search stops (the roots' gaps met, the deadline less
  the time writing the policy will take, the trial budget);
- :class:`SearchBase`, the clock and counters of a search, the loop of its trials,
  its progress reports and the result it ends with.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from stack.planning import clock
from stack.planning.policy import AlphaPolicy, BoundedResult, relative_gap


class SolveError(RuntimeError):
    """A solve whose result cannot be used (a degenerate value at b0)."""


@dataclass(frozen=True)
class SearchConfig:
    """Settings of the belief-tree search.

    Attributes:
        time_limit_s: stop when this much time has passed since ``start`` on the
            solvers' clock (``clock.now``: wall time, or CPU time); None: no limit.
        target_gap: stop when V_U(b0) - V_L(b0) is at most this (absolute).
        relative_gap: ... or at most this fraction of max(|V_L(b0)|, |V_U(b0)|).
        trial_improvement: each trial aims to shrink the root's gap to this fraction.
        max_trials: stop after this many trials (None: no limit); the deterministic
            alternative to a time limit.
        max_depth: deepest node of a trial.
        prune_growth: prune the lower bound when the vector set has grown by this
            factor since the last pruning.
        fib_share: at most this share of the time limit for the fast informed bound.
        progress_every_s: at most one progress report per this many seconds.
    """

    time_limit_s: float | None = 60.0
    target_gap: float = 1e-3
    relative_gap: float = 0.0
    trial_improvement: float = 0.5
    max_trials: int | None = None
    max_depth: int = 2000
    prune_growth: float = 2.0
    fib_share: float = 0.1
    progress_every_s: float = 1.0
    target_levels: bool = True
    # [s] per vector entry kept from the time limit for writing the policy afterwards
    write_s_per_value: float = 0.0
    blas_threads: int = 1  # see stack/planning/threads.py: one thread is faster here
    # share of the time limit kept for dropping pointwise dominated vectors before the
    # policy is written (controller.prune_closed; Hallway: 6,953 vectors to 3,639)
    finish_share: float = 0.01
    # write the vectors the policy uses at the tree nodes it reaches from the roots, and
    # their successors, rather than every active vector (see BeliefTreeSearch.closure)
    reached_only: bool = True


@dataclass
class SearchStats:
    """One progress report (also kept as the solve's history)."""

    trials: int
    lower: float
    upper: float
    n_alphas: int
    n_points: int
    n_nodes: int
    backups: int
    elapsed_s: float

    @property
    def gap(self) -> float:
        return self.upper - self.lower

    # the names pbvi.IterationStats uses, so the two print the same way
    @property
    def value_b0(self) -> float:
        return self.lower

    @property
    def upper_b0(self) -> float:
        return self.upper


def format_search_progress(s: SearchStats) -> str:
    rel = relative_gap(s.lower, s.upper)
    return (
        f"{s.elapsed_s:7.2f} s  LB {s.lower:11.5f}  UB {s.upper:11.5f}  gap {s.gap:10.5f} "
        f"({100 * rel:6.2f} %)  vectors {s.n_alphas:5d}  points {s.n_points:6d}  "
        f"trials {s.trials:6d}"
    )


@dataclass
class SearchResult(BoundedResult):
    trials: int = 0
    backups: int = 0
    stopped: str = ""  # "gap", "time", "trials"

    @property
    def n_iterations(self) -> int:
        return self.trials

    def summary(self) -> dict:
        return {
            **super().summary(),
            "trials": self.trials,
            "backups": self.backups,
            "stopped": self.stopped,
        }


def child_targets(
    L: float,
    U: float,
    best_lower: float,
    eps_t: float,
    reward: float,
    gamma: float,
    weight: float,
    rest_l: float,
    rest_u: float,
) -> tuple[float, float]:
    """SARSOP's target levels (L, U) carried from a node to the child a trial enters
    (Kurniawati, Hsu and Lee 2008).

    The node's levels are first raised to what its best lower-bound Q value already
    guarantees (``best_lower``; and that plus ``eps_t``, the gap allowed at the node's
    depth); the child's are the values it must reach for the node to reach them: less
    the reward and the discounted share of the other children (``rest_l``, ``rest_u``:
    their weights times their lower, upper bounds), over the child's discounted weight.
    """
    Lp = max(L, best_lower)
    Up = max(U, best_lower + eps_t)
    c = gamma * weight
    return (Lp - reward - gamma * rest_l) / c, (Up - reward - gamma * rest_u) / c


class StoppingRules:
    """When a belief-tree search stops (shared by the flat and the mixed search): the
    roots' gaps met (absolute or relative), the deadline less the time writing the
    vectors will take, or the trial budget. A search has ``config`` (SearchConfig),
    ``roots`` (nodes with ``lb``/``ub``), ``deadline``, ``trials`` and says how many
    values its policy holds (:meth:`_values_to_write`)."""

    config: SearchConfig
    roots: list
    deadline: float
    trials: int
    _write_factor: float = 1.0  # measured writing speed / config.write_s_per_value
    _prune_s: float = 0.0  # how long the last pruning of the active set took
    _write_share: float = 1.0  # share of the values counted that the policy writes

    def write_seconds_per_value(self) -> float:
        """Seconds kept per value of the written policy: the configured figure times
        the measured slowdown of writing (1 until measured)."""
        return self.config.write_s_per_value * self._write_factor

    def _values_to_write(self) -> int:
        raise NotImplementedError

    def _late(self) -> bool:
        """Past the deadline, less the time writing the vectors will take and the
        share of the limit kept for pruning them (``config.finish_share``)."""
        if self.deadline == math.inf:
            return False
        return clock.now() >= self.deadline - self._reserve()

    def _reserve(self) -> float:
        limit = self.config.time_limit_s or 0.0
        return (
            self._values_to_write() * self.config.write_s_per_value
            + self.config.finish_share * limit
            + 1.5 * self._prune_s  # the final pruning of the active set (it grows)
        )

    def _met(self, r) -> bool:
        gap = r.ub - r.lb
        return gap <= self.config.target_gap or gap <= self.config.relative_gap * max(
            abs(r.lb), abs(r.ub)
        )

    def _done(self) -> str:
        if all(self._met(r) for r in self.roots):
            return "gap"
        if self._late():
            return "time"
        if self.config.max_trials is not None and self.trials >= self.config.max_trials:
            return "trials"
        return ""


class SearchBase(StoppingRules):
    """The part of a belief-tree search that does not depend on its beliefs: the clock
    and counters (:meth:`_begin`), the trials until a stopping rule holds
    (:meth:`_trials`; each search has its own :meth:`_trial`), the progress reports
    (:meth:`_report`) and the result (:meth:`_result`). A search says how many vectors
    and upper-bound points it holds (``n_alphas``, ``n_points``) and has ``root`` (the
    node or start whose bounds are reported) and ``nodes`` (its tree)."""

    root: Any
    nodes: dict
    start: float
    progress: Callable[[SearchStats], None] | None
    backups: int
    history: list[SearchStats]
    _last_report: float

    @property
    def n_alphas(self) -> int:
        raise NotImplementedError

    @property
    def n_points(self) -> int:
        raise NotImplementedError

    def _begin(
        self,
        config: SearchConfig,
        start: float | None,
        progress: Callable[[SearchStats], None] | None,
    ) -> None:
        """Settings, the clock (``start``: clock.now() when the time limit started,
        default now) and the counters of a new search."""
        self.config = config
        self.start = clock.now() if start is None else start
        self.deadline = (
            math.inf if config.time_limit_s is None else self.start + config.time_limit_s
        )
        self.progress = progress
        self.backups = 0
        self.trials = 0
        self.history = []
        self._last_report = -math.inf

    def _trial(self) -> None:
        raise NotImplementedError

    def _trial_root(self) -> tuple[Any, float, float, float]:
        """Where a trial starts: the root furthest from its target (b0 first on ties),
        the gap ``eps`` the trial asks it to lose (``config.trial_improvement`` of its
        gap), and SARSOP's target levels there, L = V_L(root), U = V_L(root) + eps."""
        open_roots = [r for r in self.roots if not self._met(r)] or [self.root]
        root = max(open_roots, key=lambda r: r.ub - r.lb)
        eps = self.config.trial_improvement * (root.ub - root.lb)
        return root, eps, root.lb, root.lb + eps

    def _trials(self, stopped: str) -> str:
        """Trials from the roots, each followed by a progress report, until a stopping
        rule holds (``stopped``: one already held); returns which."""
        while not stopped:
            self._trial()
            self._report()
            stopped = self._done()
        return stopped

    def _report(self, force: bool = False) -> None:
        """One progress report, at most once per ``config.progress_every_s``: kept in
        the history and passed to ``progress``."""
        now = clock.now()
        if not force and now - self._last_report < self.config.progress_every_s:
            return
        self._last_report = now
        stats = SearchStats(
            trials=self.trials,
            lower=self.root.lb,
            upper=self.root.ub,
            n_alphas=self.n_alphas,
            n_points=self.n_points,
            n_nodes=len(self.nodes),
            backups=self.backups,
            elapsed_s=now - self.start,
        )
        self.history.append(stats)
        if self.progress:
            self.progress(stats)

    def _result(self, policy: AlphaPolicy, stopped: str) -> SearchResult:
        """The search's result with ``policy``; its summary goes into the policy's meta."""
        result = SearchResult(
            policy=policy,
            lower_bound=self.root.lb,
            upper_bound=self.root.ub,
            seconds=clock.now() - self.start,
            history=self.history,
            trials=self.trials,
            backups=self.backups,
            stopped=stopped,
        )
        policy.meta.update(result.summary())
        return result
