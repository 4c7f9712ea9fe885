"""Start a set of node processes, watch them, restart or stop them, and say what happened.

ROS 2 has no ``ros2 launch`` here, so this is the launcher: each node is a process
(``python -m <module> --ros-args --params-file <file>``) with its output in
``<log_dir>/<name>.log``. :meth:`Launcher.poll` notices a process that exited: a node
marked ``restart`` is started again (up to ``max_restarts`` times), any other exit
stops everything and :attr:`Launcher.stopped_because` names the node. :meth:`stop`
sends SIGINT to every process group (the nodes leave cleanly: zero velocity, files
closed), then SIGTERM, then SIGKILL to what is left.
"""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from stack.exits import EXIT_DISK_FULL, TEARDOWN_S, TEARDOWN_SIGNAL
from stack.files import make_dir, open_write
from stack.lockstep import RUN_ID_ENV
from vigil.processes import ProcessSpec
from vigil.resume import (  # re-exported: the resumption's rules
    DEFAULT_RESUME_MAX_AGE_S,
    IDENTITY_FILE,
    MAX_HASHED_BYTES,
    STATE_FILE,
    planner_identity,
    previous_state,
    resume_decision,
)


def _child_setup(nice: int) -> None:
    """In the child, before exec: :func:`_die_with_parent`, then the spec's niceness."""
    _die_with_parent()
    if nice:
        os.nice(nice)


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM when the launcher dies, however it dies
    (Linux prctl PR_SET_PDEATHSIG), so a killed launcher never leaves a twin running.
    SIGINT and SIGTERM are reset to their defaults: a launcher started with them ignored
    (a background job, a test runner) must still be able to stop its nodes gently."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:  # not Linux: the launcher's own stop() still applies
        pass


@dataclass
class _Running:
    spec: ProcessSpec
    proc: subprocess.Popen
    log: object
    restarts: int = 0
    killed: bool = False  # by :meth:`Launcher.kill` (an injected fault), not a failure


