"""The hardware side: the velocity gate and the camera stream, pure and through rclpy."""

import math

import cv2
import numpy as np
import pytest

from stack.cells import ConfigError
from stack.hardware.camera_stream import (
    CameraStream,
    StreamConfig,
    StreamFrame,
    StreamProblem,
    calibration_from_dict,
    load_calibration,
    redact_url,
)
from stack.hardware.velocity_gate import MAX_DT_S, PLATFORM, GateConfig, VelocityGate

# -- the velocity gate -----------------------------------------------------------------


def armed_gate(**kw) -> VelocityGate:
    gate = VelocityGate(GateConfig(**kw))
    gate.arm(True, 0.0)
    return gate


def settle(gate: VelocityGate, cmd, t: float, duration_s: float = 3.0):
    """Send ``cmd`` every 50 ms for ``duration_s`` (past any acceleration ramp); the
    last output and the time after."""
    out = None
    for _ in range(round(duration_s / 0.05)):
        t += 0.05
        out = gate.command(*cmd, t)
    return out, t


def test_gate_outputs_zeros_until_armed_and_after_disarming():
    gate = VelocityGate()
    assert not gate.armed and gate.state.reason == "not armed"
    assert gate.command(0.1, 0.0, 0.1, 0.0) == (0.0, 0.0, 0.0)
    assert gate.tick(0.1) == (0.0, 0.0, 0.0) and gate.state.reason == "not armed"
    gate.arm(True, 1.0)
    out, t = settle(gate, (0.1, -0.05, 0.2), 1.0)
    assert out == pytest.approx((0.1, -0.05, 0.2))
    assert gate.state.reason == "ok" and gate.state.armed
    assert gate.tick(t + 0.2) == pytest.approx((0.1, -0.05, 0.2))
    assert gate.arm(False, t + 0.3) == (0.0, 0.0, 0.0)
    assert gate.tick(t + 0.3) == (0.0, 0.0, 0.0) and gate.state.reason == "not armed"
    assert gate.command(0.1, 0.0, 0.0, t + 0.4) == (0.0, 0.0, 0.0)


def test_gate_caps_the_planar_speed_keeping_its_direction_and_the_yaw_rate():
    gate = armed_gate(max_linear_mps=0.3, max_angular_radps=0.6)
    (vx, vy, wz), t = settle(gate, (0.6, -0.8, -2.0), 0.0)
    assert gate.state.reason == "capped"
    assert math.hypot(vx, vy) == pytest.approx(0.3)
    assert (vx, vy) == pytest.approx((0.18, -0.24))  # both scaled by the same factor
    assert wz == pytest.approx(-0.6)
    out, t = settle(gate, (0.0, 0.0, 5.0), t)
    assert out == pytest.approx((0.0, 0.0, 0.6))
    out, t = settle(gate, (0.0, 0.5, 0.0), t)
    assert out == pytest.approx((0.0, 0.3, 0.0))
    # within the caps: as given (the planar norm, not each axis, is capped)
    out, t = settle(gate, (0.2, 0.2, 0.5), t)
    assert out == pytest.approx((0.2, 0.2, 0.5))
    assert gate.state.reason == "ok"


def test_gate_zeros_a_stale_command_and_arming_forgets_the_last_one():
    gate = armed_gate(cmd_timeout_s=0.5)
    assert gate.tick(0.0) == (0.0, 0.0, 0.0) and gate.state.reason == "stale"  # none yet
    out, t = settle(gate, (0.2, 0.0, 0.0), 8.0)
    assert gate.tick(t + 0.5) == pytest.approx((0.2, 0.0, 0.0))
    assert gate.tick(t + 0.51) == (0.0, 0.0, 0.0) and gate.state.reason == "stale"
    gate.command(0.2, 0.0, 0.0, 11.0)
    gate.arm(False, 11.1)
    gate.arm(True, 11.2)
    assert gate.tick(11.2) == (0.0, 0.0, 0.0)  # no command since arming
    assert gate.state.reason == "stale"


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_gate_zeros_a_non_finite_command_and_cancels_the_previous_one(bad):
    gate = armed_gate()
    out, t = settle(gate, (0.2, 0.1, 0.1), 0.0)
    assert out == pytest.approx((0.2, 0.1, 0.1))
    assert gate.command(0.1, bad, 0.0, t + 0.1) == (0.0, 0.0, 0.0)
    assert gate.state.reason == "non-finite command"
    assert gate.tick(t + 0.2) == (0.0, 0.0, 0.0)
    out, t = settle(gate, (0.1, 0.0, 0.0), t + 0.2)  # a good one works again
    assert out == pytest.approx((0.1, 0.0, 0.0))


