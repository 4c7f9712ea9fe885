"""What the solving commands share: their arguments as a solver configuration, the
progress printer, solving a task file and reading any model file (``vigil solve``,
``solve-pomdp``, ``evaluate``, ``replay`` and ``replay-report``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TASKS = {"r1": REPO / "config" / "task-r1.yaml", "r2": REPO / "config" / "task-r2.yaml"}

# kept from --time-limit for exiting (and the policy's file: the search measures how
# long its vectors take to write and stops that much earlier): 2 %, at least 0.1 s with
# a policy to write, 0.05 s without. RockSample_4_4 at load 3 needs ~0.65 s of a 1 s
# limit wall (start-up ~0.45 s of it) and stopped after one backup with 0.3 s kept
WRITE_RESERVE = 0.02
WRITE_RESERVE_MIN_S = 0.1
EXIT_RESERVE_MIN_S = 0.05
# --perseus-share's default ("auto"): with a time limit of at least PERSEUS_FIRST_MIN_S,
# that share of it goes first to Perseus, whose vectors seed the belief-tree search (the
# best setting measured at 60 s on Hallway, Hallway2, TagAvoid and RockSample_5_7,
# docs/BENCHMARKS.md; Perseus stops early on a model the search closes at once).
# Shorter limits go to the search alone: RockSample_4_4 needs ~0.5 s of a 1 s limit.
# So do models whose sampled belief set (--beliefs x states, dense float64) exceeds
# PERSEUS_MAX_BELIEF_ENTRIES: Perseus's work grows with it (sampling a belief, and a
# product with the whole set after every backup), and past it the phase buys nothing.
# RockSample_11_11.pomdpx (249,856 states, 2.5e8 entries, 2 GB): sampling 1,000 beliefs
# takes ~30 CPU s (more than a 60 s limit's 18 s share), 50 backups at ~0.27 s each
# left the blind bound where it was, and at 60 CPU s the search alone ends higher
# (21.52-21.58 against 21.33-21.35, 4,435-4,688 backups against ~2,950, peak 2.1-2.7 GB
# against 3.0-3.1). RockSample_7_8.pomdpx (12,800 states, 1.3e7) still gains a little
# (21.48 against 21.45); the flat benchmark files are at most 3.2e6 (RockSample_5_7).
# A size, not a measured time: the same file and limit get the same settings on a
# loaded machine. Not scaled with the limit: longer limits on 11_11 were not measured.
PERSEUS_FIRST_SHARE = 0.3
PERSEUS_FIRST_MIN_S = 10.0
PERSEUS_MAX_BELIEF_ENTRIES = 5e7  # 400 MB as float64; between 7_8's 1.3e7 and 11_11's 2.5e8


def perseus_choice(
    args: argparse.Namespace, limit: float | None, n_states: int | None = None
) -> tuple[float, str]:
    """The Perseus share and why: ``--perseus-share`` when given (``"given"``), else
    (None, ``solve-pomdp``'s default) the share for ``limit`` (s) and a model of
    ``n_states`` states (None: not known yet, the limit alone decides); the task
    commands default to the task solver's 0."""
    share = getattr(args, "perseus_share", None)
    if share is not None:
        return share, "given"
    if limit is None or limit < PERSEUS_FIRST_MIN_S:
        return 0.0, f"auto: the search alone under a time limit below {PERSEUS_FIRST_MIN_S:g} s"
    if n_states is not None:
        entries = getattr(args, "beliefs", 1000) * n_states  # solve-pomdp's 1,000
        if entries > PERSEUS_MAX_BELIEF_ENTRIES:
            return 0.0, (
                f"auto: the search alone, {entries:.3g} belief entries (beliefs x states) "
                f"> {PERSEUS_MAX_BELIEF_ENTRIES:.3g}"
            )
        return PERSEUS_FIRST_SHARE, (
            f"auto: {entries:.3g} belief entries (beliefs x states) "
            f"<= {PERSEUS_MAX_BELIEF_ENTRIES:.3g}"
        )
    return PERSEUS_FIRST_SHARE, "auto"


def perseus_share(
    args: argparse.Namespace, limit: float | None, n_states: int | None = None
) -> float:
    """The share of :func:`perseus_choice`."""
    return perseus_choice(args, limit, n_states)[0]


def solver_config(args: argparse.Namespace, n_states: int | None = None):
    """The solver configuration of a command's arguments (--time-limit less the reserve
    for writing the policy); ``n_states``: the model's, for --perseus-share's default.

    Raises:
        ValueError: a time limit that is not a positive number of seconds.
    """
    from stack.planning.solve import SolverConfig

    limit = whole = getattr(args, "time_limit", None)
    if limit is not None:
        if not (limit > 0 and limit < 1e9):
            raise ValueError(f"--time-limit must be a positive number of seconds, got {limit}")
        least = WRITE_RESERVE_MIN_S if getattr(args, "output", None) else EXIT_RESERVE_MIN_S
        limit = max(limit * 0.5, limit - max(limit * WRITE_RESERVE, least))
    # a hand-made Namespace (older callers) gets the task defaults for what it lacks
    return SolverConfig(
        algorithm=getattr(args, "solver", "perseus"),
        beliefs=args.beliefs,
        iterations=args.iterations,
        time_limit_s=limit,
        fib_time_s=getattr(args, "fib_time", 0.0),
        seed=getattr(args, "seed", 0),
        target_gap=getattr(args, "target_gap", 1e-3),
        relative_gap=getattr(args, "relative_gap", 0.0),
        trials=getattr(args, "trials", None),
        perseus_share=perseus_share(args, whole, n_states),
        dual_paths=getattr(args, "dual_paths", 0),
        delayed_bound=getattr(args, "delayed_bound", False),
        # writing a vector entry as XML text takes ~0.4 us on an idle core, more under
        # load (the search measures it and scales this up); it stops that much earlier.
        # Without a time limit there is nothing to keep time from, and no measuring
        # (20 ms of RockSample_4_4's solve)
        write_s_per_value=0.5e-6 if getattr(args, "output", None) and limit is not None else 0.0,
    )


def progress_printer(args: argparse.Namespace, stream=sys.stderr, every_s: float = 1.0):
    """A progress printer: at most one line per ``every_s`` seconds."""
    import time

    from stack.planning.solve import format_progress

    if getattr(args, "quiet", False):
        return None
    last = [-float("inf")]

    def show(stats) -> None:
        now = time.perf_counter()
        if now - last[0] >= every_s:
            last[0] = now
            print(format_progress(stats), file=stream, flush=True)

    return show


def command_start(args: argparse.Namespace) -> float:
    """When the command's time limit began (``main`` records it), on the solvers' clock."""
    from stack.planning import clock

    start = getattr(args, "start", None)
    return clock.now() if start is None else start


def solve_task_file(
    task_path: Path,
    args: argparse.Namespace,
    progress=None,
    require_progress: bool = False,
    start: float | None = None,
):
    """Load and solve a task file; returns (model, pomdp, result).

    The commands pass ``require_progress=True`` (a degenerate solve is an error);
    quick solves from Python (tests, benchmarks) may leave it off.
    """
    from stack.planning.solve import solve_task_model
    from stack.planning.task import load_task

    sol = solve_task_model(
        load_task(task_path),
        solver_config(args),
        progress,
        command_start(args) if start is None else start,
        require_progress,
    )
    sol.result.policy.meta["task"] = str(task_path)
    return sol.model, sol.pomdp, sol.result


def read_model(path: str | Path):
    """A flat POMDP from a task file (.yaml), a .pomdpx file or a .pomdp file."""
    from stack.planning.pomdp_format import read_pomdp

    path = Path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        from stack.planning.model import build_model
        from stack.planning.task import load_task

        return build_model(load_task(path)).flat()
    if path.suffix.lower() == ".pomdpx":
        from stack.planning.pomdpx import read_pomdpx

        return read_pomdpx(path)
    return read_pomdp(path)


def bounds_line(s: dict) -> str:
    return (
        f"lower {s['lower_bound']:.4f}  upper {s['upper_bound']:.4f}  gap {s['gap']:.4f} "
        f"({100 * s['relative_gap']:.1f}%)  alphas {s['alpha_vectors']}  {s['seconds']:.2f} s"
        + (
            f"  dual upper {s['dual_upper_mean']:.3f} +- {s['dual_upper_ci95']:.3f} "
            f"({100 * s['dual_relative_gap']:.2f}% above the lower bound, 95 %)"
            if "dual_upper" in s
            else ""
        )
        + (f"  -> {s['policy']}" if "policy" in s else "")
    )
