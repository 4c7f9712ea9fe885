"""``vigil arm``, ``vigil disarm`` and ``vigil status`` (issue 25): the operator's commands
against the real velocity gate node over DDS, as an engineer runs them (one process per
command, the deployment's domain and DDS profile), and what they make of what they hear."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from vigil.cli import main
from vigil.operator_report import (
    Heard,
    arm_refusals,
    heartbeat_hz,
    status_exit_code,
    status_lines,
    status_record,
)

REPO = Path(__file__).resolve().parents[1]
CAPS = {
    "max_linear_mps": 0.3,
    "max_angular_radps": 0.6,
    "cmd_timeout_s": 0.5,
    "max_linear_accel_mps2": 0.5,
    "max_angular_accel_radps2": 1.5,
}

try:
    import rclpy  # noqa: F401
    from geometry_msgs.msg import Twist
    from rcl_interfaces.srv import GetParameters
    from rclpy.node import Node
    from rclpy.parameter import parameter_value_to_python
    from rostest import spin_until

    HAVE_ROS = True
except ImportError:  # pragma: no cover
    HAVE_ROS = False
    Node = object  # type: ignore[assignment,misc]

needs_ros = pytest.mark.skipif(not HAVE_ROS, reason="rclpy not installed")
# a ROS domain of the module's own (conftest.private_ros_domain): the deployment names it
pytestmark = pytest.mark.usefixtures("private_ros_domain")


def deployment(folder: Path, domain: int, **gate) -> Path:
    """A hardware deployment on ``domain`` (localhost), the shipped gate caps + ``gate``."""
    data = yaml.safe_load((REPO / "config" / "hardware.yaml").read_text())
    (folder / "cal.yaml").write_text("unused: true\n")
    data.update(
        task=str(REPO / "config" / "task-r2.yaml"),
        perception={"calibration": "cal.yaml"},
        ros={"domain_id": domain, "localhost_only": True},
    )
    data["hardware"]["velocity_gate"].update(gate)
    path = folder / f"deployment-{len(list(folder.glob('deployment-*')))}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def vigil(*argv: str, timeout: float = 120) -> tuple[int, str, str, float]:
    """``vigil ARGV`` as its own process, as typed: (exit code, stdout, stderr, seconds)."""
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "vigil.cli", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )
    return proc.returncode, proc.stdout, proc.stderr, time.monotonic() - t0


def start_node(module: str, domain: int, folder: Path, *params: str) -> subprocess.Popen:
    """A node as ``vigil launch`` starts it: the deployment's domain and DDS profile
    (vigil/system.py), ``params`` as ``name:=value``."""
    from vigil.dds import dds_env, write_profile

    env = {**os.environ, **dds_env(write_profile(folder, ()), True)}
    env.update(ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED="1")
    args = [a for p in params for a in ("-p", p)]
    return subprocess.Popen(
        [sys.executable, "-m", module, "--ros-args", *args],
        env=env, cwd=REPO, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def stop(proc: subprocess.Popen) -> str:
    """SIGTERM, then the node's log."""
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.communicate()[1]


class Probe(Node if HAVE_ROS else object):  # type: ignore[misc]
    """The test's own view of the gate: its parameter, and whether a command of
    navigation's reaches the base."""

    def __init__(self):
        super().__init__("operator_probe")
        self.out: list[tuple[float, float, float]] = []
        self.create_subscription(Twist, "/cmd_vel", self.on_cmd, 50)
        self.nav = self.create_publisher(Twist, "/nav/cmd_vel", 10)
        self.params = self.create_client(GetParameters, "velocity_gate/get_parameters")

    def on_cmd(self, msg):
        self.out.append((msg.linear.x, msg.linear.y, msg.angular.z))

    def armed(self, ros) -> bool | None:
        if not spin_until(ros, self.params.service_is_ready, 10.0):
            return None
        future = self.params.call_async(GetParameters.Request(names=["armed"]))
        if not spin_until(ros, future.done, 10.0):
            return None
        return parameter_value_to_python(future.result().values[0])

    def drives(self, ros, vx: float = 0.1, seconds: float = 3.0) -> bool:
        """Does a command of ``vx`` reach the base (within ``seconds``)?"""
        msg = Twist()
        msg.linear.x = vx
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.nav.publish(msg)
            if spin_until(ros, lambda: bool(self.out) and self.out[-1][0] > 0.0, 0.05):
                return True
        return False


