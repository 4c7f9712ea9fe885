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
import os
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from stack.exits import EXIT_DISK_FULL, TEARDOWN_S, TEARDOWN_SIGNAL
from stack.files import make_dir, open_write
from vigil.processes import ProcessSpec


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