class Launcher:
    """Runs the processes of one system.

    Args:
        specs: the processes, started in this order.
        log_dir: where each process's output goes.
        env: environment for all of them (on top of this process's).
        max_restarts: restarts allowed per process.
        say: where status lines go.
        restart_delay_s: a process that exited is started again this long after (like
            ``respawn_delay`` of ros2 launch or systemd's ``RestartSec``): a node that
            dies at start does not spin, and the rest of the system sees it absent.
    """

    def __init__(
        self,
        specs: list[ProcessSpec],
        log_dir: Path,
        env: dict[str, str] | None = None,
        max_restarts: int = 3,
        say: Callable[[str], None] = print,
        restart_delay_s: float = 0.0,
    ):
        self.specs = list(specs)
        self.restart_delay_s = float(restart_delay_s)
        # exited processes waiting for their restart: name -> (spec, restarts, due time)
        self.waiting: dict[str, tuple[ProcessSpec, int, float]] = {}
        self.log_dir = Path(log_dir)
        self.env = {**os.environ, **(env or {})}
        self.max_restarts = max_restarts
        self.say = say
        self.running: dict[str, _Running] = {}
        self.stopped_because: str | None = None
        self.exit_codes: dict[str, int | None] = {}
        self.failures: list[str] = []  # "<name> exited (code N): <last log line>"
        # what went wrong without failing the system (a teardown ended by its alarm)
        self.warnings: list[str] = []
        # the first of them: (name, exit code, line); vigil.ending classifies it
        self.first_failure: tuple[str, int | None, str] | None = None

    def _failed(self, name: str, rc: int | None, line: str) -> None:
        self.failures.append(line)
        if self.first_failure is None:
            self.first_failure = (name, rc, line)

    def _spawn(self, spec: ProcessSpec, restarts: int = 0) -> None:
        self.log_dir.parent.mkdir(parents=True, exist_ok=True)
        make_dir(self.log_dir)  # never a link planted under the name
        log = open_write(self.log_dir / f"{spec.name}.log", "a")
        if restarts:
            log.write(f"\n--- restart {restarts} ---\n")
            log.flush()
        env = {**self.env, **spec.env}
        if env.get("ROS_SECURITY_KEYSTORE"):  # SROS2: each node in its own enclave
            env.setdefault("ROS_SECURITY_ENCLAVE_OVERRIDE", f"/vigil/{spec.name}")
        proc = subprocess.Popen(
            spec.argv(),
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,  # its own process group: Ctrl-C reaches us first
            preexec_fn=functools.partial(_child_setup, spec.nice),
        )
        self.running[spec.name] = _Running(spec, proc, log, restarts)

    def start(self) -> None:
        for spec in self.specs:
            self._spawn(spec)
            self.say(f"[launch] started {spec.name} (pid {self.running[spec.name].proc.pid})")

    def pids(self) -> dict[str, int]:
        return {name: r.proc.pid for name, r in self.running.items()}

    def poll(self) -> bool:
        """Handle exited processes; False once the system has stopped."""
        if self.stopped_because is not None:
            return False
        now = time.monotonic()
        for name, (spec, restarts, due) in list(self.waiting.items()):
            if now >= due:
                del self.waiting[name]
                self._spawn(spec, restarts)
                self.say(
                    f"[launch] started {name} (pid {self.running[name].proc.pid}): "
                    f"restart {restarts}/{self.max_restarts}"
                )
        for name, r in list(self.running.items()):
            rc = r.proc.poll()
            if rc is None:
                continue
            r.log.close()
            if not r.killed:
                self._failed(name, rc, self._why(name, rc))
            # a full disk is not cured by a restart: the system stops
            if r.spec.restart and r.restarts < self.max_restarts and rc != EXIT_DISK_FULL:
                if self.restart_delay_s > 0:
                    del self.running[name]
                    self.waiting[name] = (r.spec, r.restarts + 1, now + self.restart_delay_s)
                    self.say(
                        f"[launch] {name} exited (code {rc}); restarting "
                        f"({r.restarts + 1}/{self.max_restarts}) in {self.restart_delay_s:g} s"
                    )
                    continue
                self._spawn(r.spec, r.restarts + 1)
                self.say(
                    f"[launch] {name} exited (code {rc}); restarting "
                    f"({r.restarts + 1}/{self.max_restarts}): pid {self.running[name].proc.pid}"
                )
                continue
            self.exit_codes[name] = rc
            del self.running[name]
            self.stopped_because = self._why(name, rc)
            self.say(f"[launch] {self.stopped_because}: stopping the system")
            self.stop()
            return False
        return True

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to one node (fault injection); the launcher restarts it."""
        r = self.running[name]
        r.killed = True
        os.killpg(r.proc.pid, sig)

    def _why(self, name: str, rc: int | None) -> str:
        """``<name> exited (code N)``, with the last error line of its log if any."""
        last = last_error_line(self.log_dir / f"{name}.log")
        code = f"code {rc}"
        if rc is not None and rc < 0:
            try:
                code += f", {signal.Signals(-rc).name}"
            except ValueError:
                pass
        elif rc == EXIT_DISK_FULL:
            code += ", no space left on device"
        return f"{name} exited ({code})" + (f": {last}" if last else "")

    def stop(self, timeout_s: float = 5.0) -> dict[str, int | None]:
        """Stop every process: SIGINT, ``timeout_s`` later SIGTERM, then SIGKILL; returns
        exit codes. SIGKILL comes no sooner than 1 s after a node's own teardown alarm
        (``TEARDOWN_S`` after SIGINT, :func:`stack.ros_main.spin_node`), so a node whose
        ROS teardown hangs ends by its alarm: a warning, not a failure."""
        for sig, wait_s in (
            (signal.SIGINT, timeout_s),
            (signal.SIGTERM, max(2.0, TEARDOWN_S + 1.0 - timeout_s)),
            (signal.SIGKILL, 2.0),
        ):
            alive = [r for r in self.running.values() if r.proc.poll() is None]
            if not alive:
                break
            for r in alive:
                try:
                    os.killpg(r.proc.pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline and any(r.proc.poll() is None for r in alive):
                time.sleep(0.05)
        for name, r in self.running.items():
            rc = r.proc.poll()
            self.exit_codes[name] = rc
            r.log.close()
            if rc == -TEARDOWN_SIGNAL and not r.killed:  # its work done, DDS hung
                line = (f"{name}: its ROS teardown hung after its last words; ended by its "
                        f"own {TEARDOWN_S:g} s alarm (stacks in {name}.log)")  # fmt: skip
                self.warnings.append(line)
                self.say(f"[launch] warning: {line}")
            elif rc != 0 and not r.killed:  # a node that did not leave cleanly on SIGINT
                self._failed(name, rc, self._why(name, rc) + " at shutdown")
        self.running.clear()
        if self.stopped_because is None:
            self.stopped_because = "stopped"
        return dict(self.exit_codes)


def last_error_line(path: Path, tail_bytes: int = 16384) -> str:
    """The last line of a log that reads as an error ("" if none or unreadable)."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - tail_bytes))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return ""
    marks = ("[ERROR]", "[FATAL]", "Error:", "Error ", "error:")
    for line in reversed(lines):
        if any(m in line for m in marks):
            return line.strip()[:300]
    return ""


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


__all__ = [
    "DEFAULT_RESUME_MAX_AGE_S",
    "IDENTITY_FILE",
    "MAX_HASHED_BYTES",
    "STATE_FILE",
    "GraphWatch",
    "Launcher",
    "ProcessSpec",
    "launch",
    "planner_identity",
    "prepare_launch",
    "previous_state",
    "resume_decision",
]


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
):
    """Everything ``vigil launch`` does before a process starts; returns (deployment,
    system, run id).

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
    out = Path(out).resolve()
    earlier = previous_state(out)
    run_id = uuid.uuid4().hex[:12]
    run_dir = fresh_run_dir(out, run_id)
    say(f"[launch] folder {run_dir}")
    system = prepare(dep, run_dir, say=say)
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


def launch(
    config: str | Path,
    out: str | Path,
    say: Callable[[str], None] = print,
    resume: bool = False,
    resume_max_age_s: float = DEFAULT_RESUME_MAX_AGE_S,
    host: str | None = None,
) -> int:
    """``vigil launch CONFIG``: start the system, show each node up, run until a signal
    or until a node dies for good; returns the exit code of the first cause
    (:mod:`vigil.ending`).

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

    signals = Signals()
    try:
        dep, system, run_id = prepare_launch(config, out, resume, resume_max_age_s, say, host)
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
        while signals.first is None and launcher.poll():
            watch.poll()
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
    write_run_json(run_dir, record, say)
    say(f"[launch] ended: {ending.cause} (exit {ending.code})")
    if crash is not None:
        raise crash
    return ending.code
