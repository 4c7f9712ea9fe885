"""The camera people node: ceiling-camera frames in, the person's cell and direction out.

Subscribes (names are parameters):
    ``/camera/image_raw`` sensor_msgs/Image (bgr8, rgb8, mono8, bgra8, rgba8).

Publishes:
    ``/perception/person`` vigil_interfaces/CameraPerson: :class:`CameraPersonState` per
        frame {status ("person" | "no person" | "unknown"), position, cell, direction,
        foot point, boxes (x, y, w, h, weight each), missed_frames, warning, people};
        also published by a watchdog as "unknown" when frames stop arriving.
    ``/perception/person_position`` geometry_msgs/PointStamped: the person's map
        position (frame ``map_frame``), only while a person is seen.
    with ``label_topics`` (off by default; the thesis's topics, the typed message
    carries the same): ``/perception/person_cell`` std_msgs/String: the cell number or
    "No person"; ``/perception/person_direction`` std_msgs/String: "North" ... "Not moving".

Parameters: ``config_file`` (YAML with optional ``grid`` and ``camera`` sections),
``lockstep`` (see :mod:`stack.ros_lockstep`), ``label_topics`` (false), ``calibration_file`` (see
:mod:`stack.perception.homography`; missing: every state is
"unknown" and a warning is logged), ``image_topic``, ``map_frame``,
``frame_timeout_s``, ``max_future_stamp_s`` (1.0) and ``max_past_stamp_s`` (0: no limit): a frame
stamped further from the node's clock is ignored and counted (:mod:`stack.stamp_guard`).

QoS: frames are subscribed reliable, keep-last 2 (:data:`stack.ros_qos.FRAME_QOS`, docs/SAFETY.md).
"""

from __future__ import annotations

import math

from geometry_msgs.msg import PointStamped
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import String
from vigil_interfaces.msg import CameraPerson

import stack.topics as topic
from stack.cells import ConfigError
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus
from stack.perception.config import load_config_file
from stack.perception.errors import BadFrameError, CalibrationError
from stack.perception.homography import load_calibration
from stack.perception.messages import image_from_msg, stamp_to_s
from stack.perception.observation import NO_PERSON
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node
from stack.ros_msgs import camera_to_msg
from stack.ros_params import declare
from stack.ros_qos import FRAME_QOS
from stack.stamp_guard import StampGuard


class CameraPeopleNode(Node):
    """HOG people detection, floor position, cell and direction for each frame."""

    def __init__(self, **kwargs):
        super().__init__("camera_people", **kwargs)
        v = declare(
            self,
            config_file="",
            calibration_file="",
            image_topic=topic.CAMERA_IMAGE,
            map_frame="map",
            frame_timeout_s=2.0,
            lockstep=False,
            max_future_stamp_s=1.0,
            max_past_stamp_s=0.0,
            label_topics=False,
        )
        calibration_file = v.calibration_file
        self.map_frame = v.map_frame
        self.frame_timeout_s = v.frame_timeout_s
        if not self.frame_timeout_s > 0:
            raise ConfigError("frame_timeout_s", self.frame_timeout_s, "must be > 0")
        self.lockstep = Participant(self, v.lockstep)
        grid, sections = load_config_file(v.config_file)
        config = CameraConfig.from_dict(sections.get("camera"))
        homography = None
        try:
            homography = load_calibration(calibration_file).homography if calibration_file else None
        except CalibrationError as err:
            self.get_logger().error(f"{err}: person positions will be 'unknown'")
        if homography is None and not calibration_file:
            self.get_logger().error("no calibration_file: person positions will be 'unknown'")
        self.tracker = CameraPeopleTracker(config, grid, homography)
        ls = self.lockstep
        self.pub_state = ls.publisher(CameraPerson, topic.PERSON, 10)
        self.pub_position = ls.publisher(PointStamped, topic.PERSON_POSITION, 10)
        self.pub_cell = self.pub_direction = None
        if v.label_topics:
            self.pub_cell = ls.publisher(String, topic.PERSON_CELL, 10)
            self.pub_direction = ls.publisher(String, topic.PERSON_DIRECTION, 10)
        self.stamps = StampGuard(v.max_future_stamp_s, v.max_past_stamp_s)
        ls.subscription(Image, v.image_topic, self.on_image, FRAME_QOS)
        self._last_frame_s = self._now_s()
        ls.timer(self.frame_timeout_s / 2.0, self.on_watchdog)

    def _now_s(self) -> float:
        return self.lockstep.now_s()

    def on_image(self, msg: Image) -> None:
        now = self._now_s()
        stamp = stamp_to_s(msg.header.stamp)
        if stamp == 0.0:  # unstamped publisher: use the arrival time
            stamp = now
        bad = self.stamps.check(stamp, now)
        if bad:  # a frame from the future would make every later frame "out of order"
            self.get_logger().warning(
                self.stamps.describe("frame", stamp, now, bad), throttle_duration_sec=5.0
            )
            return
        self._last_frame_s = now
        try:
            image = image_from_msg(msg)
        except BadFrameError as err:
            image = None
            self.get_logger().warning(f"bad frame: {err}", throttle_duration_sec=5.0)
        state = self.tracker.process_frame(image, stamp)
        if state.warning:
            self.get_logger().warning(state.warning, throttle_duration_sec=5.0)
        self.publish(state, msg.header.stamp)

    def on_watchdog(self) -> None:
        silent_s = self._now_s() - self._last_frame_s
        if silent_s <= self.frame_timeout_s:
            return
        self.get_logger().warning(
            f"no camera frame for {silent_s:.1f} s", throttle_duration_sec=10.0
        )
        out = self.tracker.state.silent_dict(silent_s)
        self.pub_state.publish(camera_to_msg(out, self.map_frame))
        self.publish_labels(NO_PERSON, "Not moving")

    def publish_labels(self, cell: str, direction: str) -> None:
        if self.pub_cell is not None and self.pub_direction is not None:
            self.pub_cell.publish(String(data=cell))
            self.pub_direction.publish(String(data=direction))

    def publish(self, state, stamp_msg) -> None:
        self.pub_state.publish(camera_to_msg(self.tracker.message(state), self.map_frame))
        seen = state.status is PersonStatus.PERSON and state.position_m is not None
        self.publish_labels(
            str(state.cell) if seen and state.cell else NO_PERSON, state.direction.label
        )
        if seen and all(math.isfinite(v) for v in state.position_m):
            pt = PointStamped()
            pt.header.stamp = stamp_msg
            pt.header.frame_id = self.map_frame
            pt.point.x, pt.point.y = state.position_m
            self.pub_position.publish(pt)


def main(args=None) -> None:
    spin_node(CameraPeopleNode, args)


if __name__ == "__main__":
    main()
