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


def test_status_lists_the_robot_inputs_and_names_the_missing_ones():
    from vigil.operator_report import Input

    robot = {
        "/scan": Input("scan", "/scan", "the lidar driver", times=[9.0, 9.1, 9.2, 9.3]),
        "/odom": Input("odom", "/odom", "the base driver", publishers=["/mbot"]),
        "/map": Input("map", "/map", "a map server", False, publishers=["/map_server"]),
        "map -> odom": Input("map_odom", "/tf", "the localisation", times=[9.5]),
        "/amcl_pose": Input("pose", "/amcl_pose", "AMCL", False, publishers=[]),
    }
    record = status_record(healthy(robot=robot))
    assert record["problems"] == ["/odom MISSING (the base driver)", "/amcl_pose MISSING (AMCL)"]
    assert status_exit_code(record) == 1
    r = record["robot"]
    assert r["/scan"] == {"topic": "/scan", "from": "the lidar driver", "heard": 4,
                          "age_s": 0.7, "hz": 10.0, "ok": True}  # fmt: skip
    assert r["/map"]["ok"] and r["/map"]["heard"] == 0  # latched: a publisher suffices
    lines = {line.split("  ")[0]: line for line in status_lines(record)}
    assert lines["/scan"].split() == ["/scan", "OK", "10", "Hz,", "last", "0.7", "s", "ago"]
    assert "MISSING nothing heard; publishers: /mbot (the base driver)" in lines["/odom"]
    assert "OK      1 heard, last 0.5 s ago" in lines["map -> odom"]
    assert "MISSING nothing heard; publishers: none (AMCL)" in lines["/amcl_pose"]
    # a gate-only window (arm, disarm, the older callers) lists no robot inputs
    assert "robot" not in status_record(healthy())


class FakeRobot(Node if HAVE_ROS else object):  # type: ignore[misc]
    """The robot side on the loopback: the lidar, the base's odometry, a latched map and
    the localisation's map -> odom at 10 Hz; no AMCL pose."""

    def __init__(self, quiet_s: float = 0.0):
        from geometry_msgs.msg import TransformStamped
        from nav_msgs.msg import OccupancyGrid, Odometry
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import LaserScan
        from tf2_msgs.msg import TFMessage

        super().__init__("fake_robot")
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)  # fmt: skip
        grid = OccupancyGrid()
        grid.header.frame_id, grid.info.width, grid.info.height = "map", 4, 4
        grid.data = [0] * 16
        self.map_pub = self.create_publisher(OccupancyGrid, "/map", latched)
        self.map_pub.publish(grid)  # once, before anyone listens: latched
        scan, odom = LaserScan(), Odometry()
        move = TransformStamped()
        move.header.frame_id, move.child_frame_id = "map", "odom"
        move.transform.rotation.w = 1.0
        other = TransformStamped()  # not the localisation's: ignored
        other.header.frame_id, other.child_frame_id = "odom", "base_link"
        tf = self.create_publisher(TFMessage, "/tf", 100)
        pubs = [
            (self.create_publisher(LaserScan, "/scan", 10), scan),
            (self.create_publisher(Odometry, "/odom", 10), odom),
            (tf, TFMessage(transforms=[move])),
            (tf, TFMessage(transforms=[other])),
        ]
        start = time.monotonic()

        def beat():  # silent for quiet_s: its publishers are known before its messages
            if time.monotonic() - start >= quiet_s:
                for pub, msg in pubs:
                    pub.publish(msg)

        self.create_timer(0.1, beat)


def status_with_robot(ros, config: Path, quiet_s: float, **kw) -> tuple[int, dict]:
    """``vigil status`` (in-process) while a :class:`FakeRobot` spins in a thread."""
    import threading

    from vigil.deployment import load_deployment
    from vigil.operator import status

    robot = FakeRobot(quiet_s)
    ros.add_node(robot)
    done = threading.Event()

    def spin():
        while not done.is_set():
            ros.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    said: list[str] = []
    try:
        code = status(load_deployment(config), as_json=True, say=said.append, **kw)
    finally:
        done.set()
        spinner.join(timeout=10)
        ros.remove_node(robot)
        robot.destroy_node()
    return code, json.loads(said[0])


