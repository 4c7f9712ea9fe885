"""The ``vigil`` command line: one entry point, a subcommand per job.

vigil solve TASK.yaml -o POLICY.npz      solve a task model (progress per iteration)
vigil export-pomdp TASK.yaml -o F.pomdp  write the task model in Cassandra format
vigil solve-pomdp F.pomdp [-o P.policy]  solve any .pomdp/.pomdpx file, print bounds
vigil evaluate MODEL --policy P          mean discounted return by simulation (any model/policy)
vigil replay --table all                 chapter 5's tables against our planner
vigil replay-report --out DIR            solve, replay chapter 5, simulate, report
vigil run SCENARIO [--config F] [--seed S] [--out DIR]   an experiment through ROS in the twin
vigil replay-bag RUN [--out DIR]         re-play a run's bag into its planner; same steps?
vigil bag-reindex BAG                    salvage a killed bag node's bag into BAG_recovered
vigil experiments DIR --out OUT [--docs F --label L]   a scenario set and its metric table
vigil launch CONFIG [--out DIR] [--resume]  start the whole system; Ctrl-C stops it
vigil arm CONFIG [--force]               arm the robot's velocity gate, confirmed (docs/HARDWARE.md)
vigil disarm CONFIG                      disarm it (parameter and /arm), confirmed
vigil status CONFIG [--wait S] [--json]  the gate, the base, every /diagnostics status
vigil calibrate (--twin | --points F) -o CAL   the camera's floor homography
vigil security keystore DIR --domain N   an SROS2 keystore for hardware mode (docs/SAFETY.md)
vigil security check                     can the installed DDS enforce it?

Over 500 lines because it is the one place where every command's arguments, its
one-line errors and its exit codes are defined; the work itself lives in the modules
each command calls.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import stack.topics as topic
from stack.config import write_text
from vigil.replay import replay_json, replay_markdown, run_replay
from vigil.resume import DEFAULT_RESUME_MAX_AGE_S
from vigil.solving import (
    bounds_line,
    command_start,
    perseus_choice,
    progress_printer,
    read_model,
    solve_task_file,
    solver_config,
)

REPO = Path(__file__).resolve().parents[1]


def _solver_args(
    p: argparse.ArgumentParser,
    iterations: int = 50,
    algorithm: str = "sarsop",
    trials: int | None = None,
    relative_gap: float = 0.0,
    beliefs: int = 300,
    perseus_share: float | None = 0.0,
) -> None:
    p.add_argument(
        "--solver",
        choices=("sarsop", "perseus"),
        default=algorithm,
        help="sarsop: belief-tree search with a refined upper bound; perseus: the thesis's",
    )
    p.add_argument("--iterations", type=int, default=iterations, help="Perseus iterations")
    p.add_argument("--beliefs", type=int, default=beliefs, help="Perseus: sampled belief points")
    p.add_argument(
        "--time-limit",
        type=float,
        default=None,
        help="seconds for the whole command (start-up, reading, solving, writing); wall time, "
        "or CPU time with --cpu-time (solve, solve-pomdp)",
    )
    p.add_argument("--target-gap", type=float, default=1e-3, help="sarsop: stop at this gap")
    p.add_argument(
        "--relative-gap",
        type=float,
        default=relative_gap,
        help="sarsop: stop at this gap / |V(b0)|",
    )
    p.add_argument("--trials", type=int, default=trials, help="sarsop: stop after this many")
    p.add_argument(
        "--perseus-share",
        type=float,
        default=perseus_share,
        help="sarsop: share of the time limit for Perseus first, whose vectors seed the search"
        + (
            "; always obeyed when given (default: auto, 0.3 with a --time-limit of 10 s or "
            "more on a model whose --beliefs x states is at most 5e7, else 0; the JSON "
            "output's perseus_share and perseus_note say which)"
            if perseus_share is None
            else ""
        ),
    )
    p.add_argument(
        "--fib-time", type=float, default=0.0, help="Perseus: seconds for the fast informed bound"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the belief sampler")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


# -- subcommands ------------------------------------------------------------------------


def cmd_solve(args: argparse.Namespace) -> int:
    _, pomdp, result = solve_task_file(
        Path(args.task), args, progress_printer(args), require_progress=True
    )
    path = result.policy.save(args.output)
    out = result.summary() | {"policy": str(path)}
    print(json.dumps(out, indent=2) if args.json else bounds_line(out))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from stack.planning.model import build_model
    from stack.planning.pomdp_format import write_pomdp
    from stack.planning.task import load_task

    pomdp = build_model(load_task(args.task)).flat()
    write_pomdp(pomdp, args.output)
    print(
        f"wrote {args.output}: {pomdp.n_states} states, {pomdp.n_actions} actions, "
        f"{pomdp.n_observations} observations"
    )
    return 0


def cmd_solve_pomdp(args: argparse.Namespace) -> int:

    from stack.planning.solve import solve

    start = command_start(args)
    solver_config(args)  # checks the arguments before the model is read
    pomdp = read_model(args.file)
    # --perseus-share's default depends on the model's size (vigil.solving.perseus_choice)
    config = solver_config(args, pomdp.n_states)
    share_note = perseus_choice(args, getattr(args, "time_limit", None), pomdp.n_states)[1]
    progress = None if args.json else progress_printer(args)
    if progress is not None and config.algorithm == "sarsop":
        print(f"perseus share {config.perseus_share:g} ({share_note})", file=sys.stderr)
    result = solve(pomdp, config, progress=progress, start=start)
    result.policy.meta["model"] = Path(args.file).name
    out = {
        "file": str(args.file),
        "states": pomdp.n_states,
        "actions": pomdp.n_actions,
        "observations": pomdp.n_observations,
    } | result.summary()
    if config.algorithm == "sarsop":
        out["perseus_share"] = config.perseus_share
        out["perseus_note"] = share_note
    if args.output:
        out["policy"] = str(result.policy.save(args.output))
    from stack.planning import clock

    out["command_seconds"] = clock.now() - start
    out["clock"] = "cpu" if clock.cpu_time() else "wall"
    out["stopped"] = result.policy.meta.get("stopped", "")  # gap, time or trials (sarsop)
    if "backups" in result.policy.meta:  # the belief-tree search's count (sarsop)
        out["backups"] = int(result.policy.meta["backups"])
    print(json.dumps(out, indent=2) if args.json else bounds_line(out))
    if getattr(args, "standalone", False):
        # the search tree (10^5 nodes) takes the interpreter a second or more to free
        # on a loaded machine (RockSample_4_4: 0.15 s at load 5); the policy is written
        # and closed and the output flushed, so the command ends here (docs/BENCHMARKS.md)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    from stack.planning.evaluate import evaluate
    from stack.planning.policy import AlphaPolicy

    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.planner is not None:  # the n-person task's online planner or a baseline (issue 16)
        from stack.planning.evaluate_people import evaluate_planners

        out = evaluate_planners(
            args.model, args.planner, args.episodes, args.seed, args.json, horizon=args.horizon
        )
        print(out)
        return 0
    if args.policy is None:
        raise ValueError("give --policy (a solved policy) or --planner (online, greedy, single)")
    from stack.planning.pomdpx import observed_blocks

    pomdp = read_model(args.model)
    policy = AlphaPolicy.load(
        args.policy,
        n_states=pomdp.n_states,
        model_hash=pomdp.fingerprint(),
        obs_blocks=observed_blocks(pomdp),  # SARSOP's policy of a .pomdpx file
    )
    ev = evaluate(pomdp, policy, episodes=args.episodes, horizon=args.horizon, seed=args.seed)
    print(
        json.dumps(ev.summary())
        if args.json
        else f"mean discounted return {ev.mean:.3f} +- {ev.ci95:.3f} (95%, {ev.episodes} episodes, "
        f"horizon {ev.horizon})"
    )
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from stack.planning.replay import TABLES

    names = list(TABLES) if args.table == "all" else [args.table]
    results, _ = run_replay(names, args)
    if args.json:
        print(json.dumps(replay_json(results), indent=2))
    else:
        print(replay_markdown(results))
    return 0


def cmd_main(args: argparse.Namespace) -> int:
    """Until the twin scenarios land: solve both task models, replay chapter 5, report."""
    from stack.planning.evaluate import evaluate
    from stack.planning.replay import TABLES
    from vigil.report.figures import plot_replay

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results, solved = run_replay(list(TABLES), args)
    summary: dict = {"tasks": {}, "replay": {}}
    for name, (_model, pomdp, result) in solved.items():
        path = result.policy.save(out / f"policy-{name}.npz")
        ev = evaluate(pomdp, result.policy, episodes=args.episodes, seed=args.seed)
        summary["tasks"][name] = result.summary() | {
            "policy": path.name,
            "evaluation": ev.summary(),
        }
        print(
            f"task {name}: "
            + bounds_line(result.summary())
            + f"; simulated return {ev.mean:.2f} +- {ev.ci95:.2f}"
        )
    write_text(out / "replay.md", "# Chapter 5 replayed\n\n" + replay_markdown(results))
    summary["replay"] = replay_json(results)
    summary["agreement"] = sum(r.agreement for r in results)
    summary["agreement_with_ties"] = sum(r.agreement_with_ties for r in results)
    summary["steps"] = sum(len(r.steps) for r in results)
    for r in results:
        model = solved[r.table.task][0]
        plot_replay(model, r, out / f"table-{r.table.name}.png")
    write_text(out / "summary.json", json.dumps(summary, indent=2))
    print(
        f"replay agreement {summary['agreement']}/{summary['steps']} "
        f"({summary['agreement_with_ties']} counting ties)"
    )
    print(f"report written to {out}/ (replay.md, summary.json, table-*.png, policy-*.npz)")
    return 0


def cmd_twin_snapshot(args: argparse.Namespace) -> int:
    """Write the ceiling camera's view and a top view with the lidar scan as PNGs."""
    from twin.snapshot import snapshot

    paths = snapshot(Path(args.out), Path(args.config) if args.config else None, seed=args.seed)
    for path in paths:
        print(f"wrote {path}")
    return 0