def test_gate_limits_acceleration_but_never_delays_a_stop():
    gate = armed_gate(max_linear_accel_mps2=0.5, max_angular_accel_radps2=1.0)
    # 50 ms after arming: at most 0.025 m/s and 0.05 rad/s
    assert gate.command(0.3, 0.0, 0.6, 0.05) == pytest.approx((0.025, 0.0, 0.05))
    assert gate.state.reason == "capped"
    # the ramp: each 50 ms adds 0.025 m/s; a long gap grants no more than MAX_DT_S
    assert gate.command(0.3, 0.0, 0.6, 0.10) == pytest.approx((0.05, 0.0, 0.1))
    assert gate.command(0.3, 0.0, 0.6, 5.0)[0] == pytest.approx(0.05 + 0.5 * MAX_DT_S)
    out, t = settle(gate, (0.3, 0.0, 0.6), 5.0)
    assert out == pytest.approx((0.3, 0.0, 0.6))
    # slowing down and stopping pass at once
    assert gate.command(0.1, 0.0, 0.2, t + 0.01) == pytest.approx((0.1, 0.0, 0.2))
    assert gate.command(0.0, 0.0, 0.0, t + 0.02) == (0.0, 0.0, 0.0)
    # reversing is a change of 0.6 m/s: slewed, first through zero
    settle(gate, (0.3, 0.0, 0.0), t + 0.02)
    vx, _, _ = gate.command(-0.3, 0.0, 0.0, t + 10.0)
    assert vx == pytest.approx(0.3 - 0.5 * MAX_DT_S)
    # a stale command drops the speed to zero, and the ramp starts again from zero
    assert gate.tick(t + 20.0) == (0.0, 0.0, 0.0)
    assert gate.command(0.3, 0.0, 0.0, t + 20.05)[0] == pytest.approx(0.025)


@pytest.mark.parametrize(
    "key, value",
    [
        ("max_linear_mps", 50.0),
        ("max_linear_mps", PLATFORM.max_linear_mps + 0.01),
        ("max_angular_radps", 10.0),
        ("cmd_timeout_s", 30.0),
        ("max_linear_accel_mps2", 100.0),
        ("max_angular_accel_radps2", 0.0),
        ("max_linear_accel_mps2", math.inf),
    ],
)
def test_gate_caps_beyond_the_platform_limits_are_refused(key, value):
    with pytest.raises(ConfigError) as err:
        GateConfig.from_dict({key: value})
    assert err.value.key == f"velocity_gate.{key}"
    GateConfig.from_dict({"max_linear_mps": PLATFORM.max_linear_mps})  # the limit itself is fine


def test_gate_config_from_dict_and_require_arming_false():
    cfg = GateConfig.from_dict({"max_linear_mps": 0.5, "require_arming": False})
    assert cfg.max_linear_mps == 0.5 and isinstance(cfg.max_linear_mps, float)
    gate = VelocityGate(cfg)
    assert gate.armed and settle(gate, (0.5, 0.0, 0.0), 0.0)[0] == pytest.approx((0.5, 0.0, 0.0))
    gate.arm(False, 5.0)  # an explicit disarm holds even without require_arming
    assert gate.command(0.5, 0.0, 0.0, 5.1) == (0.0, 0.0, 0.0)
    assert GateConfig.from_dict(None) == GateConfig()
    with pytest.raises(ConfigError, match=r"velocity_gate.max_angular_radps: -1.0 is invalid"):
        GateConfig.from_dict({"max_angular_radps": -1.0})
    with pytest.raises(ConfigError, match="velocity_gate.cmd_timeout_s: 'x'.*number"):
        GateConfig.from_dict({"cmd_timeout_s": "x"})
    with pytest.raises(ConfigError, match="velocity_gate.speed: .*unknown key"):
        GateConfig.from_dict({"speed": 1.0})
    with pytest.raises(ConfigError, match="require_arming.*true or false"):
        GateConfig.from_dict({"require_arming": 1})
    with pytest.raises(ConfigError, match="max_linear_mps: nan"):  # built in code: the field
        GateConfig(max_linear_mps=math.nan)


