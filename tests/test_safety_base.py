"""The base's own command timeout and the gate's heartbeat (issue 23).

What must happen when the sender of the base's commands dies lives on the receiving
side: a SIGKILLed sender publishes no last zero. The twin's base stops
``cmd_timeout_s`` after the last command *arrived* (simulated time, in real-time and
lock-step modes), and the velocity gate beats on ``/velocity_gate/heartbeat`` so that a
base-side watchdog can tell a dead gate from a quiet one.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stack.cells import ConfigError
from stack.hardware.base_watchdog import (
    GATE_SILENT,
    NO_COMMAND,
    OK,
    STALE,
    ZERO,
    BaseWatchdog,
    check_timeout,
)

HERE = Path(__file__).resolve().parent
PEERS = HERE / "safety_peers"
ROOT = HERE.parent


# -- the pure rule --------------------------------------------------------------------
def test_a_command_stands_for_the_timeout_after_its_receipt_then_zero():
    w = BaseWatchdog(cmd_timeout_s=0.5)
    assert w.output(0.0) == ZERO and w.reason == NO_COMMAND
    w.command((0.3, 0.0, 0.2), 10.0)
    assert w.output(10.0) == (0.3, 0.0, 0.2) and w.reason == OK
    assert w.output(10.5) == (0.3, 0.0, 0.2)
    assert w.output(10.5001) == ZERO and w.reason == STALE
    assert w.output(1e9) == ZERO
    w.command((0.1, 0.0, 0.0), 11.0)  # a new command stands again
    assert w.output(11.2) == (0.1, 0.0, 0.0)
    assert w.output(10.9) == ZERO and w.reason == STALE  # a clock that ran backwards


def test_a_non_finite_command_is_held_as_zeros():
    w = BaseWatchdog()
    w.command((math.nan, math.inf, -math.inf), 0.0)
    assert w.output(0.1) == ZERO


def test_a_silent_gate_stops_the_base_before_the_command_timeout():
    w = BaseWatchdog(cmd_timeout_s=0.5, heartbeat_timeout_s=0.2)
    w.heartbeat(0.0)
    w.command((0.3, 0.0, 0.0), 0.0)
    assert w.output(0.15) == (0.3, 0.0, 0.0)
    assert w.output(0.25) == ZERO and w.reason == GATE_SILENT
    w.heartbeat(0.3)  # a quiet gate keeps beating: only the command's age counts
    assert w.output(0.4) == (0.3, 0.0, 0.0) and w.reason == OK
    # looked at only once both have timed out (a loaded machine): the dead gate is named
    assert w.output(1.0) == ZERO and w.reason == GATE_SILENT
    w.heartbeat(1.0)
    assert w.output(1.05) == ZERO and w.reason == STALE  # beating, the command old


@pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0, 0.0, "0.5", True, None])
def test_a_timeout_that_could_keep_a_command_alive_is_refused(bad):
    with pytest.raises(ConfigError, match=r"cmd_timeout_s: .* is invalid"):
        BaseWatchdog(cmd_timeout_s=bad)
    if bad is not None:  # None: the heartbeat is not watched
        with pytest.raises(ConfigError, match="heartbeat_timeout_s"):
            BaseWatchdog(heartbeat_timeout_s=bad)


def test_check_timeout_bounds():
    assert check_timeout("k", 1) == 1.0
    with pytest.raises(ConfigError, match="<= 1"):
        check_timeout("k", 1.5, upper_s=1.0)


# -- the twin's base ------------------------------------------------------------------
def _bridge(**params):
    from rclpy.parameter import Parameter

    from twin.bridge_node import TwinBridge
    from twin.config import TwinConfig
    from twin.twin import Twin

    cfg = TwinConfig.from_dict({"camera": {"width_px": 160, "height_px": 100}})
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    return TwinBridge(Twin(cfg, seed=0), parameter_overrides=overrides)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -0.5])
def test_the_bridge_refuses_a_timeout_that_never_stops_the_base(ros, bad):
    with pytest.raises(ConfigError, match="cmd_timeout_s"):
        _bridge(cmd_timeout_s=bad)


def _spawn(script: Path, *args: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        [sys.executable, str(script), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )


def _speed(bridge) -> float:
    return float(abs(bridge.twin.ground_truth().robot_velocity[0]))


def _spin_until(ex, cond, wall_s: float) -> bool:
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.01)
        if cond():
            return True
    return False


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_the_twin_base_stops_within_the_timeout_after_its_sender_is_killed(ros, mode):
    """SIGKILL the process sending /cmd_vel while the base drives at 0.3 m/s: the base
    stops ``cmd_timeout_s`` (+ the braking time of its acceleration limit) of simulated
    time after the last command arrived, though no zero was ever sent."""
    params: dict = {"cmd_timeout_s": 0.5}
    if mode == "realtime":
        params["realtime"] = True
    else:  # the sender is a participant; once dead it is waited for 1 s, then excused
        params.update(
            lockstep=True,
            participants=["driver"],
            stall_warn_s=0.5,
            stall_timeout_s=1.0,
            stall_abort_s=60.0,
        )
    bridge = _bridge(**params)
    ros.add_node(bridge)
    proc = _spawn(PEERS / "drive_base.py", *([mode] if mode == "lockstep" else []))
    try:
        assert _spin_until(ros, lambda: _speed(bridge) > 0.25, 90.0), "the base never moved"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    robot = bridge.twin.config.robot
    braking_s = 0.3 / robot.max_linear_accel_mps2
    period_s = bridge.twin.config.control_period_s
    speeds: list[tuple[float, float]] = []  # (simulated time, speed)

    def record() -> bool:
        speeds.append((bridge.twin.time_s, _speed(bridge)))
        last = bridge.watchdog.last_command_s
        return bridge.twin.time_s > last + 0.5 + braking_s + 1.0

    assert _spin_until(ros, record, 120.0), "simulated time stood still after the kill"
    last = bridge.watchdog.last_command_s
    assert bridge.watchdog.reason == STALE
    # still moving just before the timeout (nothing else stopped it)...
    moving = [s for t, s in speeds if last < t < last + 0.5 - 2 * period_s]
    assert moving and min(moving) > 0.2, speeds[:10]
    # ...and at rest from the timeout plus braking on, without a zero ever being sent
    t_zero = last + 0.5 + braking_s + 3 * period_s
    late = [s for t, s in speeds if t >= t_zero]
    assert late and max(late) < 0.01, (last, speeds[-10:])
    ros.remove_node(bridge)
    bridge.destroy_node()


# -- the gate's heartbeat -------------------------------------------------------------
@pytest.mark.slow
def test_the_gate_heartbeat_tells_a_dead_gate_from_a_quiet_one(ros):
    """A quiet gate (no navigation commands: stale) keeps beating; a SIGKILLed gate
    leaves its last non-zero command on the base topic, but a base-side watchdog on
    its heartbeat stops within the heartbeat timeout."""
    import rclpy
    from geometry_msgs.msg import Twist
    from std_msgs.msg import UInt64

    import stack.topics as topic

    node = rclpy.create_node("base_side")
    watchdog = BaseWatchdog(cmd_timeout_s=0.5, heartbeat_timeout_s=0.25)
    beats: list[int] = []
    beat_times: list[float] = []
    base: list[tuple[float, float, float]] = []

    def on_beat(msg: UInt64) -> None:
        beats.append(msg.data)
        beat_times.append(time.monotonic())
        watchdog.heartbeat(beat_times[-1])

    def on_base(msg: Twist) -> None:
        cmd = (msg.linear.x, msg.linear.y, msg.angular.z)
        base.append(cmd)
        watchdog.command(cmd, time.monotonic())

    node.create_subscription(UInt64, topic.GATE_HEARTBEAT, on_beat, 10)
    node.create_subscription(Twist, topic.CMD_VEL, on_base, 10)
    nav = node.create_publisher(Twist, topic.NAV_CMD_VEL, 10)
    ros.add_node(node)
    argv = ["-m", "stack.hardware.node_velocity_gate", "--ros-args", "-p", "require_arming:=false"]
    gate = subprocess.Popen(
        [sys.executable, *argv],
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        assert _spin_until(ros, lambda: len(beats) >= 3, 60.0), "no heartbeat"
        # quiet: no navigation command for 1 s, the gate sends zeros and keeps beating
        n0 = len(beats)
        _spin_until(ros, lambda: False, 1.0)
        assert len(beats) - n0 >= 10, "a quiet gate must keep beating at 20 Hz"
        assert beats == sorted(beats) and len(set(beats)) == len(beats)

        def drive() -> bool:
            msg = Twist()
            msg.linear.x = 0.2
            nav.publish(msg)
            return watchdog.output(time.monotonic()) != ZERO

        assert _spin_until(ros, drive, 30.0), "the gate never forwarded a command"
        gate.send_signal(signal.SIGKILL)
        gate.wait(timeout=10)
        t_kill = time.monotonic()
        # navigation is still alive and asking; only the heartbeat shows the gate died
        stopped = _spin_until(ros, lambda: not drive(), 5.0)
        assert stopped and watchdog.reason == GATE_SILENT
        assert base[-1][0] > 0.0  # no last zero came from the killed gate
        # the heartbeat died with the gate (what was in flight at the kill aside) ...
        n_dead = len(beats)
        _spin_until(ros, lambda: False, 1.0)
        assert len(beats) == n_dead
        # ... and the base stopped 0.25 s after the last beat it heard, before its
        # command timeout (0.5 s) would have: on its own clock, not this test's polling
        # (a wall-clock bound on the polling failed on a loaded machine)
        last_beat_s = beat_times[-1]
        assert last_beat_s >= t_kill - 1.0  # it beat until the kill
        assert watchdog.output(last_beat_s + 0.25 + 1e-3) == ZERO
        assert watchdog.reason == GATE_SILENT
    finally:
        if gate.poll() is None:
            gate.kill()
            gate.wait(timeout=10)
        ros.remove_node(node)
        node.destroy_node()
