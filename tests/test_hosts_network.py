"""The networked system across three hosts (issue 25): the robot side (the twin's bridge
as the robot, with its localisation, leg tracker, navigation and speech), the camera
side (the people detector) and the planner side (observations, planner, recorder, bag)
each in a network namespace of its own, joined by veth links over a bridge in a fourth
namespace, each running ``vigil launch FILE --host NAME`` with its own copy of the
deployment (DDS on its own address only, the other two as peers), the twin on the wall
clock. The namespaces and links are made by the test, on this machine only.

Each host runs the same scenario (``vigil launch FILE --host NAME --scenario S``): the
robot side's twin walks its person, the planner side makes its steps, then ends
("finished") and writes the run's report; the other two stop on Ctrl-C. Two lengths: a
short scenario (5.1.1 cut to 6 steps) and a whole one of the guarding set
(``scenarios/guard/fast-walker.yaml``, its visit to cell 1).

Checked: the planner decided from observations that joined the camera side's frames
and the robot side's odometry, the person was seen, the robot side's twin kept the wall
clock, the camera's images crossed the robot's link, the report was written on the
planner side, and every host stopped cleanly. No delay or loss is added on the links:
this machine's kernel has no ``netem`` queueing discipline (the test says so when it
cannot add one).

Needs root and iproute2 (CI runs as root).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ros,
    pytest.mark.skipif(
        os.geteuid() != 0 or shutil.which("ip") is None, reason="needs root and iproute2"
    ),
]

HOSTS = {
    "robot": ["twin_bridge", "localisation", "legs", "navigation", "speech"],
    "camera": ["camera_people"],
    "planner": ["observations", "planner", "recorder", "bag", "markers"],
}
SHORT_STEPS = 6


def sh(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(args, check=check, capture_output=True, text=True, timeout=30)


@pytest.fixture
def lan():
    """Three namespaces (robot, camera, planner) on 10.<n>.0.1-3, bridged in a fourth."""
    tag = f"{os.getpid() % 100000}"
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


def scenario_file(tmp_path: Path, length: str) -> Path:
    """The short scenario (5.1.1 cut to SHORT_STEPS steps) or a whole guarding one."""
    if length == "whole":
        return REPO / "scenarios" / "guard" / "fast-walker.yaml"
    source = REPO / "scenarios" / "5.1.1.yaml"
    data = yaml.safe_load(source.read_text())
    data.update(steps=SHORT_STEPS, task=str((source.parent / data["task"]).resolve()))
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def deployment(tmp_path: Path, host: str, addresses: dict[str, str], domain: int) -> Path:
    """The host's own copy of the twin deployment: DDS on its address, the others peers."""
    from vigil.system import policy_for

    data = yaml.safe_load((CONFIG / "twin.yaml").read_text())
    task = CONFIG / "task-r1.yaml"
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
    data["twin"].update(scene=str(CONFIG / "twin-scene.yaml"), realtime=True)
    path = tmp_path / f"{host}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def link_bytes(ns: str) -> int:
    """Bytes received plus sent on the namespace's link."""
    stats = json.loads(sh("ip", "-n", ns, "-s", "-j", "link", "show", "eth0").stdout)[0]
    return int(stats["stats64"]["rx"]["bytes"]) + int(stats["stats64"]["tx"]["bytes"])


@pytest.mark.parametrize("length", ["short", "whole"])
def test_a_scenario_runs_across_three_hosts(lan, tmp_path, length):
    names, addresses = lan
    netem = sh("ip", "netns", "exec", names["robot"], "tc", "qdisc", "add", "dev", "eth0",
               "root", "netem", "delay", "5ms", check=False)  # fmt: skip
    if netem.returncode != 0:
        print(f"no delay or loss on the links: {netem.stderr.strip()}")
    scenario = scenario_file(tmp_path, length)
    steps_to_make = yaml.safe_load(scenario.read_text())["steps"]
    domain = 100 + os.getpid() % 100
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "FAST", "RMW_"))}
    env.update(PYTHONPATH=str(REPO), MUJOCO_GL="egl")
    procs: dict[str, subprocess.Popen] = {}
    logs: dict[str, Path] = {}
    try:
        for host in ("robot", "camera", "planner"):
            dep = deployment(tmp_path, host, addresses, domain)
            logs[host] = tmp_path / f"{host}.out"
            procs[host] = subprocess.Popen(
                ["ip", "netns", "exec", names[host], sys.executable, "-m", "vigil.cli",
                 "launch", str(dep), "--host", host, "--out", str(tmp_path / host),
                 "--scenario", str(scenario)],
                stdout=logs[host].open("w"), stderr=subprocess.STDOUT, env=env, cwd=REPO,
                start_new_session=True,
            )  # fmt: skip
        # the planner side ends by itself once its steps are made (at most 10 s a step)
        deadline = time.monotonic() + 60 + 10 * steps_to_make
        while procs["planner"].poll() is None and time.monotonic() < deadline:
            assert all(procs[h].poll() is None for h in ("robot", "camera")), {
                h: logs[h].read_text()[-2000:] for h in ("robot", "camera")
            }
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
    out = {h: logs[h].read_text() for h in logs}
    assert codes == dict.fromkeys(procs, 0), {h: out[h][-2000:] for h in out}
    for host, nodes in HOSTS.items():  # each host started its own nodes and no other
        started = {line.split()[2] for line in out[host].splitlines() if "] started " in line}
        assert started == set(nodes), (host, started)
    # the planner side decided from the camera side's frames and the robot's odometry
    run = json.loads((tmp_path / "planner" / "run.json").read_text())
    assert run["ending"] == "finished" and run["report"] == "written", run
    steps = [json.loads(line) for line in (tmp_path / "planner" / "steps.jsonl").open()]
    assert len(steps) == steps_to_make, out["planner"][-2000:]
    observed = [s["observation"] for s in steps if s.get("observation")]
    assert all(o["robot"].isdigit() for o in observed), observed
    assert sum("frame_stamp_s" in o for o in observed) >= len(observed) - 1
    assert any(o["person"].isdigit() for o in observed), observed  # the person was seen
    # the robot side's twin kept the wall clock; the images crossed its link
    realtime = json.loads((tmp_path / "robot" / "realtime.json").read_text())
    # (how many of the frames due were delivered depends on the machine's load: a
    # benchmark's figure, docs/BENCHMARKS.md; here only that they flowed)
    assert realtime["factor"] > 0.95 and realtime["frames"] >= 50, realtime
    assert moved > 20e6, moved  # 10 frames of 768 kB a second, and the rest
    summary = json.loads((tmp_path / "planner" / "summary.json").read_text())
    metrics = summary["metrics"]
    if length == "whole":  # its visit to cell 1, seen from the planner side's records
        assert metrics["n_visits"] == 1, metrics
    print(f"{len(steps)} steps, person seen in {sum(o['person'].isdigit() for o in observed)}, "
          f"visits guarded {metrics['guarded']}/{metrics['n_visits']}, "
          f"robot link {moved / 1e6:.0f} MB, twin factor {realtime['factor']}, "
          f"frames {realtime['frames']}/{realtime['frames_due']}")  # fmt: skip
