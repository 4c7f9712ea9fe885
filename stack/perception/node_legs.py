"""The legs node: laser scans and the robot's pose in, tracked people and speeds out.

Subscribes (names are parameters):
    ``/scan`` sensor_msgs/LaserScan.
    ``/odom`` nav_msgs/Odometry: the robot's pose in the map frame (the twin's odom
        frame is the map frame); scans are transformed with the latest pose. With
        ``pose_source: tf`` instead ``/tf`` and ``/tf_static``: the pose is looked up as
        ``map <- laser_frame`` (on a robot, where odometry drifts from the map; the laser's
        mount then comes from TF's ``base_link -> laser_frame``, and the ``laser_*``
        parameters are not used).
    ``/map`` nav_msgs/OccupancyGrid (transient local): segments on its obstacles
        (chair and table legs) are ignored.

Publishes:
    ``/perception/legs`` vigil_interfaces/LegTracks: {valid_beams, segments,
        on_obstacles, legs, people, tracks [{id, position, velocity, speed_mps,
        speed_class, hits, age_s, confirmed}]} per scan (frame ``map_frame``).
    ``/perception/leg_people`` geometry_msgs/PoseArray: confirmed tracks' positions
        (frame ``map_frame``), e.g. for navigation's person avoidance.

Parameters: ``config_file`` (YAML with optional ``legs``, ``tracker`` and
``observations`` sections), ``scan_topic``, ``odom_topic``, ``map_topic``,
``map_frame``, ``lockstep`` (see :mod:`stack.ros_lockstep`), ``laser_x_m``,
``laser_y_m``, ``laser_yaw_rad`` (the laser's mount on the
robot, with ``pose_source: odom``), ``laser_frame`` (``laser``: the scan's frame in TF),
``pose_source`` (odom | tf), ``tf_timeout_s`` (1.0: how long the TF chain may be
missing before a warning), ``max_pose_age_s`` (older poses make the scan unusable),
``max_future_stamp_s`` (1.0) and ``max_past_stamp_s`` (0: no limit): a scan or odometry
message stamped further from the node's clock is ignored and counted
(:mod:`stack.stamp_guard`).
"""

from __future__ import annotations

from geometry_msgs.msg import Pose, PoseArray
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import LaserScan
from vigil_interfaces.msg import LegTracks

import stack.topics as topic
from stack import tf
from stack.cells import ConfigError
from stack.perception.config import load_config_file
from stack.perception.errors import BadScanError
from stack.perception.legs import LegConfig, Pose2D, detect_legs
from stack.perception.messages import (
    legs_to_dict,
    pose_from_msg,
    scan_from_msg,
    stamp_to_s,
    static_map_from_msg,
)
from stack.perception.observation import CombinerConfig
from stack.perception.scan_pose import MAX_POSE_AGE_S, ScanPosePairing
from stack.perception.tracker import LegTracker, TrackerConfig
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node
from stack.ros_msgs import legs_to_msg
from stack.ros_params import declare, declare_topics
from stack.ros_tf import MapPose
from stack.stamp_guard import StampGuard


