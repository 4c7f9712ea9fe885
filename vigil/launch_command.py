"""``vigil launch CONFIG``: the whole system from a deployment file, until Ctrl-C.

:func:`prepare_launch` makes the run folder (``vigil run``'s rules) and decides whether
the planner resumes an earlier launch's state (:mod:`vigil.resume`); :func:`launch`
starts the nodes with :class:`vigil.launch.Launcher`, shows each one appear in the ROS
graph (:class:`GraphWatch`), and writes ``run.json`` however it ends. With ``--host``
only one host's nodes start (the system over several machines); with ``--scenario``
(twin) the host with the planner ends once the scenario's steps are made.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from stack.cells import ConfigError
from stack.lockstep import RUN_ID_ENV
from vigil.launch import Launcher
from vigil.resume import (  # re-exported: the resumption's rules
    DEFAULT_RESUME_MAX_AGE_S,
    IDENTITY_FILE,
    MAX_HASHED_BYTES,
    STATE_FILE,
    planner_identity,
    previous_state,
    resume_decision,
)

if TYPE_CHECKING:
    from vigil.scenario import Scenario

__all__ = [
    "DEFAULT_RESUME_MAX_AGE_S",
    "IDENTITY_FILE",
    "MAX_HASHED_BYTES",
    "STATE_FILE",
    "GraphWatch",
    "Launcher",
    "launch",
    "planner_identity",
    "prepare_launch",
    "previous_state",
    "resume_decision",
]


class GraphWatch:
    """Says when each node appears in the ROS graph (a small rclpy node of our own)."""

    def __init__(self, names: list[str], say: Callable[[str], None] = print):
        import rclpy

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("vigil_launch", context=self.context)
        self.waiting = list(names)
        self.say = say

    def poll(self) -> list[str]:
        """Names that came up since the last call."""
        if not self.waiting:
            return []
        present = set(self.node.get_node_names())
        up = [n for n in self.waiting if n in present]
        for n in up:
            self.waiting.remove(n)
            self.say(f"[launch] up: {n}")
        return up

    def close(self) -> None:
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


def _write_new(path: Path, data: bytes) -> None:
    """Create ``path`` (never over an existing file, never through a link)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def prepare_launch(
    config: str | Path,
    out: str | Path,
    resume: bool = False,
    resume_max_age_s: float = DEFAULT_RESUME_MAX_AGE_S,
    say: Callable[[str], None] = print,
    host: str | None = None,
    scenario: Scenario | None = None,
):
    """Everything ``vigil launch`` does before a process starts; returns (deployment,
    system, run id). ``scenario`` (twin only): its walk, start and steps.

    The run folder follows ``vigil run``'s rules (:func:`vigil.run_folder.fresh_run_dir`): a
    new or empty folder is used, an earlier run's folder is kept and the launch goes to
    ``<out>-2``, ``-3``, ..., any other non-empty folder is refused. A planner state of
    an earlier launch is copied into the new folder only under :func:`resume_decision`.

    Raises:
        ConfigError: a bad deployment, ``--out`` or ``--resume-max-age-s``.
    """
    from stack.config import read_text_capped
    from stack.hardware.base_watchdog import check_timeout
    from vigil.deployment import load_deployment
    from vigil.run_folder import fresh_run_dir
    from vigil.system import host_specs, prepare

    max_age_s = check_timeout("--resume-max-age-s", resume_max_age_s)
    dep = load_deployment(config)
    if scenario is not None and dep.mode != "twin":
        raise ConfigError("--scenario", scenario.name, "a scenario needs a twin deployment")
    out = Path(out).resolve()
    earlier = previous_state(out)
    run_id = uuid.uuid4().hex[:12]
    run_dir = fresh_run_dir(out, run_id)
    say(f"[launch] folder {run_dir}")
    system = prepare(dep, run_dir, scenario, say=say)
    if dep.nodes.processes == "one":
        say("[launch] nodes.processes: one is for vigil run; vigil launch starts a process a node")
    if host is not None:  # one host of several: its own nodes only (the deployment's hosts)
        specs = host_specs(system, dep, host)
        system = replace(system, specs=specs)
        say(f"[launch] host {host}: " + ", ".join(s.name for s in specs))
    planner = system.params.get("planner", {})
    identity = planner_identity(dep.source, planner)
    _write_new(run_dir / IDENTITY_FILE, (json.dumps(identity, indent=2) + "\n").encode())
    state, line = resume_decision(earlier, identity, resume, max_age_s, time.time())
    if state is not None and planner.get("state_file"):
        _write_new(Path(planner["state_file"]), read_text_capped(state).encode())
    say(f"[launch] {line}")
    return dep, system, run_id


def count_lines(path: Path) -> int:
    """Complete lines of a file that may not exist yet (the planner's steps)."""
    try:
        return path.read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def _report(run_dir: Path, scenario: Scenario, say: Callable[[str], None]) -> str:
    """The run's report from what this host recorded (a speech log on another host is
    not here: its warnings are then not counted); "written" or why not."""
    from vigil.ending import one_line
    from vigil.report import write_report

    try:
        write_report(run_dir, scenario.task, None, say=say)
    except Exception as err:  # noqa: BLE001 - the launch's own ending stands
        line = one_line(f"{type(err).__name__}: {err}")
        say(f"[launch] report not written: {line}")
        return f"failed: {line}"
    say(f"[launch] report: {run_dir}/steps.md, summary.json")
    return "written"


