"""DDS isolation (issue 13): the twin's nodes cannot be reached from another host.

A second network namespace joined by a veth pair stands in for another host. An
intruder there names this host as its DDS peer and publishes ``/arm`` and
``/cmd_vel``. A listener with the launcher's environment (vigil/dds.py profile) hears
nothing; the same listener with only ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (the
old setting) hears it, which shows the test can fail; and a local publisher with the
profile still reaches it. Needs root and iproute2 (CI runs as root).
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from vigil.dds import dds_env, write_profile
from vigil.ros_domain import claim_domain

HERE = Path(__file__).resolve().parent / "safety_peers"
REPO = HERE.parents[1]

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ros,
    pytest.mark.skipif(
        os.geteuid() != 0 or shutil.which("ip") is None, reason="needs root and iproute2"
    ),
]


def sh(*args: str) -> None:
    subprocess.run(args, check=True, capture_output=True, timeout=30)


@pytest.fixture
def other_host():
    """A network namespace at 10.213.<n>.2 reaching this host at 10.213.<n>.1."""
    n = os.getpid() % 200 + 20
    ns, host_if, ns_if = f"vigil-t{os.getpid()}", f"vgh{os.getpid() % 100000}", "vga0"
    sh("ip", "netns", "add", ns)
    try:
        sh("ip", "link", "add", host_if, "type", "veth", "peer", "name", ns_if, "netns", ns)
        sh("ip", "addr", "add", f"10.213.{n}.1/24", "dev", host_if)
        sh("ip", "link", "set", host_if, "up")
        sh("ip", "netns", "exec", ns, "ip", "addr", "add", f"10.213.{n}.2/24", "dev", ns_if)
        sh("ip", "netns", "exec", ns, "ip", "link", "set", ns_if, "up")
        sh("ip", "netns", "exec", ns, "ip", "link", "set", "lo", "up")
        yield ns, f"10.213.{n}.1"
    finally:
        subprocess.run(["ip", "link", "del", host_if], capture_output=True)
        subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def base_env(domain: int) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("ROS_", "FASTRTPS_", "FASTDDS_", "RMW_"))
    }
    env.update(ROS_DOMAIN_ID=str(domain), PYTHONPATH=str(REPO))
    return env


def listen_while(listener_env, intruder_cmd, seconds=6.0, intruder_env=None) -> str:
    listener = subprocess.Popen(
        [sys.executable, str(HERE / "listen_arm.py"), str(seconds + 3)],
        env=listener_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert listener.stdout.readline().strip() == "READY"
        subprocess.run(intruder_cmd, capture_output=True, timeout=60, check=True, env=intruder_env)
        out, _ = listener.communicate(timeout=60)
    finally:
        if listener.poll() is None:
            listener.kill()
    return out.strip().splitlines()[-1]


def _intruder(ns: str, domain_id: int, host_ip: str) -> list[str]:
    """A publisher of ``/arm`` and the base topic in network namespace ``ns`` (another
    host) that knows the domain id and this host's address."""
    return [
        "ip", "netns", "exec", ns, "env", f"ROS_DOMAIN_ID={domain_id}",
        f"ROS_STATIC_PEERS={host_ip}", "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET",
        f"PYTHONPATH={REPO}", sys.executable, str(HERE / "publish_arm.py"), "6",
    ]  # fmt: skip


def test_a_peer_on_another_host_can_neither_arm_nor_drive(other_host, tmp_path):
    ns, host_ip = other_host
    claim = claim_domain()
    try:
        env = base_env(claim.domain_id)
        intruder = _intruder(ns, claim.domain_id, host_ip)
        # the old setting: discovery range LOCALHOST only: the intruder gets through
        old = {**env, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
        assert listen_while(old, intruder) != "RECEIVED arm=0 cmd_vel=0"
        # the launcher's environment: nothing arrives
        ours = {**env, **dds_env(write_profile(tmp_path), localhost_only=True)}
        assert listen_while(ours, intruder) == "RECEIVED arm=0 cmd_vel=0"
        # and the nodes of this host still talk to each other
        local = [sys.executable, str(HERE / "publish_arm.py"), "4"]
        result = listen_while(ours, local, seconds=4.0, intruder_env=ours)
        assert result != "RECEIVED arm=0 cmd_vel=0", result
    finally:
        claim.release()


def test_a_host_on_the_robot_network_is_heard_without_sros2(other_host, tmp_path):
    """The whitelist is no authentication (docs/SAFETY.md, "Threat model"): in hardware
    mode ``ros.interfaces`` lists this PC's address on the robot network, and a host on
    that network that knows the domain id reaches the nodes, ``/arm`` and the base topic
    alike. Only DDS Security (SROS2) would refuse it, which the middleware here lacks."""
    ns, host_ip = other_host
    claim = claim_domain()
    try:
        env = base_env(claim.domain_id)
        intruder = _intruder(ns, claim.domain_id, host_ip)
        robot = {**env, **dds_env(write_profile(tmp_path, [host_ip]), localhost_only=False)}
        line = listen_while(robot, intruder)
        arm, cmd = (int(part.split("=")[1]) for part in line.split()[1:])
        assert arm > 0 and cmd > 0, line
    finally:
        claim.release()


def test_every_node_the_launcher_starts_gets_the_profile(tmp_path):
    import yaml

    from vigil.deployment import parse_deployment
    from vigil.system import prepare

    (tmp_path / "policy.npz").write_bytes(b"")
    data = yaml.safe_load((REPO / "config" / "twin.yaml").read_text())
    data.update(task=str(REPO / "config" / "task-r1.yaml"), policy=str(tmp_path / "policy.npz"))
    data["twin"]["scene"] = str(REPO / "config" / "twin-scene.yaml")
    dep = parse_deployment(data, tmp_path / "twin.yaml")
    system = prepare(dep, tmp_path / "run", say=lambda s: None)
    profile = Path(system.env["FASTDDS_DEFAULT_PROFILES_FILE"])
    assert profile.parent == tmp_path / "run"
    assert system.env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(profile)
    assert "<useBuiltinTransports>false</useBuiltinTransports>" in profile.read_text()
    assert all(not spec.env.get("FASTDDS_DEFAULT_PROFILES_FILE") for spec in system.specs)