def _command(sub, name: str, what: str, **kwargs) -> argparse.ArgumentParser:
    """A subcommand whose --help says what it does and every option's default."""
    return sub.add_parser(
        name,
        help=what,
        description=what[0].upper() + what[1:] + ".",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        **kwargs,
    )


def _task_solver_args(p: argparse.ArgumentParser) -> None:
    """The solver options of the commands that solve the case-study tasks, defaulting
    to the task solver (:data:`stack.planning.solve.TASK_CONFIG`)."""
    from stack.planning.solve import TASK_CONFIG as T

    _solver_args(p, T.iterations, T.algorithm, T.trials, T.relative_gap, T.beliefs, T.perseus_share)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="vigil",
        description="vigil: a robot and a ceiling camera keep people out of restricted cells, "
        "planning under uncertainty (POMDP). `vigil COMMAND --help` for each command.",
    )
    sub = ap.add_subparsers(dest="command", required=True)

    p = _command(sub, "solve", "solve a task file into a policy")
    p.add_argument("task", help="task file, e.g. config/task-r1.yaml")
    p.add_argument("-o", "--output", required=True, help="policy file (.npz, or .policy XML)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    _task_solver_args(p)
    p.add_argument(
        "--dual-paths",
        type=int,
        default=0,
        help="one-person tasks: sampled paths (a multiple of 16, e.g. 64) of the "
        "statistical (information-relaxation) upper bound at b0 reported beside the "
        "search's bounds; it takes 10%% of --time-limit after the search; 0 = off "
        "(default: off, the certified delayed bound is the tighter deterministic one)",
    )
    p.add_argument(
        "--delayed-bound",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="one-person tasks under a --time-limit of 20 s or more: compute the "
        "certified delay-2 revelation upper bound in a thread beside the search (the "
        "second core, ~2 GB for the process; under --cpu-time its CPU counts too) and report the "
        "tighter upper bound (default on)",
    )
    p.add_argument(
        "--cpu-time",
        action="store_true",
        help="--time-limit counts this process's CPU seconds, not wall",
    )
    p.set_defaults(func=cmd_solve)

    p = _command(sub, "export-pomdp", "write a task model as a Cassandra .pomdp file")
    p.add_argument("task", help="task file, e.g. config/task-r1.yaml")
    p.add_argument("-o", "--output", required=True, help="the .pomdp file to write")
    p.set_defaults(func=cmd_export)

    p = _command(sub, "solve-pomdp", "solve a .pomdp (Cassandra) or .pomdpx file")
    p.add_argument("file", help="the model file")
    p.add_argument(
        "-o", "--output", help="policy file: exactly this path; .policy writes SARSOP's XML"
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    # the benchmark files' best settings measured (docs/BENCHMARKS.md): Perseus first
    # under a long limit on a model of moderate size (vigil.solving.perseus_choice), its
    # 1,000 beliefs
    _solver_args(p, iterations=1000, beliefs=1000, perseus_share=None)
    p.add_argument(
        "--cpu-time",
        action="store_true",
        help="--time-limit counts this process's CPU seconds (as SARSOP's figures), not wall",
    )
    p.set_defaults(func=cmd_solve_pomdp)

    p = _command(sub, "evaluate", "mean discounted return of a policy, by simulation")
    p.add_argument("model", help="a task file (.yaml), a .pomdp or a .pomdpx file")
    p.add_argument("--policy", help="ours (.npz) or SARSOP's (.policy XML)")
    p.add_argument(
        "--planner",
        choices=("online", "greedy", "single"),
        help="instead of --policy: a task file's n-person planner (issue 16)",
    )
    p.add_argument("--episodes", type=int, default=100, help="simulated episodes")
    p.add_argument(
        "--horizon",
        type=int,
        default=None,
        help="steps per episode (None: until the discount falls below 1e-3)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the simulation")
    p.add_argument("--json", action="store_true", help="print mean, ci95 ... as JSON")
    p.set_defaults(func=cmd_evaluate)

    p = _command(sub, "replay", "replay chapter 5's tables through our planner")
    p.add_argument(
        "--table", choices=["5.1", "5.2", "5.3", "5.4", "all"], default="all", help="which table"
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    _task_solver_args(p)
    p.set_defaults(func=cmd_replay)

    p = _command(sub, "twin", "the digital twin")
    twin_sub = p.add_subparsers(dest="twin_command", required=True)
    q = _command(twin_sub, "snapshot", "camera view and top view with lidar, as PNG")
    q.add_argument("--out", default="runs/snapshot", help="folder for the images")
    q.add_argument("--config", default=None, help="twin config YAML (default: built-in)")
    q.add_argument("--seed", type=int, default=0, help="the twin's seed")
    q.set_defaults(func=cmd_twin_snapshot)

    p = _command(sub, "run", "run a scenario through the ROS stack and write its report")
    p.add_argument("scenario", help="scenario file, e.g. scenarios/5.2.2.yaml")
    p.add_argument("--config", default=None, help="deployment file (default config/twin.yaml)")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--out", default=None, help="run folder (default runs/<scenario>)")
    p.add_argument(
        "--observations",
        choices=("twin", "table"),
        default="twin",
        help="twin: the whole stack; table: the thesis table's observations",
    )
    p.add_argument("--timeout", type=float, default=1800.0, help="wall-clock seconds")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="hardware in the loop: the twin keeps the wall clock and the stack does not "
        "wait for it (no lock-step); summary.json's realtime entry says how well it kept up",
    )
    p.set_defaults(func=cmd_run)

    p = _command(
        sub,
        "replay-bag",
        "re-play a run's bag into its observations and planner nodes and compare the steps "
        "(exit 1 on a mismatch, 2 on an error)",
    )
    p.add_argument("run", help="a run folder written by vigil run (with bag/ and params.yaml)")
    p.add_argument(
        "--out", default=None, help="the replay's folder (default RUN/replay, replay_1, ...)"
    )
    p.add_argument(
        "--stall",
        type=float,
        default=120.0,
        help="wall seconds without an acknowledgement from the nodes before giving up",
    )
    p.set_defaults(func=cmd_replay_bag)

    p = _command(
        sub,
        "bag-reindex",
        "salvage a bag whose writer was killed (no metadata.yaml): its complete messages "
        "into a new, indexed bag BAG_recovered beside it; the original is left as it is "
        "(exit 2 when there is nothing to salvage)",
    )
    p.add_argument("bag", help="the bag's folder, e.g. runs/5.1.1/bag")
    p.set_defaults(func=cmd_bag_reindex)

    p = _command(
        sub,
        "experiments",
        "run a folder of scenarios; metric table per scenario and totals, and a figure",
    )
    p.add_argument("scenarios", help="folder of scenario files (or one file), e.g. scenarios/guard")
    p.add_argument("--out", required=True, help="the set's folder, e.g. runs/guard")
    p.add_argument("--config", default=None, help="deployment file (default config/twin.yaml)")
    p.add_argument("--seed", type=int, default=None, help="override every scenario's seed")
    p.add_argument("--only", nargs="+", default=(), help="these file stems only")
    p.add_argument(
        "--report-only",
        action="store_true",
        help="recompute the reports of the run folders in --out; run nothing",
    )
    p.add_argument("--docs", default=None, help="update a marked section of this Markdown file")
    p.add_argument("--label", default="guard", help="the section's marker label")
    p.add_argument(
        "--realtime", action="store_true", help="each run as vigil run --realtime (wall clock)"
    )
    p.add_argument("--heading", default="", help="heading for a new section (empty: none)")
    p.set_defaults(func=cmd_experiments)

    p = _command(
        sub, "fit-perception", "fit the camera pipeline's model to rendered in-process runs"
    )
    p.add_argument("folders", nargs="*", type=Path, help="folders of rendered runs to fit on")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="model file (default config/perception-model.yaml)")  # fmt: skip
    p.add_argument("--task", type=Path, default=None, help="first run rendered walks of it")
    p.add_argument("--episodes", type=int, default=30, help="rendered walks to run first")
    p.add_argument("--seed", type=int, default=101, help="seed of those walks")
    p.add_argument("--workers", type=int, default=2, help="local processes")
    p.add_argument("--out", type=Path, default=Path("runs/fit-perception"), help="their folder")
    p.add_argument("--walks", type=Path, default=None,
                   help="their walk distribution (default config/walks.yaml)")  # fmt: skip
    p.set_defaults(func=cmd_fit_perception)

    p = _command(
        sub, "montecarlo", "the whole loop in-process (dm-control) over randomised walks and faults"
    )
    p.add_argument(
        "task", type=Path, nargs="?", default=None, help="task file, e.g. config/task-r1.yaml"
    )
    p.add_argument("--episodes", type=int, default=12, help="randomised episodes")
    p.add_argument("--walks", type=Path, default=None,
                   help="walk distribution (YAML; default config/walks.yaml)")  # fmt: skip
    p.add_argument("--scenarios", type=Path, default=None,
                   help="run every scenario file of this folder instead (no TASK)")  # fmt: skip
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="local processes (or Ray CPUs); default: one per core")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the walks and faults")
    p.add_argument("--out", type=Path, default=Path("runs/montecarlo"), help="results folder")
    p.add_argument("--ray", default=None, help="'local' or a Ray cluster address")
    p.add_argument("--config", type=Path, default=None, help="deployment file")
    p.add_argument("--p-fault", type=float, default=None, help="chance of a sensor outage")
    p.add_argument("--max-sim-s", type=float, default=None, help="episode length bound")
    p.add_argument(
        "--perception",
        choices=("model", "rendered"),
        default="model",
        help="the camera: its fitted model (fast, default) or rendered + HOG (the reference)",
    )
    p.add_argument("--perception-model", type=Path, default=None, help="the model file")
    p.add_argument("--rescore", type=Path, default=None, metavar="DIR",
                   help="score the study in DIR again with today's metrics (no runs)")  # fmt: skip
    p.set_defaults(func=cmd_montecarlo)

    p = _command(sub, "launch", "start the whole system from a deployment file; Ctrl-C stops it")
    p.add_argument("config", help="config/twin.yaml or config/hardware.yaml")
    p.add_argument(
        "--out",
        default="runs/launch",
        help="run folder, by vigil run's rules: an earlier run's is kept (the launch goes "
        "to OUT-2, ...), one vigil did not make is refused",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="resume the planner from the newest earlier launch into OUT, if it had the "
        "same deployment, task and policy and is younger than --resume-max-age-s",
    )
    p.add_argument(
        "--resume-max-age-s",
        type=float,
        default=DEFAULT_RESUME_MAX_AGE_S,
        help=f"the oldest planner state --resume takes [s], default {DEFAULT_RESUME_MAX_AGE_S:g}",
    )
    p.add_argument(
        "--host",
        default=None,
        help="start only this host's nodes (the deployment's hosts: the system over "
        "several machines, each running vigil launch FILE --host NAME)",
    )
    p.add_argument(
        "--scenario",
        default=None,
        help="twin only: the scenario's walk, start and steps; the host with the planner "
        "ends once its steps are made (and, with the recorder, writes the report)",
    )
    p.set_defaults(func=cmd_launch)

    p = _command(
        sub,
        "arm",
        "arm the robot's velocity gate through its parameter service and confirm it from "
        "the gate's own status (exit 3: no gate answered, 4: the gate refused or did not "
        "confirm, 5: a check refused, see --force)",
    )
    _operator_args(p)
    p.add_argument(
        "--wait",
        type=float,
        default=1.5,
        help="seconds to listen to /diagnostics before arming, for the checks",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="arm although a check refuses (a component at ERROR, caps above the "
        "deployment's, a non-finite command, another publisher of the base topic)",
    )
    p.set_defaults(func=cmd_arm)

    p = _command(
        sub,
        "disarm",
        "disarm the robot's velocity gate: its parameter and false on its arm topic at once, "
        "until the gate confirms (exit 3: no gate answered, 4: not confirmed)",
    )
    _operator_args(p)
    p.set_defaults(func=cmd_disarm)

    p = _command(
        sub,
        "status",
        "the velocity gate (armed, reason, caps, heartbeat), the base's last command, the "
        "camera and every /diagnostics status heard (exit 0: all OK, 1: otherwise, a "
        "disarmed gate included)",
    )
    _operator_args(p)
    p.add_argument(
        "--wait", type=float, default=2.0, help="seconds to listen once the gate is found"
    )
    p.add_argument("--json", action="store_true", help="print the state as JSON")
    p.set_defaults(func=cmd_status)

    p = _command(sub, "calibrate", "the ceiling camera's floor homography")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--twin", help="twin config YAML ('default' for the built-in scene)")
    g.add_argument("--points", help="YAML of clicked/measured {pixel: [u, v], map: [x, y]}")
    p.add_argument("-o", "--output", required=True, help="the calibration YAML to write")
    p.set_defaults(func=cmd_calibrate)

    p = _command(sub, "security", "SROS2 for hardware mode (docs/SAFETY.md)")
    sec = p.add_subparsers(dest="security_command", required=True)
    q = _command(sec, "keystore", "write a keystore: CA, enclaves, governance, permissions")
    q.add_argument("path", help="a new or empty folder")
    q.add_argument("--domain", type=int, required=True, help="the deployment's ros.domain_id")
    q.add_argument("--base-topic", default=topic.CMD_VEL, help="the base driver's velocity topic")
    q.set_defaults(func=cmd_security_keystore)
    q = _command(sec, "check", "can the installed DDS enforce a keystore?")
    q.set_defaults(func=cmd_security_check)

    p = _command(
        sub,
        "replay-report",
        "solve both tasks, replay chapter 5's tables, simulate, write a report ('main' is an "
        "older name for it)",
        aliases=["main"],
    )
    p.add_argument("--out", default="runs/main", help="report folder")
    p.add_argument("--episodes", type=int, default=50, help="simulated episodes per task")
    _task_solver_args(p)
    p.set_defaults(func=cmd_main)
    return ap


