"""The camera stream node: the real ceiling camera's frames as ``sensor_msgs/Image``.

On the robot (no twin) this node stands in for the twin's camera: it reads the AXIS
P1344 stream (RTSP or HTTP MJPEG, see :mod:`stack.hardware.camera_stream`) on a timer
and publishes what the perception nodes subscribe to. While the stream is down it
publishes no image (downstream perception reports "unknown" / "No person" by its own
watchdog) and keeps retrying; it never exits on stream trouble.

Publishes (names are parameters):
    ``/camera/image_raw`` sensor_msgs/Image, rgb8, stamped with the node clock at the read,
        ``frame_id`` from the parameter.
    ``/camera/camera_info`` sensor_msgs/CameraInfo with the same header, only when
        ``camera_info_file`` is given (K and P scaled when the images have another size
        than the calibration).
    ``/diagnostics`` diagnostic_msgs/DiagnosticArray: status ``camera_stream`` (level
        OK while streaming, ERROR otherwise; message; values ok, kind, frames, url: the URL
        without credentials); on every change and once a second.

Parameters: ``config_file`` (YAML with a ``camera_stream:`` section, keys as
:class:`StreamConfig`: the deployment file's ``hardware.camera_stream``, or a file with
the section at its top); each key of that section is also a parameter (``url``,
``rate_hz``, ``width_px``, ``height_px``, ``reconnect_s``, ``frozen_after_frames``,
``open_timeout_s``) whose value overrides the file's; ``frame_id``
(``camera_optical_frame``, the optical frame of :mod:`stack.tf`), ``camera_info_file``,
``image_topic``, ``info_topic``, ``diagnostics_topic``.
"""

from __future__ import annotations

import dataclasses

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image

import stack.topics as topic
from stack import tf
from stack.cells import ConfigError
from stack.config import read_section
from stack.hardware.camera_stream import (
    CameraCalibration,
    CameraStream,
    StreamConfig,
    StreamFrame,
    load_calibration,
    redact_url,
)
from stack.ros_main import Releasing, spin_node
from stack.ros_msgs import diagnostics_to_msg
from stack.ros_params import declare, declare_topics
from stack.ros_qos import FRAME_QOS  # one QoS for frames, both ends

STATUS_PERIOD_S = 1.0


class CameraStreamNode(Releasing, Node):
    """Reads the stream at ``rate_hz`` and publishes images, camera info and status."""

    def __init__(self, capture_factory=None, **kwargs):
        super().__init__("camera_stream", **kwargs)
        p = self.declare_parameter
        v = declare(self, config_file="", frame_id=tf.CAMERA_OPTICAL, camera_info_file="")
        section = read_section(v.config_file, "camera_stream", parent="hardware")
        # the file's values, checked, are the parameters' defaults (the url may be given
        # as a parameter only); the parameters are checked again
        url = section.get("url", "")
        if not isinstance(url, str):
            raise ConfigError("camera_stream.url", url, "must be a string")
        start = StreamConfig.from_dict({**section, "url": url or "-"}, "camera_stream")
        values = {
            f.name: p(f.name, url if f.name == "url" else getattr(start, f.name)).value
            for f in dataclasses.fields(StreamConfig)
        }
        self.config = StreamConfig.from_dict(values, "camera_stream")
        self.frame_id, info_file = v.frame_id, v.camera_info_file
        topics = declare_topics(
            self, image=topic.CAMERA_IMAGE, info=topic.CAMERA_INFO, diagnostics=topic.DIAGNOSTICS
        )
        image_topic, info_topic, status_topic = (
            topics["image"],
            topics["info"],
            topics["diagnostics"],
        )

        self.calibration: CameraCalibration | None = (
            load_calibration(info_file) if info_file else None
        )
        self._scaled: CameraCalibration | None = None
        extra = {} if capture_factory is None else {"capture_factory": capture_factory}
        self.stream = CameraStream(self.config, **extra)
        self.url = redact_url(self.config.url)

        self.image_pub = self.create_publisher(Image, image_topic, FRAME_QOS)
        self.info_pub = self.create_publisher(CameraInfo, info_topic, 10) if info_file else None
        self.status_pub = self.create_publisher(DiagnosticArray, status_topic, 10)
        self._last_status: tuple | None = None
        self._last_status_s = -1e9
        self.timer = self.create_timer(1.0 / self.config.rate_hz, self.on_timer)
        self.get_logger().info(
            f"camera_stream: {self.url} at {self.config.rate_hz:g} Hz on {image_topic}"
            + (f", calibration {info_file}" if info_file else "")
        )

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_timer(self) -> None:
        was_down = self.stream.problem is not None or self.stream.frames == 0
        result = self.stream.read()
        if isinstance(result, StreamFrame):
            if was_down:
                h, w = result.rgb.shape[:2]
                self.get_logger().info(f"streaming {w}x{h} from {self.url}")
            self.publish_frame(result)
            self.publish_status(True, "streaming", f"streaming from {self.url}")
        else:
            self.get_logger().warning(result.message, throttle_duration_sec=5.0)
            self.publish_status(False, result.kind, result.message)

    def publish_frame(self, frame: StreamFrame) -> None:
        rgb = frame.rgb
        h, w = rgb.shape[:2]
        msg = Image()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = self.frame_id
        msg.height, msg.width = h, w
        msg.encoding = "rgb8"
        msg.is_bigendian = 0
        msg.step = w * 3
        msg.data = rgb.tobytes()
        self.image_pub.publish(msg)
        if self.info_pub is not None and self.calibration is not None:
            cal = self._scaled
            if cal is None or (cal.width, cal.height) != (w, h):
                cal = self._scaled = self.calibration.scaled(w, h)
                if (w, h) != (self.calibration.width, self.calibration.height):
                    self.get_logger().info(
                        f"calibration is for {self.calibration.width}x{self.calibration.height}, "
                        f"images are {w}x{h}: K and P scaled"
                    )
            info = CameraInfo()
            info.header = msg.header
            info.width, info.height = w, h
            info.distortion_model = cal.distortion_model
            info.d = list(cal.D)
            info.k, info.r, info.p = list(cal.K), list(cal.R), list(cal.P)
            self.info_pub.publish(info)

    def publish_status(self, ok: bool, kind: str, message: str) -> None:
        now = self.now_s()
        key = (ok, kind, message)
        if key == self._last_status and now - self._last_status_s < STATUS_PERIOD_S:
            return
        self._last_status, self._last_status_s = key, now
        values = {"ok": ok, "kind": kind, "frames": self.stream.frames, "url": self.url}
        level = "ok" if ok else "error"
        stamp = self.get_clock().now().to_msg()
        self.status_pub.publish(
            diagnostics_to_msg(self.get_name(), self.url, level, message, values, stamp)
        )

    def _release(self) -> None:
        """The camera stream, closed once (:class:`stack.ros_main.Releasing`)."""
        self.stream.close()


def main(args=None) -> None:
    spin_node(CameraStreamNode, args)


if __name__ == "__main__":
    main()
