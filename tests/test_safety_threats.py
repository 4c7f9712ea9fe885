"""The threat model of docs/SAFETY.md, as it stands without SROS2 (issue 23): what a
process on the robot's host that knows the ROS domain can do to the velocity gate,
and what vigil still guarantees.

The gate runs as ``vigil launch`` starts it (its own process, the deployment's domain
and DDS profile). The intruder is this test process: no vigil profile, no certificate
(DDS Security cannot be enforced with the middleware installed here, issue 13), only
the domain id. It finds the gate, and:

- cannot raise the gate's caps or its command timeout (read-only parameters);
- can publish the base topic itself, around the gate: ``vigil arm`` then refuses,
  naming it;
- can arm the gate through ``/arm`` (SROS2 would allow ``/arm`` to the operator's
  enclave only), but what it then asks, 5 m/s and 10 rad/s, reaches the base capped
  (0.3 m/s, 0.6 rad/s) and slewed (0.5 m/s², at most 0.05 m/s between outputs);
- floods the gate's input: the outputs stay capped, the gate lives and beats on;
- falls silent: the base gets a zero within the command timeout.
"""

from __future__ import annotations

import time

import pytest

try:
    from geometry_msgs.msg import Twist
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.node import Node
    from rclpy.parameter import parameter_value_to_python
    from rostest import spin_until
    from std_msgs.msg import Bool, UInt64

    HAVE_ROS = True
except ImportError:  # pragma: no cover
    HAVE_ROS = False
    Node = object  # type: ignore[assignment,misc]

pytestmark = [
    pytest.mark.skipif(not HAVE_ROS, reason="rclpy not installed"),
    pytest.mark.usefixtures("private_ros_domain"),
]

CAP_V, CAP_W, TIMEOUT_S, ACCEL = 0.3, 0.6, 0.5, 0.5  # config/hardware.yaml's gate
STEP = ACCEL * 0.1  # the most the speed may grow between two outputs (MAX_DT_S 0.1 s)


class Intruder(Node if HAVE_ROS else object):  # type: ignore[misc]
    """A participant of the domain with no vigil profile and no certificate."""

    def __init__(self):
        super().__init__("intruder")
        self.out: list[tuple[float, float, float]] = []  # (time, vx, wz) on the base topic
        self.beats: list[float] = []  # arrival times of the gate's heartbeat
        self.create_subscription(Twist, "/cmd_vel", self.on_cmd, 1000)
        self.create_subscription(UInt64, "/velocity_gate/heartbeat", self.on_beat, 100)
        self.nav = self.create_publisher(Twist, "/nav/cmd_vel", 10)
        self.arm = self.create_publisher(Bool, "/arm", 10)
        self.setp = self.create_client(SetParameters, "/velocity_gate/set_parameters")
        self.getp = self.create_client(GetParameters, "/velocity_gate/get_parameters")

    def on_cmd(self, msg: Twist) -> None:
        self.out.append((time.monotonic(), msg.linear.x, msg.angular.z))

    def on_beat(self, msg: UInt64) -> None:
        self.beats.append(time.monotonic())

    def call(self, ros, client, request):
        # a service ready for requests may not yet have matched this client's reply
        # reader (DDS discovers each side in its own time; seen in CI under load): the
        # reply is then lost, and a request sent again is answered
        for _ in range(3):
            future = client.call_async(request)
            if spin_until(ros, future.done, 10.0):
                return future.result()
            client.remove_pending_request(future)
        raise AssertionError("the gate's parameter service did not answer three requests")

    def set_double(self, ros, name: str, value: float):
        value_msg = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value_msg)])
        return self.call(ros, self.setp, request).results[0]

    def get(self, ros, *names: str) -> list:
        result = self.call(ros, self.getp, GetParameters.Request(names=list(names)))
        return [parameter_value_to_python(v) for v in result.values]

    def ask(self, vx: float, wz: float) -> None:
        msg = Twist()
        msg.linear.x, msg.angular.z = vx, wz
        self.nav.publish(msg)