def cmd_run(args: argparse.Namespace) -> int:
    from vigil.run import RunError, run_scenario

    try:
        summary = run_scenario(
            args.scenario,
            args.config,
            args.out,
            args.seed,
            args.observations,
            args.timeout,
            realtime=args.realtime,
        )
    except RunError as err:  # the first cause in one line, an exit code per cause
        print(f"vigil run: {err}", file=sys.stderr)
        return err.code
    keys = ("steps", "total_discounted_reward", "left_map", "returned_to_rest")
    print(json.dumps({k: summary.get(k) for k in keys}, sort_keys=True))
    return 0


def cmd_replay_bag(args: argparse.Namespace) -> int:
    from vigil.replay_bag import ReplayError, comparison_markdown, replay_run

    def say(line: str) -> None:
        print(line, flush=True)

    try:
        result = replay_run(args.run, args.out, say=say, stall_s=args.stall)
    except ReplayError as err:
        print(f"vigil replay-bag: error: {err}", file=sys.stderr)
        return 2
    print(comparison_markdown(result.comparison), end="")
    if result.note:
        print(f"note: {result.note}")
    print(f"[replay-bag] {result.out_dir}/replay.md ({result.wall_s:.0f} s)")
    return 0 if result.comparison.matches else 1


def cmd_bag_reindex(args: argparse.Namespace) -> int:
    from vigil.bag_salvage import closed_cleanly, salvage_bag

    bag = Path(args.bag)
    if closed_cleanly(bag):
        print(f"{bag} has its metadata.yaml: it was closed cleanly, nothing to salvage")
        return 0
    result = salvage_bag(bag)  # SalvageError (a ValueError): one line, exit 2 (main)
    print("\n".join(result.lines()))
    return 0