@needs_ros
@pytest.mark.ros
@pytest.mark.slow
def test_status_arm_and_disarm_the_real_gate(ros, tmp_path, private_ros_domain):
    domain = private_ros_domain
    config = deployment(tmp_path, domain)
    gate = start_node("stack.hardware.node_velocity_gate", domain, tmp_path,
                      f"config_file:={config}")  # fmt: skip
    camera = start_node("stack.hardware.node_camera_stream", domain, tmp_path,
                        f"url:={tmp_path / 'gone.avi'}", "reconnect_s:=0.5")  # fmt: skip
    probe = Probe()
    ros.add_node(probe)
    try:
        # disarmed: the gate is WARN "not armed", the camera ERROR: not OK (exit 1)
        code, out, err, _ = vigil("status", str(config), "--wait", "4")
        assert code == 1, out + err
        lines = {line.split()[0]: line for line in out.splitlines()}
        assert "WARN    disarmed: not armed" in lines["velocity_gate"], out
        assert "caps 0.3 m/s, 0.6 rad/s, command timeout 0.5 s" in lines["velocity_gate"]
        assert re.search(r"heartbeat (1\d|2\d)\.\d Hz", lines["velocity_gate"]), out  # ~20
        assert "publishers: /velocity_gate" in lines["base"], out
        assert "ERROR   cannot open" in lines["camera_stream"], out

        # a component at ERROR: not armed (exit 5), the reason named
        code, out, err, _ = vigil("arm", str(config), "--wait", "4")
        assert code == 5, out + err
        assert "not arming: camera_stream ERROR (cannot open" in err, err
        assert "the gate says: disarmed, not armed" in err, err
        stop(camera)
        # a deployment whose caps are lower than the running gate's: not armed either
        stricter = deployment(tmp_path, domain, max_linear_mps=0.2)
        code, out, err, _ = vigil("arm", str(stricter))
        assert code == 5, out + err
        assert "the gate's max_linear_mps 0.3 exceeds the deployment's 0.2" in err, err
        assert probe.armed(ros) is False

        code, out, err, seconds = vigil("arm", str(config))
        assert code == 0, out + err
        assert out.startswith("velocity gate armed: caps 0.3 m/s, 0.6 rad/s"), out
        assert f"ROS domain {domain}" in out and len(out.splitlines()) == 1
        assert probe.armed(ros) is True  # the parameter, read by another participant
        assert probe.drives(ros), "armed, but a navigation command did not reach the base"
        assert max(abs(v) for v in probe.out[-1]) <= 0.3 + 1e-9

        code, out, err, _ = vigil("status", str(config), "--json")
        record = json.loads(out)
        assert code == 1, out + err  # armed, navigation idle: the gate's WARN "stale"
        assert record["gate"]["armed"] is True and record["gate"]["armed_parameter"] is True
        assert record["gate"]["reason"] == "stale" and record["gate"]["level"] == "WARN"
        assert record["gate"]["caps"]["max_linear_mps"] == 0.3
        assert 10.0 < record["gate"]["heartbeat_hz"] < 30.0
        assert record["domain_id"] == domain

        code, out, err, _ = vigil("disarm", str(config))
        assert code == 0, out + err
        assert out.startswith("velocity gate disarmed: zero velocity"), out
        assert probe.armed(ros) is False
        probe.out.clear()
        assert not probe.drives(ros, seconds=1.0), "disarmed, but a command reached the base"
        assert probe.out and all(o == (0.0, 0.0, 0.0) for o in probe.out)
    finally:
        ros.remove_node(probe)
        probe.destroy_node()
        stop(camera)
        log = stop(gate)
    assert "ARMED: forwarding velocity commands" in log and "disarmed: zero velocity" in log
    assert log.count("ARMED") == 1, log  # the refused arms did not arm


@needs_ros
@pytest.mark.ros
def test_without_a_gate_arm_and_disarm_fail_within_their_timeout_naming_it(
    tmp_path, private_ros_domain
):
    config = deployment(tmp_path, private_ros_domain)
    code, out, err, seconds = vigil("arm", str(config), "--timeout", "2")
    assert code == 3, out + err
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert "vigil arm: error: no velocity gate answered within 2 s" in err
    assert "/velocity_gate/set_parameters" in err and f"ROS domain {private_ros_domain}" in err
    assert 2.0 <= seconds < 2.0 + 20.0  # the timeout, plus start-up on a loaded machine
    code, out, err, seconds = vigil("disarm", str(config), "--timeout", "2")
    assert code == 3, out + err
    assert len(err.strip().splitlines()) == 1 and "may still be ARMED" in err, err
    assert 2.0 <= seconds < 2.0 + 20.0