# -- the camera stream -------------------------------------------------------------------


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def write_video(path, n_frames=6, size=(64, 48)):
    """An MJPG .avi whose frame i is BGR (200, 10*i, 30) with a moving white square."""
    w, h = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (w, h))
    assert writer.isOpened()
    for i in range(n_frames):
        frame = np.zeros((h, w, 3), np.uint8)
        frame[:] = (200, 10 * i, 30)
        frame[4:12, 4 + 4 * i : 12 + 4 * i] = 255
        writer.write(frame)
    writer.release()
    return path


class FakeCapture:
    def __init__(self, frames, opened=True):
        self.frames, self.opened, self.released = list(frames), opened, False

    def isOpened(self):  # noqa: N802 - cv2's name
        return self.opened

    def read(self):
        if not self.frames:
            return False, None
        f = self.frames.pop(0)
        if isinstance(f, Exception):
            raise f
        return True, f

    def release(self):
        self.released = True


class FakeFactory:
    """Hands out the given captures in turn (the last one again when they run out)."""

    def __init__(self, *captures):
        self.captures, self.calls = list(captures), []

    def __call__(self, source, api, params):
        self.calls.append((source, api, list(params)))
        return self.captures.pop(0) if len(self.captures) > 1 else self.captures[0]


def test_stream_config_validation():
    cfg = StreamConfig.from_dict({"url": "0", "rate_hz": 5})
    assert cfg.url == "0" and cfg.source == 0 and cfg.rate_hz == 5.0
    assert StreamConfig(url="http://cam/mjpg").source == "http://cam/mjpg"
    with pytest.raises(ConfigError, match="camera_stream.url: '' is invalid: must name a URL"):
        StreamConfig.from_dict({})
    with pytest.raises(ConfigError, match="camera_stream.url: 0 is invalid: must be a string"):
        StreamConfig.from_dict({"url": 0})  # a device index is written "0"
    with pytest.raises(ConfigError, match="camera_stream.url: '  '"):
        StreamConfig.from_dict({"url": "  "})
    with pytest.raises(ConfigError, match="camera_stream.width_px.*both"):
        StreamConfig.from_dict({"url": "x", "width_px": 640})
    with pytest.raises(ConfigError, match="camera_stream.frozen_after_frames: 1"):
        StreamConfig.from_dict({"url": "x", "frozen_after_frames": 1})
    with pytest.raises(ConfigError, match="camera_stream.rate_hz: 0.0"):
        StreamConfig.from_dict({"url": "x", "rate_hz": 0})
    with pytest.raises(ConfigError, match="camera_stream.fps.*unknown key"):
        StreamConfig.from_dict({"url": "x", "fps": 10})
    with pytest.raises(ConfigError, match="camera_stream.height_px: 1.5.*integer"):
        StreamConfig.from_dict({"url": "x", "height_px": 1.5})
    assert redact_url("rtsp://root:secret@10.0.0.9/axis-media") == "rtsp://***@10.0.0.9/axis-media"
    assert redact_url("/videos/a.avi") == "/videos/a.avi"


def test_stream_reads_a_video_file_as_rgb_and_reopens_it_at_the_end(tmp_path):
    path = write_video(tmp_path / "cam.avi", n_frames=6)
    clock = FakeClock()
    stream = CameraStream(StreamConfig(url=str(path), reconnect_s=2.0), clock=clock)
    frames = [stream.read() for _ in range(6)]
    assert all(isinstance(f, StreamFrame) for f in frames)
    assert [f.seq for f in frames] == [1, 2, 3, 4, 5, 6]
    rgb = frames[3].rgb
    assert rgb.shape == (48, 64, 3) and rgb.dtype == np.uint8 and rgb.flags.c_contiguous
    assert np.abs(rgb[40, 40].astype(int) - (30, 30, 200)).max() <= 8  # BGR (200, 30, 30)
    assert stream.problem is None and stream.opens == 1
    end = stream.read()
    assert isinstance(end, StreamProblem) and end.kind == "read_failed"
    assert end.message == "read failed, reconnecting in 2.0 s"
    assert end.retry_at_s == pytest.approx(102.0) and not stream.is_open
    clock.t += 1.9
    assert stream.read() is end and stream.opens == 1  # waiting
    clock.t += 0.2
    again = stream.read()
    assert isinstance(again, StreamFrame) and again.seq == 7 and stream.opens == 2
    assert stream.problem is None