def cmd_experiments(args: argparse.Namespace) -> int:
    from vigil.experiments import run_set, write_docs

    record = run_set(
        args.scenarios,
        args.out,
        config=args.config,
        seed=args.seed,
        report_only=args.report_only,
        only=args.only,
        realtime=args.realtime,
    )
    if args.docs:
        doc = write_docs(args.docs, args.out, args.label, args.heading)
        print(f"updated the section {args.label!r} of {doc}")
    print(json.dumps(record["totals"], sort_keys=True))
    return 1 if any(e["error"] for e in record["scenarios"]) else 0


def cmd_fit_perception(args: argparse.Namespace) -> int:
    from vigil.fit_perception import fit_folders
    from vigil.inprocess import DEFAULT_PERCEPTION_MODEL

    folders = list(args.folders)
    if args.task is not None:
        from vigil.montecarlo import run_study
        from vigil.walks import DEFAULT_WALKS, load_walks

        study = load_walks(args.walks or DEFAULT_WALKS)
        record = run_study(args.task, args.episodes, args.out, args.seed, args.workers,
                           study=study, perception="rendered")  # fmt: skip
        folders.append(Path(record["out"]))  # <out>-2 when OUT held an earlier run
    if not folders:
        from stack.cells import ConfigError

        raise ConfigError("folders", [], "give rendered run folders, or --task to run some")
    fit_folders(folders, args.output or DEFAULT_PERCEPTION_MODEL)
    return 0