def launch(
    config: str | Path,
    out: str | Path,
    say: Callable[[str], None] = print,
    resume: bool = False,
    resume_max_age_s: float = DEFAULT_RESUME_MAX_AGE_S,
    host: str | None = None,
    scenario: str | Path | None = None,
) -> int:
    """``vigil launch CONFIG``: start the system, show each node up, run until a signal
    or until a node dies for good; returns the exit code of the first cause
    (:mod:`vigil.ending`). With ``scenario`` (twin only) the twin walks the scenario's
    people and the planner makes its steps; the host that runs the planner then ends
    ("finished", exit 0) and, if it runs the recorder too, writes the run's report
    (steps.md, summary.json, ...) as ``vigil run`` does; the other hosts run on until
    stopped.

    SIGINT (Ctrl-C) and SIGTERM are how an operator stops a launch: every node leaving
    cleanly then exits 0. A node that died (or failed to stop cleanly), a full disk or a
    stalled lock-step exits with its own code; SIGHUP (the terminal went away) 129.
    Every ending writes ``run.json`` (``ending``, ``cause``, ``exit_code``, the nodes'
    exit codes and failures) into the launch's folder.

    The run folder and the planner's resumption: :func:`prepare_launch`. With ``host``,
    only that host's nodes of the deployment's ``hosts`` start (the system over several
    hosts: each runs ``vigil launch FILE --host NAME``).

    Raises:
        ConfigError: a bad deployment, ``--out`` or ``--resume-max-age-s``.
    """
    from vigil.ending import (
        EXIT_OK,
        Ending,
        Interrupted,
        Signals,
        from_launcher,
        is_disk_full,
        one_line,
        operator_stop,
        release,
        reserve,
        write_run_json,
    )
    from vigil.scenario import load_scenario

    signals = Signals()
    plan = load_scenario(scenario) if scenario is not None else None
    try:
        dep, system, run_id = prepare_launch(config, out, resume, resume_max_age_s, say, host, plan)
    except Interrupted as err:
        signals.restore()
        say(f"[launch] {err.name}: stopped before any node started")
        return Ending(err.name, err.name).code
    except BaseException:
        signals.restore()
        raise
    t0 = time.monotonic()
    run_dir = system.run_dir
    reserve(run_dir)
    logs = run_dir / "logs"
    claim = None
    launcher = Launcher(system.specs, logs, system.env, dep.nodes.max_restarts, say,
                        dep.nodes.restart_delay_s)  # fmt: skip
    watch = None
    ending: Ending | None = None
    crash: BaseException | None = None
    try:
        if dep.mode == "twin" and dep.ros.domain_id < 0:  # private: no parallel run hears it
            from vigil.ros_domain import claim_domain

            claim = claim_domain()
            system.env["ROS_DOMAIN_ID"] = str(claim.domain_id)
            launcher.env["ROS_DOMAIN_ID"] = str(claim.domain_id)
        system.env.setdefault(RUN_ID_ENV, run_id)
        launcher.env.setdefault(RUN_ID_ENV, run_id)
        say(f"[launch] ROS domain {system.env.get('ROS_DOMAIN_ID', '(environment)')}")
        for key, value in system.env.items():
            os.environ[key] = value  # the graph watch must look at the system's own domain
        watch = GraphWatch([s.name for s in system.specs], say)
        launcher.start()
        signals.watching()
        say(f"[launch] {dep.mode} mode, logs in {logs}; Ctrl-C stops everything")
        names = {s.name for s in system.specs}
        steps_to_make = plan.steps if plan is not None and "planner" in names else 0
        while signals.first is None and launcher.poll():
            watch.poll()
            if steps_to_make and count_lines(run_dir / "steps.jsonl") >= steps_to_make:
                ending = Ending("finished", f"finished: {steps_to_make} steps")
                break
            time.sleep(0.2)
        if signals.first is not None:
            say(f"[launch] {signals.first}: stopping")
            ending = operator_stop(signals.first)
    except Interrupted as err:
        ending = operator_stop(err.name)
    except BaseException as err:  # noqa: BLE001 - recorded in run.json, then raised again
        crash = err
        if is_disk_full(err):
            ending = Ending("disk full", f"disk full: vigil: {one_line(str(err))}")
        else:
            ending = Ending("internal", f"vigil failed: {one_line(repr(err))}")
    finally:
        signals.cleaning()
        codes = launcher.stop(dep.nodes.stop_timeout_s)
        if watch is not None:
            watch.close()
        if claim is not None:
            claim.release()
        release(run_dir)
        signals.restore()
    if ending is None or ending.code == EXIT_OK:  # a node failed first, or at the stop
        ending = from_launcher(launcher) or ending
    if ending is None:
        ending = Ending("node", f"the system stopped: {launcher.stopped_because}")
    say("[launch] stopped: " + ", ".join(f"{k} {v}" for k, v in codes.items()))
    for failure in launcher.failures:
        say(f"[launch] failure: {failure}")
    record = {
        "command": "launch",
        "mode": dep.mode,
        "run_id": run_id,
        "ending": ending.kind,
        "cause": ending.cause,
        "exit_code": ending.code,
        "exit_codes": codes,
        "failures": launcher.failures,
        "wall_s": round(time.monotonic() - t0, 1),
    }
    if plan is not None:
        record["scenario"] = plan.name
    write_run_json(run_dir, record, say)
    if plan is not None and ending.kind == "finished" and "recorder" in names:
        record["report"] = _report(run_dir, plan, say)
        write_run_json(run_dir, record, say)
    say(f"[launch] ended: {ending.cause} (exit {ending.code})")
    if crash is not None:
        raise crash
    return ending.code