def test_stream_resizes_when_asked(tmp_path):
    path = write_video(tmp_path / "cam.avi", n_frames=2)
    stream = CameraStream(StreamConfig(url=str(path), width_px=32, height_px=20))
    frame = stream.read()
    assert isinstance(frame, StreamFrame) and frame.rgb.shape == (20, 32, 3)
    stream.close()


def test_stream_reports_what_cannot_be_opened_and_never_raises(tmp_path):
    clock = FakeClock()
    missing = CameraStream(StreamConfig(url=str(tmp_path / "none.avi")), clock=clock)
    problem = missing.read()
    assert isinstance(problem, StreamProblem) and problem.kind == "cannot_open"
    assert problem.message == f"cannot open {tmp_path / 'none.avi'}"
    bad = CameraStream(StreamConfig(url="rtsp://root:secret@127.0.0.1:1/x", open_timeout_s=1.0))
    problem = bad.read()
    assert isinstance(problem, StreamProblem) and problem.kind == "cannot_open"
    assert problem.message == "cannot open rtsp://***@127.0.0.1:1/x"  # no password

    def explode(*args):
        raise RuntimeError("backend gone")

    boom = CameraStream(StreamConfig(url="x"), capture_factory=explode)
    assert boom.read().message == "cannot open x: backend gone"
    raising = CameraStream(
        StreamConfig(url="x"), capture_factory=FakeFactory(FakeCapture([OSError("eof")]))
    )
    problem = raising.read()
    assert problem.kind == "read_failed" and "eof" in problem.message


def test_stream_reconnects_after_reconnect_s_with_the_timeouts_passed():
    clock = FakeClock()
    frame = np.zeros((4, 6), np.uint8)  # grey frames become RGB
    factory = FakeFactory(FakeCapture([], opened=False), FakeCapture([frame, frame + 1]))
    stream = CameraStream(
        StreamConfig(url="0", reconnect_s=2.0, open_timeout_s=3.0), factory, clock
    )
    first = stream.read()
    assert first.kind == "cannot_open" and first.message == "cannot open 0"
    assert factory.calls == [
        (
            0,
            cv2.CAP_ANY,
            [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, 3000, cv2.CAP_PROP_READ_TIMEOUT_MSEC, 3000],
        )
    ]
    for dt in (0.5, 1.0, 0.4):
        clock.t += dt
        assert stream.read() is first
    assert len(factory.calls) == 1
    clock.t += 0.1
    got = stream.read()
    assert isinstance(got, StreamFrame) and got.rgb.shape == (4, 6, 3) and got.seq == 1
    assert len(factory.calls) == 2


def test_stream_detects_a_frozen_stream_and_reopens_it():
    clock = FakeClock()
    same = np.full((8, 8, 3), 7, np.uint8)
    frozen_cap = FakeCapture([same.copy() for _ in range(10)])
    fresh_cap = FakeCapture([same, same + 1])
    factory = FakeFactory(frozen_cap, fresh_cap)
    stream = CameraStream(StreamConfig(url="x", frozen_after_frames=5), factory, clock)
    got = [stream.read() for _ in range(5)]
    assert all(isinstance(g, StreamFrame) for g in got[:4])
    problem = got[4]
    assert isinstance(problem, StreamProblem) and problem.kind == "frozen"
    assert problem.message == "frozen: 5 identical frames"
    assert frozen_cap.released and not stream.is_open
    clock.t += 2.0
    assert isinstance(stream.read(), StreamFrame) and stream.opens == 2
    # changing frames never count as frozen
    moving = [np.full((8, 8, 3), i, np.uint8) for i in range(30)]
    stream = CameraStream(StreamConfig(url="x"), FakeFactory(FakeCapture(moving)), clock)
    assert all(isinstance(stream.read(), StreamFrame) for _ in range(30))