def cmd_montecarlo(args: argparse.Namespace) -> int:
    from stack.cells import ConfigError
    from vigil.montecarlo import load_scenario_folder, rescore_study, run_study
    from vigil.walks import DEFAULT_WALKS, load_walks

    if args.rescore is not None:
        if args.task is not None or args.scenarios is not None:
            raise ConfigError("--rescore", str(args.rescore), "takes no TASK or --scenarios")
        record = rescore_study(args.rescore)
        print(json.dumps(record["summary"], sort_keys=True))
        return 0
    if (args.task is None) == (args.scenarios is None):
        raise ConfigError("TASK/--scenarios", args.task, "give a task or --scenarios DIR")
    study = load_walks(args.walks or DEFAULT_WALKS, p_fault=args.p_fault,
                       max_sim_s=args.max_sim_s)  # fmt: skip
    scenarios = None if args.scenarios is None else load_scenario_folder(args.scenarios)
    record = run_study(
        args.task,
        args.episodes,
        args.out,
        args.seed,
        args.workers,
        args.ray,
        args.config,
        study,
        perception=args.perception,
        perception_model=args.perception_model,
        scenarios=scenarios,
    )
    print(json.dumps(record["summary"], sort_keys=True))
    return 1 if record["summary"]["failed_episodes"] else 0


