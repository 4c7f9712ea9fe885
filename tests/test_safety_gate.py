"""The velocity gate fails safe (issue 13): monotonic timing, a final zero on SIGINT and
SIGTERM, and in hardware mode the gate is the only way to the base."""

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from stack.cells import ConfigError
from vigil.deployment import parse_deployment

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"

try:
    import rclpy  # noqa: F401
    from geometry_msgs.msg import Twist
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rostest import spin_until
    from std_msgs.msg import Bool

    HAVE_ROS = True
except ImportError:  # pragma: no cover
    HAVE_ROS = False

needs_ros = pytest.mark.skipif(not HAVE_ROS, reason="rclpy not installed")


# a ROS domain of its own (conftest.private_ros_domain)
pytestmark = pytest.mark.usefixtures("private_ros_domain")


def hardware_data(tmp_path, **changes):
    (tmp_path / "cal.yaml").write_text("unused: true\n")
    data = yaml.safe_load((CONFIG / "hardware.yaml").read_text())
    data.update(task=str(CONFIG / "task-r2.yaml"), perception={"calibration": "cal.yaml"})
    data.update(changes)
    return data


# -- the deployment ------------------------------------------------------------------------
def test_shipped_hardware_file_is_on_its_own_domain_and_restricted(tmp_path):
    dep = parse_deployment(hardware_data(tmp_path), tmp_path / "hardware.yaml")
    assert dep.ros.domain_id > 0
    assert dep.ros.localhost_only or dep.ros.interfaces


@pytest.mark.parametrize(
    "ros, topics, key",
    [
        ({"domain_id": -1}, {}, "ros.domain_id"),
        ({"domain_id": 0}, {}, "ros.domain_id"),
        ({"domain_id": 7, "localhost_only": False, "interfaces": []}, {}, "ros.interfaces"),
        ({"domain_id": 7, "interfaces": ["eth0; rm"]}, {}, "ros.interfaces"),
        ({"domain_id": 7}, {"cmd_vel": "/nav/cmd_vel"}, "topics.cmd_vel"),  # the bypass
        ({"domain_id": 7}, {"cmd_vel": "/arm"}, "topics.cmd_vel"),
        ({"domain_id": 7, "keystore": "no/such/keystore"}, {}, "ros.keystore"),
    ],
)
def test_hardware_deployment_refuses_unsafe_network_and_topic_settings(tmp_path, ros, topics, key):
    data = hardware_data(tmp_path, ros=ros, topics=topics)
    with pytest.raises(ConfigError) as err:
        parse_deployment(data, tmp_path / "hardware.yaml")
    assert err.value.key == key


def test_hardware_caps_are_bounded_by_the_platform(tmp_path):
    data = hardware_data(tmp_path)
    data["hardware"]["velocity_gate"]["max_linear_mps"] = 50.0
    with pytest.raises(ConfigError) as err:
        parse_deployment(data, tmp_path / "hardware.yaml")
    assert err.value.key == "hardware.velocity_gate.max_linear_mps" and "platform" in str(err.value)


def test_in_hardware_mode_only_the_gate_publishes_the_base_topic(tmp_path):
    from vigil.system import prepare

    (tmp_path / "policy.npz").write_bytes(b"")
    data = hardware_data(tmp_path, policy=str(tmp_path / "policy.npz"))
    data["topics"] = {"cmd_vel": "/base/cmd_vel"}
    dep = parse_deployment(data, tmp_path / "hardware.yaml")
    system = prepare(dep, tmp_path / "run", say=lambda s: None)
    users = {
        name
        for name, params in system.params.items()
        for value in params.values()
        if value == "/base/cmd_vel"
    }
    assert users == {"velocity_gate"}
    assert (
        system.params["velocity_gate"]["input_topic"]
        == system.params["navigation"]["cmd_vel_topic"]
    )