def test_calibration_files_in_both_layouts_and_scaling(tmp_path):
    ours = tmp_path / "axis.yaml"
    ours.write_text(
        "width: 640\nheight: 480\nK: [500, 0, 319.5, 0, 500, 239.5, 0, 0, 1]\n"
        "D: [-0.3, 0.1, 0, 0, 0]\ndistortion_model: plumb_bob\n"
    )
    cal = load_calibration(ours)
    assert (cal.width, cal.height, cal.D[0]) == (640, 480, -0.3)
    assert cal.P == (500, 0, 319.5, 0, 0, 500, 239.5, 0, 0, 0, 1, 0)
    half = cal.scaled(320, 240)
    assert half.K == pytest.approx((250, 0, 159.5, 0, 250, 119.5, 0, 0, 1))
    assert half.P[2] == pytest.approx(159.5) and half.D == cal.D
    ros = calibration_from_dict(
        {
            "image_width": 640,
            "image_height": 480,
            "camera_name": "axis",
            "camera_matrix": {"rows": 3, "cols": 3, "data": list(cal.K)},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": list(cal.D)},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": list(cal.R)},
            "projection_matrix": {"rows": 3, "cols": 4, "data": list(cal.P)},
        }
    )
    assert ros == cal
    with pytest.raises(ConfigError, match="camera_info_file.K: None is invalid: is required"):
        (tmp_path / "bad.yaml").write_text("width: 640\nheight: 480\n")
        load_calibration(tmp_path / "bad.yaml")
    with pytest.raises(ConfigError, match="calibration.K.*needs 9"):
        calibration_from_dict({"width": 1, "height": 1, "K": [1, 2]})


# -- the nodes through rclpy -------------------------------------------------------------

try:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Bool

    from stack.hardware.node_camera_stream import CameraStreamNode
    from stack.hardware.node_velocity_gate import VelocityGateNode
    from stack.ros_msgs import diagnostics_from_msg
except ImportError:  # the pure tests above still run
    rclpy = None
    Node = object

needs_ros = pytest.mark.skipif(rclpy is None, reason="needs rclpy")


from rostest import spin_until  # noqa: E402  (the ros fixture: conftest.py)


class Probe(Node):
    """Stands in for navigation, the operator and the base driver; records traffic."""

    def __init__(self):
        super().__init__("probe")
        self.out: list[tuple[float, float, float]] = []
        self.states: list[dict] = []
        self.images: list[Image] = []
        self.infos: list[CameraInfo] = []
        self.status: list[dict] = []
        self.levels: list[int] = []
        self.nav_pub = self.create_publisher(Twist, "/nav/cmd_vel", 10)
        self.arm_pub = self.create_publisher(Bool, "/arm", 10)
        self.create_subscription(Twist, "/cmd_vel", self.on_cmd, 10)
        # health on /diagnostics (issue 14): one status per node, keyed by its name
        self.create_subscription(DiagnosticArray, "/diagnostics", self.on_diagnostics, 10)
        self.create_subscription(Image, "/camera/image_raw", self.images.append, 10)
        self.create_subscription(CameraInfo, "/camera/camera_info", self.infos.append, 10)

    def on_cmd(self, msg):
        self.out.append((msg.linear.x, msg.linear.y, msg.angular.z))

    def on_diagnostics(self, msg):
        for name, entry in diagnostics_from_msg(msg).items():
            level = entry.pop("level")
            if name == "velocity_gate":
                entry.pop("message")
                self.states.append(entry)
                self.levels.append(level)
            elif name == "camera_stream":
                self.status.append(entry)

    def send(self, vx, vy, wz):
        msg = Twist()
        msg.linear.x, msg.linear.y, msg.angular.z = vx, vy, wz
        self.nav_pub.publish(msg)