def test_the_commands_refuse_a_twin_deployment_and_a_bad_timeout(capsys):
    assert main(["arm", str(REPO / "config" / "twin.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vigil arm: error: mode: 'twin'") and "no velocity gate" in err
    assert len(err.strip().splitlines()) == 1
    assert main(["status", str(REPO / "config" / "hardware.yaml"), "--wait", "nan"]) == 2
    assert "--wait" in capsys.readouterr().err


# -- what is made of what was heard (no ROS) -----------------------------------------------
def heard(**kw) -> Heard:
    h = Heard(domain_id=42, base_topic="/cmd_vel", nav_topic="/nav/cmd_vel", window_s=2.0)
    h.now = 10.0
    for k, v in kw.items():
        setattr(h, k, v)
    return h


def gate_status(armed=False, reason="not armed", level=1, **caps):
    return {"level": level, "message": reason, "armed": armed, "reason": reason,
            "max_linear_mps": 0.3, "max_angular_radps": 0.6, **caps}  # fmt: skip


def healthy(**kw) -> Heard:
    given = {
        "statuses": {"velocity_gate": gate_status(True, "ok", 0)},
        "status_at": {"velocity_gate": 9.8},
        "beats": [(8.0 + i * 0.05, 100 + i) for i in range(40)],
        "base_publishers": ["/velocity_gate"],
    }
    return heard(**(given | kw))


def test_arm_checks_refuse_what_an_engineer_would_not_arm_into():
    ok = healthy(gate_reasons=["not armed"])
    assert arm_refusals(ok, CAPS) == []
    stale = healthy(gate_reasons=["stale"])  # an armed gate, navigation idle: normal
    assert arm_refusals(stale, CAPS) == []
    bad = healthy(gate_reasons=["not armed", "non-finite command", "not armed"])
    assert arm_refusals(bad, CAPS) == [
        "the gate saw a non-finite command from navigation (NaN or inf)"
    ]
    loose = healthy(params={"cmd_timeout_s": 1.0, "max_linear_mps": 0.3})
    assert arm_refusals(loose, CAPS) == ["the gate's cmd_timeout_s 1 exceeds the deployment's 0.5"]
    blind = healthy()
    blind.statuses["camera_stream"] = {"level": 2, "message": "cannot open rtsp://cam"}
    blind.status_at["camera_stream"] = 9.5
    assert arm_refusals(blind, CAPS) == ["camera_stream ERROR (cannot open rtsp://cam)"]
    bypass = healthy(base_publishers=["/velocity_gate", "/teleop"])
    assert "/teleop also publishes /cmd_vel (a path around the gate)" in arm_refusals(bypass, CAPS)
    silent = heard()
    assert "published no state" in arm_refusals(silent, CAPS)[0]


def test_status_is_ok_only_when_everything_heard_is_ok():
    ok = healthy()
    record = status_record(ok)
    assert record["ok"] and status_exit_code(record) == 0, record["problems"]
    assert record["gate"]["heartbeat_hz"] == 20.0
    assert status_lines(record)[-1] == "OK"
    disarmed = healthy()
    disarmed.statuses["velocity_gate"] = gate_status()
    record = status_record(disarmed)
    assert status_exit_code(record) == 1
    assert record["problems"] == ["velocity_gate WARN (not armed)"]
    absent = heard()
    record = status_record(absent)
    assert status_exit_code(record) == 1 and not record["gate"]["present"]
    assert "ABSENT" in "\n".join(status_lines(record))
    dead = healthy(beats=[])
    assert "no heartbeat" in " ".join(status_record(dead)["problems"])
    slow = healthy(beats=[(8.0 + i * 0.5, i) for i in range(4)], params={"rate_hz": 20.0})
    assert "heartbeat is slow: 2.0 Hz of 20 Hz" in " ".join(status_record(slow)["problems"])


def test_heartbeat_rate_counts_beats_not_messages_and_survives_a_restart():
    assert heartbeat_hz([]) is None and heartbeat_hz([(0.0, 5)]) is None
    lossy = [(0.0, 0), (0.5, 10), (1.0, 20)]  # 18 of 20 messages lost
    assert heartbeat_hz(lossy) == 20.0
    restarted = [(0.0, 500), (0.1, 502), (0.2, 1), (0.7, 11)]
    assert heartbeat_hz(restarted) == pytest.approx(20.0)
