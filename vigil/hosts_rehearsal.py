"""The twin over three hosts on this machine: network namespaces joined by virtual links.

A rehearsal of the networked system (issue 25) without three computers: the robot side
(the twin's bridge as the robot, with its localisation, leg tracker, navigation and
speech), the camera side (the people detector) and the planner side (observations,
planner, recorder, bag) each in a network namespace of its own, joined by veth links
over a bridge in a fourth namespace, each running ``vigil launch FILE --host NAME
--scenario S`` with its own copy of the deployment (DDS on its own address only, the
other two as peers), the twin on the wall clock.

:func:`virtual_lan` makes (and always removes) the namespaces; :func:`run_across_hosts`
runs one scenario across them and gathers the planner side's report, with the robot
side's speech log copied beside it so the warnings count. Needs root and iproute2; used
by ``tests/test_hosts_network.py`` and ``bench/bench_hosts.py``. No rclpy here.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from vigil.launch_command import count_lines

REPO = Path(__file__).resolve().parents[1]
HOSTS = {
    "robot": ["twin_bridge", "localisation", "legs", "navigation", "speech"],
    "camera": ["camera_people"],
    "planner": ["observations", "planner", "recorder", "bag", "markers"],
}
STEP_BOUND_S = 10.0  # the planner side ends within 60 s + this per step, or is stopped


def sh(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(args, check=check, capture_output=True, text=True, timeout=30)


def can_run() -> bool:
    """Root and iproute2: what making namespaces needs."""
    return os.geteuid() == 0 and shutil.which("ip") is not None


@contextmanager
def virtual_lan(tag: str | None = None) -> Iterator[tuple[dict[str, str], dict[str, str]]]:
    """Three namespaces (robot, camera, planner) on 10.<n>.0.1-3, bridged in a fourth;
    yields (host -> namespace, host -> address). Removed on the way out, however."""
    tag = tag or f"{os.getpid() % 100000}"
    n = os.getpid() % 200 + 20
    names = {h: f"vgl{h[0]}{tag}" for h in HOSTS}
    hub = f"vglh{tag}"
    made: list[str] = []
    try:
        for ns in (hub, *names.values()):
            sh("ip", "netns", "add", ns)
            made.append(ns)
            sh("ip", "-n", ns, "link", "set", "lo", "up")
        sh("ip", "-n", hub, "link", "add", "br0", "type", "bridge")
        sh("ip", "-n", hub, "link", "set", "br0", "up")
        addresses = {}
        for k, (host, ns) in enumerate(names.items(), start=1):
            inner, outer = "eth0", f"p{host[0]}"
            sh("ip", "link", "add", f"x{host[0]}{tag}", "type", "veth", "peer", "name",
               f"y{host[0]}{tag}")  # fmt: skip
            sh("ip", "link", "set", f"x{host[0]}{tag}", "netns", ns)
            sh("ip", "-n", ns, "link", "set", f"x{host[0]}{tag}", "name", inner)
            sh("ip", "link", "set", f"y{host[0]}{tag}", "netns", hub)
            sh("ip", "-n", hub, "link", "set", f"y{host[0]}{tag}", "name", outer)
            sh("ip", "-n", hub, "link", "set", outer, "master", "br0")
            sh("ip", "-n", hub, "link", "set", outer, "up")
            addresses[host] = f"10.{n}.0.{k}"
            sh("ip", "-n", ns, "addr", "add", f"{addresses[host]}/24", "dev", inner)
            sh("ip", "-n", ns, "link", "set", inner, "up")
            sh("ip", "-n", ns, "route", "add", "224.0.0.0/4", "dev", inner)
        yield names, addresses
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def add_delay(namespace: str, delay_ms: float) -> str | None:
    """``netem`` delay on the namespace's link; None if added, else why not (this
    machine's kernel has no ``netem``)."""
    proc = sh("ip", "netns", "exec", namespace, "tc", "qdisc", "add", "dev", "eth0", "root",
              "netem", "delay", f"{delay_ms:g}ms", check=False)  # fmt: skip
    return None if proc.returncode == 0 else proc.stderr.strip() or "tc failed"