@needs_ros
@pytest.mark.ros
def test_velocity_gate_node_holds_until_armed_then_caps_and_times_out(ros, tmp_path):
    config = tmp_path / "hardware.yaml"
    config.write_text(
        "velocity_gate:\n  max_linear_mps: 0.3\n  cmd_timeout_s: 0.3\n"
        "  max_linear_accel_mps2: 2.0\n  max_angular_accel_radps2: 6.0\n"
    )
    probe = Probe()
    gate = VelocityGateNode(parameter_overrides=[Parameter("config_file", value=str(config))])
    assert gate.config.cmd_timeout_s == 0.3
    for node in (probe, gate):
        ros.add_node(node)
    try:
        spin_until(ros, lambda: False, 0.3)  # discovery
        # not armed: commands give zeros (at 2 Hz), never motion
        for _ in range(5):
            probe.send(0.5, 0.0, 0.0)
            spin_until(ros, lambda: False, 0.1)
        assert spin_until(ros, lambda: len(probe.out) >= 1, 2.0)
        assert all(o == (0.0, 0.0, 0.0) for o in probe.out)
        assert probe.states and probe.states[-1]["armed"] is False
        assert probe.states[-1]["reason"] == "not armed" and probe.levels[-1] == 1  # WARN
        # arm through /arm: capped commands go through; the parameter follows
        probe.arm_pub.publish(Bool(data=True))
        assert spin_until(ros, lambda: gate.gate.armed, 3.0), "/arm true did not arm"
        assert gate.get_parameter("armed").value is True
        n = len(probe.out)
        at_cap = lambda: probe.out[-1] == pytest.approx((0.18, 0.24, 0.6))  # noqa: E731
        for _ in range(40):  # at 20 Hz: past the acceleration ramp (0.1 m/s per step)
            probe.send(0.6, 0.8, 2.0)
            if spin_until(ros, at_cap, 0.05):
                break
        moving = [o for o in probe.out[n:] if o != (0.0,) * 3]
        assert moving and at_cap()
        assert all(math.hypot(o[0], o[1]) <= 0.3 + 1e-9 for o in moving)
        # commands stop: a zero within the timeout plus a tick
        n = len(probe.out)
        assert spin_until(ros, lambda: len(probe.out) > n, 1.0)
        assert probe.out[n] == (0.0, 0.0, 0.0)
        assert spin_until(ros, lambda: probe.states[-1]["reason"] == "stale", 1.5)
        assert probe.states[-1] == {
            "armed": True,
            "reason": "stale",
            "max_linear_mps": 0.3,
            "max_angular_radps": 0.6,
        }
        # disarm by parameter: a zero at once, and the gate holds
        for _ in range(20):
            probe.send(0.1, 0.0, 0.0)
            if spin_until(ros, lambda: probe.out[-1] == pytest.approx((0.1, 0.0, 0.0)), 0.05):
                break
        assert probe.out[-1] == pytest.approx((0.1, 0.0, 0.0))
        n = len(probe.out)
        gate.set_parameters([Parameter("armed", value=False)])
        assert probe.out[n:] == [] and not gate.gate.armed
        assert spin_until(ros, lambda: len(probe.out) > n, 1.0)
        assert probe.out[n] == (0.0, 0.0, 0.0)
        probe.send(0.1, 0.0, 0.0)
        spin_until(ros, lambda: False, 0.3)
        assert all(o == (0.0, 0.0, 0.0) for o in probe.out[n:])
        # caps are read-only at run time
        result = gate.set_parameters([Parameter("max_linear_mps", value=2.0)])[0]
        assert not result.successful and gate.config.max_linear_mps == 0.3
    finally:
        for node in (probe, gate):
            ros.remove_node(node)
            node.destroy_node()


@needs_ros
@pytest.mark.ros
def test_camera_stream_node_publishes_rgb8_images_from_a_video_file(ros, tmp_path):
    video = write_video(tmp_path / "cam.avi", n_frames=20)
    info = tmp_path / "axis.yaml"
    info.write_text("width: 128\nheight: 96\nK: [100, 0, 63.5, 0, 100, 47.5, 0, 0, 1]\nD: []\n")
    probe = Probe()
    cam = CameraStreamNode(
        parameter_overrides=[
            Parameter("url", value=str(video)),
            Parameter("rate_hz", value=30.0),
            Parameter("camera_info_file", value=str(info)),
        ]
    )
    for node in (probe, cam):
        ros.add_node(node)
    try:
        assert spin_until(ros, lambda: len(probe.images) >= 3, 10.0), "no images"
        img = probe.images[0]
        assert (img.encoding, img.width, img.height, img.step) == ("rgb8", 64, 48, 192)
        assert img.header.frame_id == "camera_optical_frame"  # the frame TF knows
        assert img.header.stamp.sec > 0
        rgb = np.frombuffer(bytes(img.data), np.uint8).reshape(48, 64, 3)
        assert np.abs(rgb[40, 40].astype(int) - (30, 0, 200)).max() <= 8
        assert spin_until(ros, lambda: len(probe.infos) >= 1, 2.0)
        ci = probe.infos[0]
        assert (ci.width, ci.height) == (64, 48)
        assert ci.k[0] == pytest.approx(50.0) and ci.k[2] == pytest.approx(31.5)
        assert spin_until(ros, lambda: any(s["ok"] for s in probe.status), 2.0)
    finally:
        for node in (probe, cam):
            ros.remove_node(node)
            node.destroy_node()


