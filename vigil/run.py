"""``vigil run SCENARIO``: one experiment through the real ROS stack, then its report.

The run starts every node (:mod:`vigil.system`, :mod:`vigil.launch`), prints a line
per decision step as the planner records it, injects the scenario's faults, stops the
system when the planner has made the scenario's steps, and writes the report
(:func:`vigil.run_report.write_report`) into the run folder.

With ``observations="table"`` the twin, perception and navigation are replaced by the
thesis table's observations (:mod:`vigil.node_table_player`), as chapter 5's
simulation entered them by hand; the planner node is the same.
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import replace
from pathlib import Path

from stack.cells import ConfigError
from stack.files import MAX_RECORD_BYTES, read_text_capped
from stack.lockstep import RUN_ID_ENV  # read by stack.ros_lockstep (acks) and the twin bridge
from vigil.container import one_process, split_logs
from vigil.deployment import load_deployment
from vigil.ending import (
    KINDS,
    Ending,
    Interrupted,
    Signals,
    from_launcher,
    is_disk_full,
    one_line,
    release,
    reserve,
    write_run_json,
)
from vigil.launch import Launcher
from vigil.ros_domain import claim_domain
from vigil.run_folder import MAX_NUMBERED, RUN_MARK, fresh_run_dir  # noqa: F401 (re-exported)
from vigil.scenario import load_scenario
from vigil.system import prepare, prepare_table

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = REPO / "config" / "twin.yaml"


class RunError(RuntimeError):
    """The run did not finish cleanly: a node died, the disk filled up, a signal, a stall,
    the timeout. ``ending`` holds the first cause and ``code`` the exit code
    (:mod:`vigil.ending`)."""

    def __init__(self, message: str, ending: Ending | None = None):
        super().__init__(message)
        self.ending = ending or Ending("node", message)

    @property
    def code(self) -> int:
        return self.ending.code


def _records(path: Path) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in read_text_capped(path, MAX_RECORD_BYTES).splitlines():
        try:
            out.append(json.loads(line))
        except ValueError:
            break  # a line being written
    return out


def run_scenario(
    scenario_path: str | Path,
    config_path: str | Path | None = None,
    out: str | Path | None = None,
    seed: int | None = None,
    observations: str = "twin",
    timeout_s: float = 1800.0,
    say=print,
    realtime: bool = False,
) -> dict:
    """Run a scenario end to end and write its report; returns the summary.

    Args:
        scenario_path: the scenario file (``scenarios/*.yaml``).
        config_path: the deployment file (default ``config/twin.yaml``).
        out: the run folder (default ``runs/<scenario name>``); a non-empty folder of
            an earlier run is kept and the run goes to ``<out>-2`` (see
            :func:`fresh_run_dir`), any other non-empty folder is refused.
        seed: overrides the scenario's seed.
        observations: "twin" (the whole stack in the twin) or "table" (the thesis
            table's observations through the planner node).
        timeout_s: wall-clock limit.
        realtime: the twin keeps the wall clock and the stack does not wait for it
            (hardware in the loop; the deployment's ``lockstep`` off, ``twin.realtime``
            on): the run's ``summary.json`` says how well it kept up (``realtime``).

    Every way out after the run folder exists (the run finished, a node died, the disk
    filled up, SIGINT, SIGTERM, SIGHUP, a stalled lock-step, the timeout, a bad file
    found while preparing) stops the nodes (the bag closes), writes ``run.json`` with
    the first cause (``ending``, ``cause``, ``exit_code``) and what report it can
    (:mod:`vigil.ending`).

    Raises:
        ConfigError: a bad scenario or deployment file.
        RunError: the run did not finish cleanly; ``.code`` is the exit code of its cause.
    """
    scenario = load_scenario(scenario_path)
    if seed is not None:
        scenario = replace(scenario, seed=seed)
    dep = load_deployment(config_path or DEFAULT_CONFIG)
    if realtime:
        dep = replace(dep, lockstep=False, twin=replace(dep.twin, realtime=True))
    run_id = uuid.uuid4().hex[:12]
    run_dir = fresh_run_dir(Path(out or REPO / "runs" / scenario.name).resolve(), run_id)
    signals = Signals()
    try:
        return _run(scenario, dep, run_dir, run_id, observations, timeout_s, signals, say)
    finally:
        signals.restore()


def _run(scenario, dep, run_dir: Path, run_id: str, observations: str, timeout_s: float,
         signals: Signals, say) -> dict:  # fmt: skip
    """:func:`run_scenario` once its folder exists: every way out writes ``run.json``."""
    from stack.planning.replay import TABLES

    t0 = time.monotonic()
    record = {
        "scenario": scenario.name,
        "seed": scenario.seed,
        "observations": observations,
        "run_id": run_id,
        "exit_codes": {},
        "failures": [],
        "warnings": [],
    }
    reserve(run_dir)  # room for run.json and the report if the disk fills up
    say(f"[run] folder {run_dir}")
    say(f"[run] {scenario.name}: {scenario.title} ({scenario.steps} steps, seed {scenario.seed})")
    try:
        system = _prepare(scenario, dep, run_dir, observations, say)
    except (Interrupted, ValueError, OSError) as err:  # ConfigError is a ValueError
        ending = _early_ending(err)
        release(run_dir)
        _finish(run_dir, record, ending, t0, None, say)
        if isinstance(err, Interrupted):
            raise RunError(ending.cause, ending) from None
        raise

    claim = None
    if dep.ros.domain_id < 0:  # a private domain: a parallel run never hears this one
        claim = claim_domain()
        system.env["ROS_DOMAIN_ID"] = str(claim.domain_id)
    system.env[RUN_ID_ENV] = run_id  # the lock-step ignores another run's nodes
    say(f"[run] ROS domain {system.env.get('ROS_DOMAIN_ID', '(environment)')}, run id {run_id}")
    launcher = Launcher(system.specs, run_dir / "logs", system.env, dep.nodes.max_restarts, say=say,
                        restart_delay_s=dep.nodes.restart_delay_s)  # fmt: skip
    ending: Ending | None = None
    crash: BaseException | None = None
    try:
        launcher.start()
        signals.watching()
        if signals.first is None:
            ending = _watch(launcher, scenario, run_dir, timeout_s, signals, say)
        else:
            ending = _signal_ending(signals.first, 0, scenario.steps)
    except BaseException as err:  # noqa: BLE001 - recorded, then raised again below
        crash = err
        if is_disk_full(err):
            ending = Ending("disk full", f"disk full: vigil: {one_line(str(err))}")
        elif isinstance(err, Interrupted | KeyboardInterrupt):
            ending = _signal_ending(getattr(err, "name", "SIGINT"), 0, scenario.steps)
            crash = None
        else:
            ending = Ending("internal", f"vigil failed: {one_line(repr(err))}")
    finally:
        signals.cleaning()  # from here a signal waits: the nodes stop, the bag closes
        codes = launcher.stop(dep.nodes.stop_timeout_s)
        split_logs(system, run_dir / "logs")
        if claim is not None:
            claim.release()
        release(run_dir)
    if ending is None or ending.kind == "finished":  # a node that failed along the way
        ending = from_launcher(launcher) or ending
    assert ending is not None
    record.update(exit_codes=codes, failures=launcher.failures, warnings=launcher.warnings)
    wall_s = time.monotonic() - t0
    say(f"[run] stopped after {wall_s:.0f} s: " + ", ".join(f"{k} {v}" for k, v in codes.items()))
    summary = _finish(
        run_dir, record, ending, t0, (scenario.task, TABLES.get(scenario.thesis_table)), say
    )
    ending = Ending(record["ending"], record["cause"])
    if crash is not None:
        raise crash
    if ending.code:
        raise RunError(ending.cause, ending)
    return summary or {}


def _prepare(scenario, dep, run_dir: Path, observations: str, say):
    if observations == "table":
        return prepare_table(dep, run_dir, scenario, say)
    if observations == "twin":
        if dep.mode != "twin":
            raise ConfigError("mode", dep.mode, "vigil run needs a twin deployment")
        system = prepare(dep, run_dir, scenario, say=say)
        return one_process(dep, system, scenario, say)
    raise ConfigError("observations", observations, "must be twin or table")


def _early_ending(err: BaseException) -> Ending:
    """The ending of a run stopped while its nodes were being prepared."""
    if isinstance(err, Interrupted):
        return Ending(err.name, f"{err.name}: stopped while preparing the run")
    if is_disk_full(err):
        return Ending("disk full", f"disk full: {one_line(str(err))}")
    return Ending("bad input", one_line(str(err)))


def _signal_ending(name: str, shown: int, total: int) -> Ending:
    return Ending(name, f"{name}: stopped at step {shown}/{total}")


def _watch(launcher, scenario, run_dir: Path, timeout_s: float, signals: Signals, say) -> Ending:
    """Show the steps, inject the kills, and return how the run ended."""
    kills = [f for f in scenario.faults if f.kind == "kill"]
    t0 = time.monotonic()
    shown = 0
    while True:
        if signals.first is not None:
            return _signal_ending(signals.first, shown, scenario.steps)
        if not launcher.poll():
            return from_launcher(launcher) or Ending(
                "node", f"the system stopped: {launcher.stopped_because}"
            )
        steps = _records(run_dir / "steps.jsonl")
        for rec in steps[shown:]:
            say("[run] " + _progress(rec, scenario.steps))
        shown = len(steps)
        for fault in list(kills):
            if shown >= fault.after_step and fault.node in launcher.running:
                say(f"[fault] killing {fault.node} after step {shown}")
                launcher.kill(fault.node)
                kills.remove(fault)
        if shown >= scenario.steps:
            return Ending("finished", f"finished: {shown} steps")
        if time.monotonic() - t0 > timeout_s:
            return Ending(
                "timeout", f"timed out after {timeout_s:.0f} s at step {shown}/{scenario.steps}"
            )
        time.sleep(0.2)


def _finish(run_dir: Path, record: dict, ending: Ending, t0: float, report, say) -> dict | None:
    """``run.json`` (first without the report, so that a report that fills the disk or
    fails still leaves the cause), then what report can be written, then ``run.json``
    again with the report's outcome; returns the report's summary (None if none)."""
    record.update(
        ending=ending.kind,
        cause=ending.cause,
        exit_code=ending.code,
        error=None if ending.code == 0 else ending.cause,
        wall_s=round(time.monotonic() - t0, 1),
        report="not written",
    )
    write_run_json(run_dir, record, say)
    summary = None
    if report is not None:
        from vigil.report import write_report

        task, table = report
        try:
            summary = write_report(run_dir, task, table, say=say)
            record["report"] = "written"
            say(f"[run] report: {run_dir}/steps.md, positions.png, belief.png, summary.json")
        except Exception as err:  # noqa: BLE001 - the first cause stays the run's
            line = one_line(f"{type(err).__name__}: {err}")
            record["report"] = f"failed: {line}"
            say(f"[run] report not written: {line}")
            if ending.kind == "finished":
                kind = "disk full" if is_disk_full(err) else "report"
                record.update(ending=kind, cause=f"{kind}: report: {line}")
                record.update(exit_code=KINDS[kind], error=record["cause"])
        record["wall_s"] = round(time.monotonic() - t0, 1)
        write_run_json(run_dir, record, say)
    say(f"[run] ended: {record['cause']} (exit {record['exit_code']})")
    return summary


def _progress(rec: dict, total: int) -> str:
    o = rec.get("observation") or {}
    t = rec.get("stamp_s") or 0.0
    when = f" t={t:.1f}s" if t < 1e6 else ""  # simulated time; wall-clock stamps not shown
    if o.get("people"):  # several people (issue 16): every slot's labels
        people = "; ".join(f"{p.get('person')}, {p.get('velocity')}" for p in o["people"])
        return (
            f"step {rec.get('step')}/{total}{when}: {rec.get('action')} -> "
            f"robot {o.get('robot', '-')}, people {people}"
        )
    return (
        f"step {rec.get('step')}/{total}{when}: {rec.get('action')} -> "
        f"robot {o.get('robot', '-')}, person {o.get('person', '-')}, {o.get('velocity', '-')}"
    )