class LegsNode(Node):
    """Leg detection and constant-velocity tracking in the map frame."""

    def __init__(self, **kwargs):
        super().__init__("legs", **kwargs)
        v = declare(
            self,
            config_file="",
            map_frame="map",
            pose_source="odom",
            tf_timeout_s=1.0,
            laser_frame=tf.LASER,
            laser_x_m=0.0,
            laser_y_m=0.0,
            laser_yaw_rad=0.0,
            max_pose_age_s=MAX_POSE_AGE_S,
            max_future_stamp_s=1.0,
            max_past_stamp_s=0.0,
            lockstep=False,
        )
        topics = declare_topics(self, scan=topic.SCAN, odom=topic.ODOM, map=topic.MAP)
        if v.pose_source not in ("odom", "tf"):
            raise ConfigError("pose_source", v.pose_source, "must be odom or tf")
        self.map_frame = v.map_frame
        self.laser_mount = Pose2D(v.laser_x_m, v.laser_y_m, v.laser_yaw_rad)
        self.max_pose_age_s = v.max_pose_age_s
        _, sections = load_config_file(v.config_file)
        self.leg_config = LegConfig.from_dict(sections.get("legs"))
        self.thresholds = CombinerConfig.from_dict(
            sections.get("observations")
        ).speed_thresholds_mps
        self.tracker = LegTracker(TrackerConfig.from_dict(sections.get("tracker")))
        self.static_map = None
        self.pairing: ScanPosePairing[LaserScan] = ScanPosePairing(v.max_pose_age_s)
        self.stamps = StampGuard(v.max_future_stamp_s, v.max_past_stamp_s)
        ls = self.lockstep = Participant(self, v.lockstep)
        self.pub_legs = ls.publisher(LegTracks, topic.LEGS, 10)
        self.pub_people = ls.publisher(PoseArray, topic.LEG_PEOPLE, 10)
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        ls.subscription(OccupancyGrid, topics["map"], self.on_map, latched)
        if v.pose_source == "tf":
            # the laser's own pose: TF holds its mount (base_link -> laser) on any robot
            self.laser_mount = Pose2D(0.0, 0.0, 0.0)
            self.map_pose = MapPose(
                ls, self.on_map_pose, v.tf_timeout_s, self.map_frame, v.laser_frame
            )
        else:
            ls.subscription(Odometry, topics["odom"], self.on_odom, 20)
        ls.subscription(LaserScan, topics["scan"], self.on_scan, qos_profile_sensor_data)

    @property
    def pose(self) -> Pose2D | None:
        """The robot's latest pose (the one scans are read with)."""
        return self.pairing.pose

    def on_map(self, msg: OccupancyGrid) -> None:
        try:
            self.static_map = static_map_from_msg(msg)
        except (ValueError, TypeError) as err:
            self.get_logger().warning(f"map ignored: {err}")

    def _stamp_ok(self, what: str, stamp: float) -> bool:
        now = self.lockstep.now_s()
        bad = self.stamps.check(stamp, now)
        if bad:  # one message from the future would hold back every later one
            self.get_logger().warning(
                self.stamps.describe(what, stamp, now, bad), throttle_duration_sec=5.0
            )
        return bad is None

    def on_odom(self, msg: Odometry) -> None:
        if not self._stamp_ok("odometry", stamp_to_s(msg.header.stamp)):
            return
        try:
            pose = pose_from_msg(msg.pose.pose)
        except ValueError as err:
            self.get_logger().warning(f"pose ignored: {err}", throttle_duration_sec=5.0)
            return
        for scan in self.pairing.on_pose(stamp_to_s(msg.header.stamp), pose):
            self.process_scan(scan)

    def on_map_pose(self, stamp_s: float, pose: Pose2D) -> None:
        """The map pose through TF (``pose_source: tf``), used as :meth:`on_odom`'s."""
        if not self._stamp_ok("map pose", stamp_s):
            return
        for scan in self.pairing.on_pose(stamp_s, pose):
            self.process_scan(scan)

    def on_scan(self, msg: LaserScan) -> None:
        """Read with the pose of the scan's instant (:class:`ScanPosePairing`)."""
        stamp = stamp_to_s(msg.header.stamp)
        if not self._stamp_ok("scan", stamp):
            return
        for scan in self.pairing.on_scan(stamp, msg):
            self.process_scan(scan)

    def process_scan(self, msg: LaserScan) -> None:
        log = self.get_logger()
        try:
            scan = scan_from_msg(msg)
            laser_pose = self.pairing.laser_pose(scan.stamp_s, self.laser_mount)
            det = detect_legs(scan, self.leg_config, laser_pose, self.static_map)
            tracks = self.tracker.update(scan.stamp_s, det.people)
        except BadScanError as err:
            log.warning(f"scan ignored: {err}", throttle_duration_sec=5.0)
            return
        record = legs_to_dict(det, tracks, self.thresholds)
        self.pub_legs.publish(legs_to_msg(record, self.map_frame))
        people = PoseArray()
        people.header.stamp = msg.header.stamp
        people.header.frame_id = self.map_frame
        for t in tracks:
            if t.confirmed:
                pose = Pose()
                pose.position.x, pose.position.y = t.position_m
                pose.orientation.w = 1.0
                people.poses.append(pose)
        self.pub_people.publish(people)


def main(args=None) -> None:
    spin_node(LegsNode, args)


if __name__ == "__main__":
    main()