# -- the node ------------------------------------------------------------------------------
class Base(Node if HAVE_ROS else object):
    """The base driver's side: what reaches /cmd_vel, and a navigation stand-in."""

    def __init__(self):
        super().__init__("base_probe")
        self.out: list[tuple[tuple[float, float, float], float]] = []
        self.create_subscription(Twist, "/cmd_vel", self.on_cmd, 50)
        self.nav = self.create_publisher(Twist, "/nav/cmd_vel", 10)
        self.arm = self.create_publisher(Bool, "/arm", 10)

    def on_cmd(self, msg):
        self.out.append(((msg.linear.x, msg.linear.y, msg.angular.z), time.monotonic()))

    def send(self, vx):
        msg = Twist()
        msg.linear.x = vx
        self.nav.publish(msg)

    def last(self):
        return self.out[-1][0] if self.out else None


@needs_ros
@pytest.mark.ros
def test_gate_times_out_on_the_monotonic_clock_even_with_a_frozen_sim_clock(ros):
    from stack.hardware.node_velocity_gate import VelocityGateNode

    base = Base()
    gate = VelocityGateNode(
        parameter_overrides=[
            Parameter("use_sim_time", value=True),  # and nobody publishes /clock
            Parameter("require_arming", value=False),
            Parameter("cmd_timeout_s", value=0.3),
            Parameter("max_linear_accel_mps2", value=2.0),
        ]
    )
    for node in (base, gate):
        ros.add_node(node)
    try:
        spin_until(ros, lambda: False, 0.3)
        for _ in range(30):
            base.send(0.2)
            if spin_until(ros, lambda: base.last() == pytest.approx((0.2, 0.0, 0.0)), 0.05):
                break
        assert base.last() == pytest.approx((0.2, 0.0, 0.0))
        # commands stop; the ROS clock stands still at 0: only a monotonic timeout stops it
        assert spin_until(ros, lambda: base.last() == (0.0, 0.0, 0.0), 10.0), "no stale zero"
        assert gate.gate.state.reason == "stale"
    finally:
        for node in (base, gate):
            ros.remove_node(node)
            node.destroy_node()


@needs_ros
@pytest.mark.ros
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_gate_process_sends_a_final_zero_and_exits_cleanly_on_a_signal(ros, sig):
    base = Base()
    ros.add_node(base)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "stack.hardware.node_velocity_gate",
            "--ros-args",
            "-p",
            "require_arming:=false",
            "-p",
            "cmd_timeout_s:=1.0",
            "-p",
            "max_linear_accel_mps2:=2.0",
        ],
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        moving = lambda: base.last() is not None and base.last()[0] > 0.1  # noqa: E731
        for _ in range(200):
            base.send(0.2)
            if spin_until(ros, moving, 0.05):
                break
        assert moving(), "the gate never forwarded a command"
        proc.send_signal(sig)
        assert proc.wait(timeout=30) == 0
        spin_until(ros, lambda: False, 0.3)
        assert base.last() == (0.0, 0.0, 0.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        err = proc.communicate()[1]
        ros.remove_node(base)
        base.destroy_node()
    assert "context is invalid" not in err and "Traceback" not in err, err
    assert "shutting down: zero velocity" in err  # the exit's zero, not only a stale one


def test_gate_node_refuses_its_input_as_output():
    if not HAVE_ROS:
        pytest.skip("rclpy not installed")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "stack.hardware.node_velocity_gate",
            "--ros-args",
            "-p",
            "output_topic:=/nav/cmd_vel",
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 2
    assert "output_topic" in proc.stderr and "Traceback" not in proc.stderr


def test_accel_limit_never_exceeds_the_rate_over_a_random_command_stream():
    import random

    from stack.hardware.velocity_gate import GateConfig, VelocityGate

    cfg = GateConfig(max_linear_accel_mps2=0.5, max_angular_accel_radps2=1.5)
    gate = VelocityGate(cfg)
    gate.arm(True, 0.0)
    rng = random.Random(3)
    t, prev = 0.0, (0.0, 0.0, 0.0)
    for _ in range(2000):
        dt = rng.choice([0.01, 0.05, 0.05, 0.2])
        t += dt
        cmd = [rng.uniform(-2, 2) for _ in range(3)]
        out = gate.command(*cmd, t)
        grow = math.hypot(out[0], out[1]) - math.hypot(prev[0], prev[1])
        assert grow <= 0.5 * min(dt, 0.1) + 1e-9
        assert abs(out[2]) - abs(prev[2]) <= 1.5 * min(dt, 0.1) + 1e-9
        assert math.hypot(out[0], out[1]) <= cfg.max_linear_mps + 1e-9
        prev = out