@needs_ros
@pytest.mark.ros
def test_status_hears_the_robot_side_and_names_what_is_missing(ros, tmp_path, private_ros_domain):
    """``vigil status`` reports the robot side the stack reads (docs/HARDWARE.md, "start the
    robot's drivers"): without the ``ros2`` command line it is the engineer's only view."""
    config = deployment(tmp_path, private_ros_domain)
    code, record = status_with_robot(ros, config, 0.0, wait_s=3.0, timeout_s=1.0)
    assert code == 1  # no gate, no AMCL pose
    r = record["robot"]
    assert r["/scan"]["ok"] and r["/scan"]["heard"] >= 5, r
    assert r["/scan"]["publishers"] == ["/fake_robot"]
    assert r["/odom"]["ok"] and r["map -> odom"]["ok"], r
    assert r["/map"]["ok"] and r["/map"]["heard"] == 1, r  # the latched map, sent before
    assert r["map -> odom"]["heard"] <= r["/scan"]["heard"] + 2  # odom -> base_link not counted
    assert not r["/amcl_pose"]["ok"] and r["/amcl_pose"]["publishers"] == []
    assert "/amcl_pose MISSING (AMCL, for navigation.pose_source: amcl)" in record["problems"]


@needs_ros
@pytest.mark.ros
def test_status_waits_for_a_stream_whose_publisher_it_found(ros, tmp_path, private_ros_domain):
    """A driver discovered late, or whose first message comes after the listen window
    (seen on the loopback rehearsal: ``/scan MISSING nothing heard; publishers:
    /fake_robot``): ``vigil status`` waits, within ``--timeout``, for the first message
    of every stream that has a publisher, instead of calling it missing."""
    config = deployment(tmp_path, private_ros_domain)
    code, record = status_with_robot(ros, config, 3.5, wait_s=0.5, timeout_s=2.0)
    r = record["robot"]
    assert r["/scan"]["publishers"] == ["/fake_robot"]
    assert r["/scan"]["ok"] and r["/odom"]["ok"] and r["map -> odom"]["ok"], record["problems"]


@needs_ros
@pytest.mark.ros
def test_arm_waits_for_the_camera_status_discovered_after_the_gate(
    ros, tmp_path, private_ros_domain
):
    """``vigil arm`` checks every status it heard; the camera's participant can be
    discovered seconds after the gate's (here, once in three arms on the loopback
    deployment, its ERROR was not heard within ``--wait`` 1.5 s and the gate armed into
    a camera that could not stream). It waits, within ``--timeout``, for the camera's
    status too, and refuses its ERROR."""
    import threading

    from rclpy.parameter import Parameter

    from stack.hardware.node_camera_stream import CameraStreamNode
    from stack.hardware.node_velocity_gate import VelocityGateNode
    from vigil.deployment import load_deployment
    from vigil.operator import EXIT_CHECKS, OperatorError, arm

    config = deployment(tmp_path, private_ros_domain)
    gate = VelocityGateNode(parameter_overrides=[Parameter("config_file", value=str(config))])
    ros.add_node(gate)
    nodes = [gate]
    done = threading.Event()

    def spin():
        started = time.monotonic()
        while not done.is_set():
            if len(nodes) == 1 and time.monotonic() - started > 2.0:  # the camera, late
                cam = CameraStreamNode(parameter_overrides=[
                    Parameter("url", value=str(tmp_path / "gone.avi")),
                    Parameter("reconnect_s", value=0.5)])  # fmt: skip
                nodes.append(cam)
                ros.add_node(cam)
            ros.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    notes: list[str] = []
    try:
        with pytest.raises(OperatorError) as refused:
            arm(load_deployment(config), timeout_s=8.0, wait_s=0.3, say=notes.append,
                warn=notes.append)  # fmt: skip
        assert gate.get_parameter("armed").value is False
    finally:
        done.set()
        spinner.join(timeout=10)
        for node in nodes:
            ros.remove_node(node)
            node.destroy_node()
    assert refused.value.code == EXIT_CHECKS
    assert "not arming: camera_stream ERROR (cannot open" in str(refused.value), notes


def test_arm_notes_a_camera_it_never_heard():
    from vigil.operator_report import arm_notes

    assert any("camera_stream: no status heard" in n for n in arm_notes(healthy()))
    seen = healthy()
    seen.statuses["camera_stream"] = {"level": 0, "message": "streaming"}
    assert arm_notes(seen) == []
