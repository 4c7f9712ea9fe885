"""The velocity gate node: navigation's commands in, capped and armed commands to the base.

In hardware mode the navigation node publishes on ``/nav/cmd_vel`` and only this node
talks to the robot's base driver. It forwards a command only while an operator has
armed it, caps the planar speed and the yaw rate, and sends zeros when commands stop
arriving (see :mod:`stack.hardware.velocity_gate`).

Arming: ``vigil arm CONFIG`` (:mod:`vigil.operator`: the ``armed`` parameter through
``/velocity_gate/set_parameters``, as ``ros2 param set /velocity_gate armed true``) or
true on ``/arm``; false (either way, ``vigil disarm`` uses both) disarms and sends a zero
at once. The ``armed`` parameter always shows the gate's state, whichever way it was set.

Subscribes (names are parameters):
    ``/nav/cmd_vel`` geometry_msgs/Twist (``input_topic``): the commands to gate.
    ``/arm`` std_msgs/Bool (``arm_topic``).

Publishes:
    ``/cmd_vel`` geometry_msgs/Twist (``output_topic``): each accepted command (capped) as
        it arrives; zeros at once when disarmed, on a non-finite command and when
        commands go stale, then zeros at 2 Hz while not armed or stale.
    ``/diagnostics`` diagnostic_msgs/DiagnosticArray (``diagnostics_topic``): status
        ``velocity_gate``, level OK when armed and passing commands (capped or not), WARN
        otherwise, message the reason, values {armed, reason, max_linear_mps,
        max_angular_radps}; on every change of armed or of moving/zero, and at 2 Hz.
    ``/velocity_gate/heartbeat`` std_msgs/UInt64 (``heartbeat_topic``): a count that
        grows by one at every run of the stale check (``rate_hz``, 20 Hz), armed or not,
        moving or not. A base-side watchdog
        (:class:`stack.hardware.base_watchdog.BaseWatchdog`) that stops hearing it knows
        the gate is dead (SIGKILL, a segfault, the OOM killer: no last zero is sent then),
        not merely quiet.

Timing (the stale timeout, the acceleration limit, the 2 Hz repeats) runs on the
monotonic clock, whatever ``use_sim_time`` says. On SIGINT/SIGTERM the node publishes
a last zero and waits (up to 0.5 s) for the driver to acknowledge it.

Parameters: ``config_file`` (YAML with a ``velocity_gate:`` section, keys as
:class:`GateConfig`: the deployment file's ``hardware.velocity_gate``, or a file with the
section at its top); each key of that section is also a read-only parameter
(``max_linear_mps``, ``max_angular_radps``, ``cmd_timeout_s``, ``require_arming``) whose
value overrides the file's; ``armed`` (default false; true when ``require_arming`` is
false), ``rate_hz`` (20, the stale check and the heartbeat), the topics above.
"""

from __future__ import annotations

import dataclasses
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, UInt64

import stack.topics as topic
from stack.cells import ConfigError
from stack.config import read_section
from stack.hardware.velocity_gate import CAPPED, OK, ZERO, GateConfig, VelocityGate
from stack.ros_main import spin_node
from stack.ros_msgs import diagnostics_to_msg
from stack.ros_params import declare, declare_topics

REPEAT_PERIOD_S = 0.5  # zeros and state while idle: 2 Hz


def twist_msg(cmd: tuple[float, float, float]) -> Twist:
    msg = Twist()
    msg.linear.x, msg.linear.y, msg.angular.z = (float(v) for v in cmd)
    return msg