@needs_ros
@pytest.mark.ros
def test_camera_stream_node_keeps_running_without_a_stream(ros, tmp_path):
    probe = Probe()
    cam = CameraStreamNode(
        parameter_overrides=[
            Parameter("url", value=str(tmp_path / "gone.avi")),
            Parameter("reconnect_s", value=0.2),
        ]
    )
    for node in (probe, cam):
        ros.add_node(node)
    try:
        assert spin_until(ros, lambda: len(probe.status) >= 1, 5.0), "no status"
        assert probe.status[0]["ok"] is False and probe.status[0]["kind"] == "cannot_open"
        assert probe.status[0]["message"].startswith("cannot open ")
        spin_until(ros, lambda: False, 0.5)
        assert probe.images == []
    finally:
        for node in (probe, cam):
            ros.remove_node(node)
            node.destroy_node()
    with pytest.raises(ConfigError, match="camera_stream.url"):
        CameraStreamNode()


@needs_ros
@pytest.mark.ros
def test_standalone_nodes_read_the_deployment_file_as_the_launcher_gives_it(ros, tmp_path):
    """docs/HARDWARE.md starts the gate and the stream on their own with
    ``config_file:=config/hardware.yaml``, whose sections sit under ``hardware:``;
    before, they read top-level sections, found none and ran on built-in defaults. Now a
    node started on its own and one started with the parameters ``vigil launch`` gives
    it (:func:`vigil.system.prepare`: the run folder's ``hardware.yaml``, ``armed``, the
    topics) hold the same configuration, and it is the file's: every key of both
    sections (``velocity_gate``, ``camera_stream``) set away from its default."""
    import dataclasses

    import yaml

    from stack.hardware.camera_stream import StreamConfig
    from stack.hardware.node_camera_stream import CameraStreamNode
    from vigil.deployment import load_deployment
    from vigil.run import REPO
    from vigil.system import prepare

    data = yaml.safe_load((REPO / "config" / "hardware.yaml").read_text())
    gate_keys = {"max_linear_mps": 0.25, "max_angular_radps": 0.5, "cmd_timeout_s": 0.4,
                 "max_linear_accel_mps2": 0.4, "max_angular_accel_radps2": 1.2,
                 "require_arming": True}  # fmt: skip
    stream_keys = {"url": "http://192.168.1.91/axis-cgi/mjpg/video.cgi", "rate_hz": 5.0,
                   "width_px": 320, "height_px": 200, "reconnect_s": 1.5,
                   "frozen_after_frames": 30, "open_timeout_s": 4.0}  # fmt: skip
    assert set(gate_keys) == {f.name for f in dataclasses.fields(GateConfig)}
    assert set(stream_keys) == {f.name for f in dataclasses.fields(StreamConfig)}
    data["hardware"]["velocity_gate"].update(gate_keys)
    data["hardware"]["camera_stream"].update(stream_keys)
    (tmp_path / "cal.yaml").write_text("unused: true\n")
    (tmp_path / "policy.npz").write_bytes(b"")
    data.update(task=str(REPO / "config" / "task-r2.yaml"), policy="policy.npz",
                perception={"calibration": "cal.yaml"})  # fmt: skip
    deployment = tmp_path / "deployment.yaml"
    deployment.write_text(yaml.safe_dump(data))
    launched = prepare(load_deployment(deployment), tmp_path / "run", say=lambda s: None).params

    def node(kind, params):
        return kind(parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])

    alone = {"config_file": str(deployment)}  # as docs/HARDWARE.md starts them
    gates = [node(VelocityGateNode, alone), node(VelocityGateNode, launched["velocity_gate"])]
    streams = [node(CameraStreamNode, alone), node(CameraStreamNode, launched["camera_stream"])]
    try:
        assert gates[0].config == gates[1].config
        assert dataclasses.asdict(gates[0].config) == gate_keys  # the file's, not defaults
        assert streams[0].config == streams[1].config
        assert dataclasses.asdict(streams[0].config) == stream_keys
    finally:
        for n in (*gates, *streams):
            n.destroy_node()
