"""ROS 2 bridge: the twin publishes what the robot's drivers and the camera would.

Publishes ``/camera/image_raw`` (sensor_msgs/Image, rgb8), ``/camera/camera_info``,
``/scan`` (sensor_msgs/LaserScan), ``/odom`` (nav_msgs/Odometry), ``/map``
(nav_msgs/OccupancyGrid, transient local), ``/clock`` (simulated time) and ground truth
under ``/twin/...``; subscribes to ``/cmd_vel`` (geometry_msgs/Twist) and stops the base
when commands are older than ``cmd_timeout_s`` of simulated time.

Time: one wall-clock timer steps the twin by one control period per tick. With
``realtime`` true the timer runs at the control rate; otherwise it runs as fast as the
executor allows (free-running). The lock-step handshake of issue 3 (advance only when
the stack has consumed the last sensor data) is not implemented yet.
"""

from __future__ import annotations

import math

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import OccupancyGrid
from nav_msgs.msg import Odometry as OdometryMsg
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo as CameraInfoMsg
from sensor_msgs.msg import Image, LaserScan
from std_msgs.msg import Int32

from twin.config import TwinConfig, load_twin_config
from twin.occupancy import OccupancyMap
from twin.sensors import CameraInfo
from twin.sensors import LaserScan as Scan
from twin.twin import GroundTruth, Odometry, Twin, VelocityCommand


def stamp_of(t_s: float) -> Time:
    """builtin_interfaces/Time of a simulation time [s]."""
    sec = int(math.floor(t_s))
    return Time(sec=sec, nanosec=int(round((t_s - sec) * 1e9)) % 1_000_000_000)


def _quat_z(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))  # x, y, z, w


def image_msg(rgb: np.ndarray, t_s: float, frame_id: str) -> Image:
    """sensor_msgs/Image (rgb8) of an (H, W, 3) uint8 array."""
    msg = Image()
    msg.header.stamp, msg.header.frame_id = stamp_of(t_s), frame_id
    msg.height, msg.width = int(rgb.shape[0]), int(rgb.shape[1])
    msg.encoding, msg.is_bigendian, msg.step = "rgb8", 0, int(rgb.shape[1] * 3)
    msg.data = np.ascontiguousarray(rgb, np.uint8).tobytes()
    return msg


def camera_info_msg(info: CameraInfo, t_s: float) -> CameraInfoMsg:
    """sensor_msgs/CameraInfo of the twin's intrinsics record."""
    msg = CameraInfoMsg()
    msg.header.stamp, msg.header.frame_id = stamp_of(t_s), info.frame_id
    msg.width, msg.height = info.width, info.height
    msg.distortion_model = info.distortion_model
    msg.d = [float(v) for v in info.D]
    msg.k = [float(v) for v in info.K.ravel()]
    msg.r = [float(v) for v in info.R.ravel()]
    msg.p = [float(v) for v in info.P.ravel()]
    return msg


def scan_msg(scan: Scan) -> LaserScan:
    """sensor_msgs/LaserScan of a twin scan."""
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = stamp_of(scan.time_s), scan.frame_id
    msg.angle_min, msg.angle_max = scan.angle_min_rad, scan.angle_max_rad
    msg.angle_increment = scan.angle_increment_rad
    msg.range_min, msg.range_max = scan.range_min_m, scan.range_max_m
    msg.ranges = scan.ranges_m.astype(np.float32).tolist()
    return msg


def odometry_msg(odom: Odometry) -> OdometryMsg:
    """nav_msgs/Odometry (frame odom, child base_link) of the twin's odometry."""
    msg = OdometryMsg()
    msg.header.stamp, msg.header.frame_id = stamp_of(odom.time_s), "odom"
    msg.child_frame_id = "base_link"
    p = msg.pose.pose
    p.position.x, p.position.y = odom.pose.x_m, odom.pose.y_m
    q = _quat_z(odom.pose.yaw_rad)
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = q
    msg.twist.twist.linear.x, msg.twist.twist.linear.y = odom.vx_mps, odom.vy_mps
    msg.twist.twist.angular.z = odom.wz_radps
    return msg


def map_msg(grid: OccupancyMap, t_s: float) -> OccupancyGrid:
    """nav_msgs/OccupancyGrid (frame map) of the twin's map."""
    msg = OccupancyGrid()
    msg.header.stamp, msg.header.frame_id = stamp_of(t_s), "map"
    msg.info.resolution = float(grid.resolution_m)
    msg.info.height, msg.info.width = int(grid.shape[0]), int(grid.shape[1])
    msg.info.origin.position.x, msg.info.origin.position.y = map(float, grid.origin_m)
    msg.info.origin.orientation.w = 1.0
    msg.data = grid.data.ravel().astype(int).tolist()
    return msg