def cmd_security_keystore(args: argparse.Namespace) -> int:
    from vigil.security import KeystoreError, main_keystore

    try:
        return main_keystore(args.path, args.domain, args.base_topic)
    except KeystoreError as exc:
        print(f"vigil security: error: {exc}", file=sys.stderr)
        return 2


def cmd_security_check(args: argparse.Namespace) -> int:
    from vigil.security import security_support

    ok, why = security_support()
    print(("enforceable: " if ok else "NOT enforceable: ") + why)
    return 0 if ok else 1


def cmd_launch(args: argparse.Namespace) -> int:
    from vigil.launch_command import launch

    return launch(
        args.config,
        args.out,
        resume=args.resume,
        resume_max_age_s=args.resume_max_age_s,
        host=args.host,
        scenario=args.scenario,
    )


def _operator_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("config", help="the robot's deployment file, e.g. config/hardware.yaml")
    p.add_argument(
        "--timeout",
        type=float,
        default=5.0,
        help="seconds to wait for the gate to appear (DDS discovery takes 0-3 s), and "
        "again for its answer",
    )


def _seconds(name: str, value: float) -> float:
    import math

    from stack.cells import ConfigError

    if not (math.isfinite(value) and 0 < value <= 3600):
        raise ConfigError(name, value, "must be a number of seconds in (0, 3600]")
    return value


