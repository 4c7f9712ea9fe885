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
from stack.lockstep import RUN_ID_ENV  # read by stack.ros_lockstep (acks) and the twin bridge
from vigil.deployment import load_deployment
from vigil.launch import Launcher
from vigil.ros_domain import claim_domain
from vigil.run_folder import MAX_NUMBERED, RUN_MARK, fresh_run_dir  # noqa: F401 (re-exported)
from vigil.scenario import load_scenario
from vigil.system import prepare, prepare_table

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = REPO / "config" / "twin.yaml"


class RunError(RuntimeError):
    """The run could not finish (a node died for good, or it timed out)."""


def _records(path: Path) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
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

    Raises:
        ConfigError: a bad scenario or deployment file.
        RunError: a node died for good, or the run timed out.
    """
    from stack.planning.replay import TABLES
    from vigil.report import write_report

    scenario = load_scenario(scenario_path)
    if seed is not None:
        scenario = replace(scenario, seed=seed)
    dep = load_deployment(config_path or DEFAULT_CONFIG)
    run_id = uuid.uuid4().hex[:12]
    run_dir = fresh_run_dir(Path(out or REPO / "runs" / scenario.name).resolve(), run_id)
    say(f"[run] folder {run_dir}")
    say(f"[run] {scenario.name}: {scenario.title} ({scenario.steps} steps, seed {scenario.seed})")
    if observations == "table":
        system = prepare_table(dep, run_dir, scenario, say)
    elif observations == "twin":
        if dep.mode != "twin":
            raise ConfigError("mode", dep.mode, "vigil run needs a twin deployment")
        system = prepare(dep, run_dir, scenario, say=say)
    else:
        raise ConfigError("observations", observations, "must be twin or table")

    claim = None
    if dep.ros.domain_id < 0:  # a private domain: a parallel run never hears this one
        claim = claim_domain()
        system.env["ROS_DOMAIN_ID"] = str(claim.domain_id)
    system.env[RUN_ID_ENV] = run_id  # the lock-step ignores another run's nodes
    say(f"[run] ROS domain {system.env.get('ROS_DOMAIN_ID', '(environment)')}, run id {run_id}")
    launcher = Launcher(system.specs, run_dir / "logs", system.env, dep.nodes.max_restarts, say=say)
    kills = [f for f in scenario.faults if f.kind == "kill"]
    t0 = time.monotonic()
    shown = 0
    error = None
    launcher.start()
    try:
        while True:
            if not launcher.poll():
                error = f"the system stopped: {launcher.stopped_because}"
                break
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
                break
            if time.monotonic() - t0 > timeout_s:
                error = f"timed out after {timeout_s:.0f} s at step {shown}/{scenario.steps}"
                break
            time.sleep(0.2)
    finally:
        codes = launcher.stop(dep.nodes.stop_timeout_s)
        if claim is not None:
            claim.release()
    if error is None and launcher.failures:
        error = "node failures: " + "; ".join(launcher.failures)
    wall_s = time.monotonic() - t0
    say(f"[run] stopped after {wall_s:.0f} s: " + ", ".join(f"{k} {v}" for k, v in codes.items()))
    table = TABLES.get(scenario.thesis_table)
    summary = write_report(run_dir, scenario.task, table, say=say)
    (run_dir / "run.json").write_text(
        json.dumps(
            {
                "scenario": scenario.name,
                "seed": scenario.seed,
                "observations": observations,
                "wall_s": round(wall_s, 1),
                "exit_codes": codes,
                "failures": launcher.failures,
                "run_id": run_id,
                "error": error,
            },
            indent=2,
            sort_keys=True,
        )
    )
    say(f"[run] report: {run_dir}/steps.md, positions.png, belief.png, summary.json")
    if error:
        raise RunError(error)
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
