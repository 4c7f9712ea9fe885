"""The twin's sensors as ROS messages: each twin record as the message a robot's driver
sends (``sensor_msgs/Image``, ``CameraInfo``, ``LaserScan``, ``nav_msgs/Odometry``,
``OccupancyGrid``, ``PoseStamped``), stamped on the simulated time plus an offset (0 in
lock-step; the system clock at the start in real time), and the bridge's
``sensor_outages`` parameter. Used by :mod:`twin.bridge_node`."""

from __future__ import annotations

import json
import math

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import OccupancyGrid
from nav_msgs.msg import Odometry as OdometryMsg
from sensor_msgs.msg import CameraInfo as CameraInfoMsg
from sensor_msgs.msg import Image, LaserScan

from stack.cells import ConfigError
from stack.lockstep import stamp_parts
from twin.occupancy import OccupancyMap
from twin.sensors import CameraInfo
from twin.sensors import LaserScan as Scan
from twin.twin import Odometry


def stamp_of(t_s: float) -> Time:
    """builtin_interfaces/Time of a simulation time [s], rounded to the nanosecond.

    Rounded as a whole number of nanoseconds first, so that 2.9999999999 s is
    3.000000000 s (not 2 s with the nanoseconds wrapped to 0).
    """
    sec, nanosec = stamp_parts(t_s)
    return Time(sec=sec, nanosec=nanosec)


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


def scan_msg(scan: Scan, offset_s: float = 0.0) -> LaserScan:
    """sensor_msgs/LaserScan of a twin scan, stamped ``offset_s`` after its time."""
    msg = LaserScan()
    msg.header.stamp, msg.header.frame_id = stamp_of(scan.time_s + offset_s), scan.frame_id
    msg.angle_min, msg.angle_max = scan.angle_min_rad, scan.angle_max_rad
    msg.angle_increment = scan.angle_increment_rad
    msg.range_min, msg.range_max = scan.range_min_m, scan.range_max_m
    msg.ranges = scan.ranges_m.astype(np.float32).tolist()
    return msg


def odometry_msg(odom: Odometry, offset_s: float = 0.0) -> OdometryMsg:
    """nav_msgs/Odometry (frame odom, child base_link) of the twin's odometry, stamped
    ``offset_s`` after its time."""
    msg = OdometryMsg()
    msg.header.stamp, msg.header.frame_id = stamp_of(odom.time_s + offset_s), "odom"
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


def parse_outages(text: str) -> list[tuple[str, float, float]]:
    """Parse ``sensor_outages``: a JSON list of [sensor, t0_s, t1_s].

    Raises:
        ConfigError: not such a list, or an unknown sensor.
    """
    try:
        items = json.loads(text or "[]")
        out = [(str(s), float(t0), float(t1)) for s, t0, t1 in items]
    except (ValueError, TypeError) as err:
        raise ConfigError(
            "sensor_outages", text, f"must be [[sensor, t0, t1], ...]: {err}"
        ) from None
    for s, t0, t1 in out:
        if s not in ("camera", "lidar") or t1 < t0:
            raise ConfigError("sensor_outages", [s, t0, t1], "sensor camera|lidar, t1 >= t0")
    return out