def _operator(args: argparse.Namespace, run) -> int:
    """Run an operator command: its one-line errors and exit codes (vigil/operator.py)."""
    from vigil.deployment import load_deployment
    from vigil.operator import OperatorError, hardware_deployment

    for name in ("timeout", "wait"):
        if hasattr(args, name):
            _seconds(f"--{name}", getattr(args, name))
    dep = hardware_deployment(load_deployment(args.config))
    try:
        return run(dep)
    except OperatorError as err:
        print(f"vigil {args.command}: error: {err}", file=sys.stderr)
        return err.code
    except KeyboardInterrupt:
        print(f"vigil {args.command}: interrupted", file=sys.stderr)
        return 130


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def cmd_arm(args: argparse.Namespace) -> int:
    from vigil.operator import arm

    return _operator(args, lambda dep: arm(dep, args.timeout, args.wait, args.force, warn=_stderr))


def cmd_disarm(args: argparse.Namespace) -> int:
    from vigil.operator import disarm

    return _operator(args, lambda dep: disarm(dep, args.timeout))


def cmd_status(args: argparse.Namespace) -> int:
    from vigil.operator import status

    return _operator(args, lambda dep: status(dep, args.wait, args.json, args.timeout))


def cmd_calibrate(args: argparse.Namespace) -> int:
    from stack.perception.homography import calibrate, load_points_file, save_calibration

    if args.twin:
        from twin.calibration import calibrate_twin
        from twin.config import TwinConfig, load_twin_config
        from twin.twin import Twin

        cfg = load_twin_config(args.twin) if args.twin != "default" else TwinConfig()
        with Twin(cfg, seed=0) as tw:
            cal = calibrate_twin(tw)
    else:
        pts = load_points_file(args.points)
        cal = calibrate(pts.image_px, pts.map_m, image_size_px=pts.image_size_px)
    save_calibration(args.output, cal)
    print(
        f"calibration: {len(cal.errors_m)} points, reprojection error mean "
        f"{cal.mean_error_m * 100:.2f} cm, max {cal.max_error_m * 100:.2f} cm -> {args.output}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    from stack.perception.errors import CalibrationError
    from stack.planning import clock

    wall_start = clock.process_start() if argv is None else time.perf_counter()
    args = build_parser().parse_args(argv)
    clock.use_cpu_time(bool(getattr(args, "cpu_time", False)))
    if clock.cpu_time():  # CPU seconds of this process: a process of its own starts at 0
        args.start = 0.0 if argv is None else clock.now()
    else:  # in-process calls: from here
        args.start = wall_start
    args.standalone = argv is None  # a process of its own, not a call from Python
    try:
        return args.func(args)
    except (ValueError, OSError, CalibrationError) as exc:  # config, model and file errors
        text = " ".join(str(exc).split())  # one line, whatever the message holds
        print(f"vigil {args.command}: error: {text}", file=sys.stderr)
        return 2
    finally:
        clock.use_cpu_time(False)  # an in-process call leaves the solvers on wall time


if __name__ == "__main__":
    sys.exit(main())
