"""Chaos: a twin run (``vigil run``, lock-step, or at real time with the velocity gate
between navigation and the base) in which seeded random nodes are SIGKILLed at seeded
random times, and what must hold afterwards (issue 23).

:func:`run_chaos` starts ``vigil run`` as a process of its own, learns each node's pid
from the launcher's lines (``started <name> (pid N)``, ``restarting (k/m): pid N``),
kills a random victim's process group at random wall-clock times and waits for the run
to end. :func:`check_run` then reads the run folder:

- the base never kept its last non-zero ``/cmd_vel`` longer than its command timeout
  (+ two odometry periods) after it arrived: from then on it brakes at its acceleration
  limit to a standstill, measured in the bag's own time (simulated in lock-step, the
  system clock at real time) (:func:`base_holds`); the base's sender is among the
  victims (navigation; at real time the velocity gate, whose death the base also hears
  as its heartbeat stopping) and the twin bridge stands in for the base;
- ``steps.jsonl`` parses line by line and every bag folder opens with ``rosbags`` and
  reads to its end;
- the run ended with one line naming a cause, and ``run.json`` holds it.

The bridge and the recorder are not restarted (killing them ends the run), and a killed
bag node leaves its bag without an index (node_bag.py): they are not victims.

The gate runs only at real time (:func:`chaos_files` with ``realtime``): its stale
timeout keeps the wall clock, and in a lock-step twin, slower than real time, it would
send zeros between navigation's commands.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import stack.topics as topic
from stack.config import dump_yaml, load_yaml, read_text_capped, write_text

REPO = Path(__file__).resolve().parents[1]
VICTIMS = (
    "navigation",
    "planner",
    "localisation",
    "camera_people",
    "legs",
    "observations",
    "speech",
    "markers",
)
GATE_VICTIMS = (*VICTIMS, "velocity_gate")  # at real time, with the gate in the chain
ODOM_PERIOD_S = 0.04  # the twin's odometry (config/twin.yaml odom_rate_hz 25)
STILL = 0.06  # m/s and rad/s: below this the base stands (its odometry's noise: ~0.02)
_PID = re.compile(r"\[launch\] (?:started (\w+) \(pid (\d+)\)|(\w+) exited .*: pid (\d+))")


@dataclass
class Kill:
    at_s: float  # wall-clock seconds after the start
    node: str
    pid: int


@dataclass
class ChaosRun:
    out: Path
    returncode: int
    last_line: str
    kills: list[Kill] = field(default_factory=list)
    wall_s: float = 0.0
    lines: list[str] = field(default_factory=list)
    stderr: list[str] = field(default_factory=list)


def run_chaos(
    scenario: Path,
    config: Path,
    out: Path,
    kills: int,
    seed: int,
    first_s: float = 20.0,
    gap_s: tuple[float, float] = (5.0, 25.0),
    victims: tuple[str, ...] = VICTIMS,
    first: str | None = None,
    after_line: str = r"\[run\] step 1/",
    when_driving: bool = False,
    timeout_s: float = 3600.0,
    realtime: bool = False,
    say: Callable[[str], None] = lambda s: None,
) -> ChaosRun:
    """``vigil run SCENARIO --config CONFIG --out OUT`` with ``kills`` SIGKILLs: the
    first uniform ``(0, first_s)`` after a line matching ``after_line`` (the first
    decision step), then one every uniform ``gap_s``; the victims drawn uniformly
    (seeded by ``seed``) among those alive, the first one ``first`` if given; with
    ``when_driving`` the first kill waits (after its delay) until the recorder's trace
    shows the robot driving (:func:`driving`); ``realtime``: ``vigil run --realtime``.
    The run goes on (restarted nodes) until its steps are made."""
    import numpy as np

    rng = np.random.default_rng(seed)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("ROS_DOMAIN_ID", None)
    proc = subprocess.Popen(
        [sys.executable, "-u", "-m", "vigil.cli", "run", str(scenario), "--config", str(config),
         "--out", str(out), "--timeout", str(timeout_s), *(["--realtime"] if realtime else [])],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    pids: dict[str, int] = {}
    lines: list[str] = []
    stderr: list[str] = []

    def read_out() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line.rstrip())
            say(line.rstrip())
            m = _PID.search(line)
            if m:
                name, pid = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
                pids[name] = int(pid)

    def read_err() -> None:
        assert proc.stderr is not None
        stderr.extend(proc.stderr.read().splitlines())

    readers = [threading.Thread(target=f, daemon=True) for f in (read_out, read_err)]
    for t in readers:
        t.start()
    t0 = time.monotonic()
    done: list[Kill] = []
    pattern = re.compile(after_line)
    while proc.poll() is None and not any(pattern.search(x) for x in lines):
        time.sleep(0.2)
    next_s = time.monotonic() - t0 + float(rng.uniform(0.0, first_s))
    while proc.poll() is None and len(done) < kills:
        now = time.monotonic() - t0
        if now < next_s or (when_driving and not done and not driving(out)):
            time.sleep(0.2 if now >= next_s else min(0.2, next_s - now))
            continue
        alive = [n for n in victims if n in pids]
        if not alive:
            time.sleep(0.2)
            continue
        node = first if first in alive and not done else str(rng.choice(alive))
        try:
            os.killpg(pids[node], signal.SIGKILL)
            done.append(Kill(round(now, 1), node, pids[node]))
            say(f"[chaos] killed {node} (pid {pids[node]}) at {now:.0f} s ({len(done)}/{kills})")
        except ProcessLookupError:  # it was being restarted: try again soon
            pass
        pids.pop(node, None)  # its next pid comes with the restart line
        next_s = now + float(rng.uniform(*gap_s))
    proc.wait()
    for t in readers:
        t.join(timeout=10)
    last = stderr[-1] if stderr else (lines[-1] if lines else "")
    return ChaosRun(out, proc.returncode, last, done, time.monotonic() - t0, lines, stderr)


def driving(run_dir: Path, speed_mps: float = 0.2, braking_mps: float = 0.05) -> bool:
    """The recorder's last trace records (ground truth, simulated time) show the robot
    moving faster than ``speed_mps`` and not braking (its speed over the last interval
    not ``braking_mps`` below the one before): a robot that brakes may already have
    been sent its last, zero command, and a sender killed then leaves no silence."""
    try:
        with open(run_dir / "trace.jsonl", "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 8192))
            lines = f.read().decode(errors="replace").splitlines()[1:]
        recs = [json.loads(x) for x in lines[-4:-1]]  # the last one may be half written
    except (OSError, ValueError):
        return False
    if len(recs) < 3 or not all(r.get("robot") for r in recs):
        return False

    def speed(a: dict, b: dict) -> float:
        dt = b["t"] - a["t"]
        dx, dy = b["robot"][0] - a["robot"][0], b["robot"][1] - a["robot"][1]
        return ((dx * dx + dy * dy) ** 0.5 / dt) if dt > 0 else 0.0

    before, last = speed(recs[0], recs[1]), speed(recs[1], recs[2])
    return last > speed_mps and last > before - braking_mps


def _bags(run_dir: Path) -> list[Path]:
    return sorted(p for p in run_dir.glob("bag*") if p.is_dir())


def base_holds(bag: Path, timeout_s: float = 0.5) -> dict:
    """Every silence of ``/cmd_vel`` longer than the base's ``timeout_s`` after a
    non-zero command (a sender that died: only the base's own timeout can stop it), in
    the bag's (simulated) time. From ``timeout_s`` + two odometry periods after the last
    command the base's ``/odom`` speed must lie under its braking envelope: the speed it
    held until then less the acceleration limit times the time since, and never under
    :data:`STILL` (odometry is noisy, about 0.02 m/s at rest, and a person walking
    into the robot pushes it), until it first stands (below :data:`STILL`): what moves
    it after that is a new command. Returns ``silences``, ``excess`` (the largest speed above
    the envelope, m/s or rad/s; 0 when it held), ``worst_stop_s`` (the longest time
    from a last command to the first sample below :data:`STILL` or the next command)."""
    from rosbags.rosbag2 import Reader

    from twin.config import TwinConfig
    from vigil.bag import typestore

    robot = TwinConfig().robot
    store = typestore()
    cmds: list[tuple[int, bool]] = []
    odom: list[tuple[int, float, float]] = []  # (t, linear speed, |yaw rate|)
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic in (topic.CMD_VEL, topic.ODOM)]
        for conn, t_ns, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == topic.CMD_VEL:
                moving = max(abs(msg.linear.x), abs(msg.linear.y), abs(msg.angular.z)) > 0
                cmds.append((t_ns, moving))
            else:
                tw = msg.twist.twist
                odom.append((t_ns, math.hypot(tw.linear.x, tw.linear.y), abs(tw.angular.z)))
    cmds.sort()
    odom.sort()
    end = odom[-1][0] if odom else 0
    grace_ns = (timeout_s + 2 * ODOM_PERIOD_S) * 1e9
    silences, worst_stop, excess = 0, 0.0, 0.0
    for k, (t, moving) in enumerate(cmds):
        t_next = cmds[k + 1][0] if k + 1 < len(cmds) else end
        if not moving or t_next - t <= grace_ns:
            continue
        silences += 1
        # the speed it held: the base may still be reaching the last command's speed
        held = [o for o in odom if t - 2e8 <= o[0] <= t + grace_ns]
        v0 = max((o[1] for o in held), default=robot.max_linear_mps)
        w0 = max((o[2] for o in held), default=robot.max_angular_radps)
        after = [o for o in odom if t < o[0] < t_next]
        still = next((u for u, v, w in after if max(v, w) < STILL), None)
        worst_stop = max(worst_stop, ((still or t_next) - t) / 1e9)
        for u, v, w in after:
            if u < t + grace_ns:
                continue
            if still is not None and u > still:
                # it stood: the base kept its timeout. Moving again means a new command,
                # a restarted sender's, which the bag may miss: each subscriber discovers
                # the new publisher in its own time (seen: the base drove 2 s on a
                # restarted gate's commands before the bag had matched it)
                break
            since = (u - t - grace_ns) / 1e9
            v_max = max(STILL, v0 - robot.max_linear_accel_mps2 * since)
            w_max = max(STILL, w0 - robot.max_angular_accel_radps2 * since)
            excess = max(excess, v - v_max, w - w_max)
    return {
        "silences": silences,
        "excess": round(excess, 3),
        "worst_stop_s": round(worst_stop, 3),
        "cmds": len(cmds),
        "odom": len(odom),
    }


def check_run(run_dir: Path) -> dict:
    """What the chaos test asserts, read from the run folder (raises on an unreadable
    file): the steps, the bags' base holds (:func:`base_holds`), run.json's ending."""
    from rosbags.rosbag2 import Reader

    steps = [json.loads(x) for x in (run_dir / "steps.jsonl").read_text().splitlines()]
    bags = {}
    for bag in _bags(run_dir):
        with Reader(bag) as reader:
            n = sum(1 for _ in reader.messages())
        bags[bag.name] = {"messages": n, **base_holds(bag)}
    record = json.loads((run_dir / "run.json").read_text())
    return {"steps": len(steps), "bags": bags, "run": record}


def chaos_files(
    folder: Path, steps: int, scenario: Path | None = None, realtime: bool = False
) -> tuple[Path, Path]:
    """A scenario (5.1.1 by default: the robot drives east from step 3) cut to ``steps``
    steps, and the twin deployment with restarts to spare (``max_restarts`` 100) and a
    1 s lock-step stall timeout: a dead participant is excused after 1 s of wall time
    (not 30), so the twin runs on while a killed node restarts (3 s later) and only the
    base's own timeout can stop it; with 30 s the twin waits for the restarted
    navigation and no simulated time passes without commands. ``realtime``: the twin at
    real time (no lock-step) with the velocity gate between navigation and the base
    (``twin.velocity_gate``)."""
    source = scenario or REPO / "scenarios" / "5.1.1.yaml"
    data = load_yaml(read_text_capped(source))
    task = (source.parent / data["task"]).resolve()
    data.update(name="chaos", steps=steps, task=str(task))
    write_text(folder / "chaos.yaml", dump_yaml(data))
    config = load_yaml(read_text_capped(REPO / "config" / "twin.yaml"))
    config["twin"].update(stall_timeout_s=1.0, stall_abort_s=120.0)
    if realtime:
        config["twin"].update(realtime=True, velocity_gate=True)
        config["lockstep"] = False
    config["twin"]["scene"] = str(REPO / "config" / "twin-scene.yaml")
    # a killed node comes back 3 s later (not as soon as Python starts, ~1 s on an idle
    # machine): the twin excuses it after 1 s and runs on for 2 s of wall time without
    # its commands, so the base's own timeout is what stops it, on any machine
    config["nodes"].update(max_restarts=100, restart_delay_s=3.0)
    # chaos kills node processes from outside: each node in a process of its own (one
    # process for the whole lock-step twin, nodes.processes: auto, has none to kill)
    config["nodes"]["processes"] = "separate"
    config["task"] = str(task)
    write_text(folder / "dep.yaml", dump_yaml(config))
    return folder / "chaos.yaml", folder / "dep.yaml"