class VelocityGateNode(Node):
    """Arms, caps and times out the base's velocity commands."""

    def __init__(self, **kwargs):
        super().__init__("velocity_gate", **kwargs)
        p = self.declare_parameter
        v = declare(self, config_file="", rate_hz=20.0)
        section = read_section(v.config_file, "velocity_gate", parent="hardware")
        start = GateConfig.from_dict(section, "velocity_gate")  # the file, checked
        # a descriptor each: rclpy records the parameter's type in the descriptor it is
        # given (one shared by all gave every cap the type of the last field, a bool)
        values = {
            f.name: p(f.name, getattr(start, f.name), ParameterDescriptor(read_only=True)).value
            for f in dataclasses.fields(GateConfig)
        }
        self.config = GateConfig.from_dict(values, "velocity_gate")  # parameters, checked
        rate_hz = v.rate_hz
        if not rate_hz > 0:
            raise ConfigError("rate_hz", rate_hz, "must be > 0")
        topics = declare_topics(
            self,
            input=topic.NAV_CMD_VEL,
            output=topic.CMD_VEL,
            arm=topic.ARM,
            diagnostics=topic.DIAGNOSTICS,
            heartbeat=topic.GATE_HEARTBEAT,
        )
        if topics["input"] == topics["output"]:
            raise ConfigError(
                "output_topic", topics["output"], "must differ from input_topic (a bypass)"
            )
        self.gate = VelocityGate(self.config)
        armed = p("armed", self.gate.armed).value
        self.cmd_pub = self.create_publisher(Twist, topics["output"], 10)
        self.state_pub = self.create_publisher(DiagnosticArray, topics["diagnostics"], 10)
        self.heartbeat_pub = self.create_publisher(UInt64, topics["heartbeat"], 1)
        self.beats = 0
        self._moving = False  # the last output published was a forwarded command
        self._last_zero_s = -1e9
        self._last_state: tuple | None = None
        self._last_state_s = -1e9
        self.add_on_set_parameters_callback(self._check_params)
        self.add_post_set_parameters_callback(self._params_set)
        self.set_armed(bool(armed))
        self.create_subscription(Twist, topics["input"], self.on_cmd, 10)
        self.create_subscription(Bool, topics["arm"], self.on_arm, 10)
        # a steady timer: with use_sim_time and a stalled /clock a ROS timer never fires
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(1.0 / rate_hz, self.on_timer, clock=steady)
        c = self.config
        self.get_logger().info(
            f"velocity_gate: {topics['input']} -> {topics['output']}, caps "
            f"{c.max_linear_mps:g} m/s, {c.max_angular_radps:g} rad/s, timeout "
            f"{c.cmd_timeout_s:g} s, {'armed' if self.gate.armed else 'NOT armed'}"
        )

    def now_s(self) -> float:
        """Safety timing runs on the monotonic clock: ``use_sim_time`` or a stalled
        ``/clock`` must not keep a stale command alive."""
        return time.monotonic()

    # -- arming -------------------------------------------------------------------
    def _check_params(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            if param.name == "armed" and param.type_ != Parameter.Type.BOOL:
                return SetParametersResult(successful=False, reason="armed is true or false")
        return SetParametersResult(successful=True)

    def _params_set(self, params: list[Parameter]) -> None:
        for param in params:
            if param.name == "armed":
                self.set_armed(bool(param.value))

    def on_arm(self, msg: Bool) -> None:
        # through the parameter, so that `ros2 param get armed` always tells the truth
        self.set_parameters([Parameter("armed", Parameter.Type.BOOL, bool(msg.data))])

    def set_armed(self, armed: bool) -> None:
        starting = self._last_state is None
        if armed == self.gate.armed and not starting:
            return
        self.gate.arm(armed, self.now_s())
        if armed:
            self.get_logger().warning("ARMED: forwarding velocity commands")
        elif not starting:
            self.get_logger().info("disarmed: zero velocity")
        self.publish_zero()
        self.publish_state(force=True)

    # -- commands -----------------------------------------------------------------
    def on_cmd(self, msg: Twist) -> None:
        out = self.gate.command(msg.linear.x, msg.linear.y, msg.angular.z, self.now_s())
        reason = self.gate.state.reason
        if reason in (OK, CAPPED):
            self.cmd_pub.publish(twist_msg(out))
            if not self._moving:
                self._moving = True
                self.publish_state(force=True)
            return
        if reason != "not armed":  # a non-finite command: stop now
            self.get_logger().warning(
                f"non-finite command ({msg.linear.x}, {msg.linear.y}, {msg.angular.z}): zero",
                throttle_duration_sec=5.0,
            )
            self.publish_zero()
            self.publish_state(force=True)

    def on_timer(self) -> None:
        self.beats += 1
        self.heartbeat_pub.publish(UInt64(data=self.beats))
        now = self.now_s()
        out = self.gate.tick(now)
        if out == ZERO and self.gate.state.reason not in (OK, CAPPED):
            if self._moving:
                self.get_logger().info(f"{self.gate.state.reason}: zero velocity")
                self.publish_zero()
                self.publish_state(force=True)
            elif now - self._last_zero_s >= REPEAT_PERIOD_S:
                self.publish_zero()
        self.publish_state()

    def publish_zero(self) -> None:
        self.cmd_pub.publish(twist_msg(ZERO))
        self._moving = False
        self._last_zero_s = self.now_s()

    def publish_state(self, force: bool = False) -> None:
        now = self.now_s()
        state = self.gate.state
        if not force and now - self._last_state_s < REPEAT_PERIOD_S:
            return
        self._last_state = (state.armed, state.reason)
        self._last_state_s = now
        values = {
            "armed": state.armed,
            "reason": state.reason,
            "max_linear_mps": self.config.max_linear_mps,
            "max_angular_radps": self.config.max_angular_radps,
        }
        level = "ok" if state.armed and state.reason in (OK, CAPPED) else "warn"
        stamp = self.get_clock().now().to_msg()
        self.state_pub.publish(
            diagnostics_to_msg(self.get_name(), "", level, state.reason, values, stamp)
        )


FINAL_ZERO_WAIT_S = 0.5  # how long the last zero may take to be acknowledged


def stop_base(node: VelocityGateNode) -> None:
    """The last words: a zero, sent reliably before the publisher goes away."""
    node.get_logger().info("shutting down: zero velocity")
    node.cmd_pub.publish(twist_msg(ZERO))
    node.cmd_pub.wait_for_all_acked(Duration(seconds=FINAL_ZERO_WAIT_S))


def main(args=None) -> None:
    # leave the base standing still on the way out (SIGINT, SIGTERM or a crash)
    spin_node(VelocityGateNode, args, on_exit=stop_base)


if __name__ == "__main__":
    main()