def host_deployment(
    folder: Path, host: str, addresses: dict[str, str], domain: int, task: Path
) -> Path:
    """The host's own copy of the twin deployment: DDS on its address, the others peers."""
    from vigil.system import policy_for

    data = yaml.safe_load((REPO / "config" / "twin.yaml").read_text())
    data.update(
        task=str(task),
        policy=str(policy_for(task, say=lambda s: None)),  # solved once, before the hosts
        lockstep=False,
        hosts=HOSTS,
        ros={
            "domain_id": domain,
            "localhost_only": False,
            "interfaces": [addresses[host]],
            "peers": [a for h, a in addresses.items() if h != host],
        },
    )
    data["twin"].update(scene=str(REPO / "config" / "twin-scene.yaml"), realtime=True)
    path = folder / f"{host}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def link_bytes(namespace: str) -> int:
    """Bytes received plus sent on the namespace's link."""
    stats = json.loads(sh("ip", "-n", namespace, "-s", "-j", "link", "show", "eth0").stdout)[0]
    return int(stats["stats64"]["rx"]["bytes"]) + int(stats["stats64"]["tx"]["bytes"])


@dataclass
class HostsRun:
    """One scenario across the three hosts: each host's exit code and output, the bytes
    over the robot's link, and the planner side's folder (its report included)."""

    folder: Path
    codes: dict[str, int]
    out: dict[str, str]
    robot_link_bytes: int
    steps: int
    summary: dict = field(default_factory=dict)
    realtime: dict = field(default_factory=dict)


def run_across_hosts(
    scenario: Path, folder: Path, names: dict[str, str], addresses: dict[str, str],
    domain: int,
) -> HostsRun:  # fmt: skip
    """``vigil launch HOST.yaml --host HOST --scenario S`` on each host; the planner side
    ends by itself once its steps are made (or is stopped after its bound), then the
    others are stopped with Ctrl-C. The robot's speech log is copied into the planner
    side's folder and the report written again there, so it counts the warnings."""
    folder.mkdir(parents=True, exist_ok=True)
    data = yaml.safe_load(scenario.read_text())
    task = (scenario.parent / data["task"]).resolve()
    steps_to_make = int(data["steps"])
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "FAST", "RMW_"))}
    env.update(PYTHONPATH=str(REPO), MUJOCO_GL="egl")
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    moved = 0
    try:
        for host in ("robot", "camera", "planner"):
            dep = host_deployment(folder, host, addresses, domain, task)
            logs[host] = folder / f"{host}.out"
            procs[host] = subprocess.Popen(
                ["ip", "netns", "exec", names[host], sys.executable, "-m", "vigil.cli",
                 "launch", str(dep), "--host", host, "--out", str(folder / host),
                 "--scenario", str(scenario)],
                stdout=logs[host].open("w"), stderr=subprocess.STDOUT, env=env, cwd=REPO,
                start_new_session=True,
            )  # fmt: skip
        deadline = time.monotonic() + 60 + STEP_BOUND_S * steps_to_make
        while procs["planner"].poll() is None and time.monotonic() < deadline:
            if any(procs[h].poll() is not None for h in ("robot", "camera")):
                break
            time.sleep(1.0)
        moved = link_bytes(names["robot"])
    finally:
        for p in procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        codes = {}
        for h, p in procs.items():
            try:
                codes[h] = p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                codes[h] = p.wait()
    planner = folder / "planner"
    steps = count_lines(planner / "steps.jsonl")
    run = HostsRun(folder, codes, {h: logs[h].read_text() for h in logs}, moved, steps)
    speech = folder / "robot" / "speech" / "speech_log.tsv"
    if speech.exists() and (planner / "summary.json").exists():
        shutil.copyfile(speech, planner / "speech" / "speech_log.tsv")
        from vigil.report import write_report

        write_report(planner, task, None, say=lambda s: None)
    if (planner / "summary.json").exists():
        run.summary = json.loads((planner / "summary.json").read_text())
    realtime = folder / "robot" / "realtime.json"
    if realtime.exists():
        run.realtime = json.loads(realtime.read_text())
    return run