def pose_msg(x: float, y: float, yaw: float, t_s: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp, msg.header.frame_id = stamp_of(t_s), "map"
    msg.pose.position.x, msg.pose.position.y = float(x), float(y)
    q = _quat_z(yaw)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = q
    return msg


class TwinBridge(Node):
    """Steps a :class:`Twin` on a timer and converts between it and ROS messages.

    Parameters: ``config`` (twin YAML, "" for defaults), ``task`` (task YAML with the
    grid, "" for none), ``seed``, ``realtime``, ``cmd_timeout_s``.
    """

    def __init__(self, twin: Twin | None = None, **kwargs):
        super().__init__("twin_bridge", **kwargs)
        self.declare_parameter("config", "")
        self.declare_parameter("task", "")
        self.declare_parameter("seed", 0)
        self.declare_parameter("realtime", False)
        self.declare_parameter("cmd_timeout_s", 0.5)
        if twin is None:
            path = self.get_parameter("config").value
            task = self.get_parameter("task").value or None
            cfg = load_twin_config(path, task) if path else TwinConfig()
            twin = Twin(cfg, seed=int(self.get_parameter("seed").value))
        self.twin = twin
        self.cmd_timeout_s = float(self.get_parameter("cmd_timeout_s").value)
        cfg = twin.config
        self._cmd = VelocityCommand()
        self._cmd_time_s = -math.inf
        self._next_camera_s = 0.0
        self._next_scan_s = 0.0
        self._camera_period_s = 1.0 / cfg.camera.rate_hz
        self._scan_period_s = 1.0 / cfg.lidar.rate_hz

        latched = QoSProfile(
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self.pub_image = self.create_publisher(Image, "/camera/image_raw", 2)
        self.pub_info = self.create_publisher(CameraInfoMsg, "/camera/camera_info", 2)
        self.pub_scan = self.create_publisher(LaserScan, "/scan", 5)
        self.pub_odom = self.create_publisher(OdometryMsg, "/odom", 10)
        self.pub_map = self.create_publisher(OccupancyGrid, "/map", latched)
        self.pub_clock = self.create_publisher(Clock, "/clock", 10)
        self.pub_robot = self.create_publisher(PoseStamped, "/twin/robot_pose", 10)
        self.pub_person = self.create_publisher(PoseStamped, "/twin/person_pose", 10)
        self.pub_person_vel = self.create_publisher(TwistStamped, "/twin/person_velocity", 10)
        self.pub_person_cell = self.create_publisher(Int32, "/twin/person_cell", 10)
        self.pub_robot_cell = self.create_publisher(Int32, "/twin/robot_cell", 10)
        self.create_subscription(Twist, "/cmd_vel", self._on_cmd_vel, 10)
        self.pub_map.publish(map_msg(twin.occupancy_map(), twin.time_s))
        period = cfg.control_period_s if self.get_parameter("realtime").value else 0.001
        self.timer = self.create_timer(period, self._tick)

    def _on_cmd_vel(self, msg: Twist) -> None:
        self._cmd = VelocityCommand(msg.linear.x, msg.linear.y, msg.angular.z)
        self._cmd_time_s = self.twin.time_s

    def _tick(self) -> None:
        tw = self.twin
        stale = tw.time_s - self._cmd_time_s > self.cmd_timeout_s
        tw.step(None if stale else self._cmd)
        t = tw.time_s
        self.pub_clock.publish(Clock(clock=stamp_of(t)))
        self.pub_odom.publish(odometry_msg(tw.odometry()))
        self._publish_truth(tw.ground_truth())
        if t + 1e-9 >= self._next_scan_s:
            self._next_scan_s += self._scan_period_s
            self.pub_scan.publish(scan_msg(tw.scan()))
        if t + 1e-9 >= self._next_camera_s:
            self._next_camera_s += self._camera_period_s
            self.pub_image.publish(image_msg(tw.render_camera(), t, tw.camera_info.frame_id))
            self.pub_info.publish(camera_info_msg(tw.camera_info, t))

    def _publish_truth(self, gt: GroundTruth) -> None:
        t = gt.time_s
        self.pub_robot.publish(pose_msg(gt.robot.x_m, gt.robot.y_m, gt.robot.yaw_rad, t))
        self.pub_robot_cell.publish(Int32(data=gt.robot_cell or -1))
        if gt.person is not None:
            p = gt.person
            self.pub_person.publish(pose_msg(p.pose.x_m, p.pose.y_m, p.pose.yaw_rad, t))
            vel = TwistStamped()
            vel.header.stamp, vel.header.frame_id = stamp_of(t), "map"
            vel.twist.linear.x, vel.twist.linear.y = map(float, p.velocity_mps)
            self.pub_person_vel.publish(vel)
            # -1: outside the region (or the room)
            self.pub_person_cell.publish(Int32(data=p.cell if p.cell is not None else -1))

    def destroy_node(self) -> None:
        self.twin.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run the bridge until interrupted."""
    rclpy.init(args=args)
    node = TwinBridge()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