@pytest.mark.ros
@pytest.mark.slow
def test_a_local_process_without_sros2_reaches_the_gate_but_not_past_its_caps(
    ros, tmp_path, private_ros_domain
):
    from test_operator import deployment, start_node, stop, vigil

    domain = private_ros_domain
    config = deployment(tmp_path, domain)
    gate = start_node("stack.hardware.node_velocity_gate", domain, tmp_path,
                      f"config_file:={config}")  # fmt: skip
    intruder = Intruder()
    ros.add_node(intruder)
    try:
        assert spin_until(ros, intruder.setp.service_is_ready, 20.0), "no gate found"
        # the caps and the timeout are read-only: refused over DDS, unchanged
        for name, value in (("max_linear_mps", 5.0), ("cmd_timeout_s", 3600.0)):
            result = intruder.set_double(ros, name, value)
            assert not result.successful and "read-only" in result.reason, (name, result.reason)
        assert intruder.get(ros, "max_linear_mps", "cmd_timeout_s", "armed") == [
            CAP_V,
            TIMEOUT_S,
            False,
        ]

        # a path around the gate: the base topic carries what the intruder sends, though
        # the gate is disarmed; `vigil arm` sees the second publisher and refuses
        around = intruder.create_publisher(Twist, "/cmd_vel", 10)
        msg = Twist()
        msg.linear.x = 0.5
        for _ in range(10):
            around.publish(msg)
            spin_until(ros, lambda: False, 0.05)
        assert any(vx == 0.5 for _, vx, _ in intruder.out), "DDS did not carry it"
        code, out, err, _ = vigil("arm", str(config), "--wait", "3")
        assert code == 5, out + err
        assert "/intruder also publishes /cmd_vel (a path around the gate)" in err, err
        assert intruder.get(ros, "armed") == [False]
        intruder.destroy_publisher(around)

        # /arm is open to every participant without SROS2: it arms the gate
        intruder.arm.publish(Bool(data=True))
        assert spin_until(ros, lambda: intruder.get(ros, "armed") == [True], 10.0)
        # what it asks reaches the base capped and slewed
        intruder.out.clear()
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            intruder.ask(5.0, 10.0)
            spin_until(ros, lambda: False, 0.05)
        speeds = [vx for _, vx, _ in intruder.out]
        assert speeds and max(speeds) == pytest.approx(CAP_V), speeds[-5:]
        assert max(abs(wz) for _, _, wz in intruder.out) <= CAP_W + 1e-9
        assert all(b - a <= STEP + 1e-9 for a, b in zip(speeds, speeds[1:], strict=False)), speeds

        # a flood of its commands: capped still, the gate lives and beats on
        intruder.out.clear()
        t0 = time.monotonic()
        for _ in range(5000):
            intruder.ask(50.0, -50.0)
        flood_s = time.monotonic() - t0
        intruder.beats.clear()
        spin_until(ros, lambda: len(intruder.beats) >= 10, 5.0)
        assert len(intruder.beats) >= 10, "the gate stopped beating after the flood"
        assert gate.poll() is None, "the gate died of the flood"
        assert intruder.out and all(
            abs(vx) <= CAP_V + 1e-9 and abs(wz) <= CAP_W + 1e-9 for _, vx, wz in intruder.out
        )

        # silent: a zero within the command timeout (plus a 20 Hz tick and the machine)
        stale = lambda: bool(intruder.out) and intruder.out[-1][1:] == (0.0, 0.0)  # noqa: E731
        assert spin_until(ros, stale, 3.0), "the flood's last command never went stale"
        spin_until(ros, lambda: False, 0.3)
        n = len(intruder.out)
        intruder.ask(5.0, 0.0)
        last = time.monotonic()
        moved = lambda: any(vx > 0.0 for _, vx, _ in intruder.out[n:])  # noqa: E731
        assert spin_until(ros, moved, 3.0), "an armed gate ignored a command"
        k = n + next(i for i, (_, vx, _) in enumerate(intruder.out[n:]) if vx > 0.0)
        assert intruder.out[k][1] <= STEP + 1e-9  # slewed from rest
        stopped = lambda: any(o[1:] == (0.0, 0.0) for o in intruder.out[k:])  # noqa: E731
        assert spin_until(ros, stopped, 3.0), "no zero after the command went stale"
        zero_at = next(t for t, vx, wz in intruder.out[k:] if (vx, wz) == (0.0, 0.0))
        stop_s = zero_at - last
        assert TIMEOUT_S - 0.05 <= stop_s <= TIMEOUT_S + 0.5, stop_s
        print(f"flood: 5000 commands in {flood_s:.2f} s; zero {stop_s:.2f} s after the last")
    finally:
        intruder.arm.publish(Bool(data=False))
        spin_until(ros, lambda: False, 0.2)
        ros.remove_node(intruder)
        intruder.destroy_node()
        log = stop(gate)
    assert "ARMED: forwarding velocity commands" in log  # the intruder armed it, once
    assert log.count("ARMED") == 1, log
