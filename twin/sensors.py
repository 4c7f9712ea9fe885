"""Sensor records and synthesis: camera intrinsics and pose, the planar lidar.

The records mirror the ROS messages the bridge publishes (sensor_msgs/CameraInfo,
sensor_msgs/LaserScan) without importing rclpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from twin.config import CameraConfig, LidarConfig

# optical frame (x right, y down, z forward) from MuJoCo's camera frame (x right, y up, z back)
OPTICAL_FROM_MUJOCO_CAMERA = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class CameraInfo:
    """Pinhole intrinsics in sensor_msgs/CameraInfo form (plumb_bob, no distortion).

    Attributes:
        width, height: image size [px].
        K: 3x3 intrinsic matrix; pixel centres at integer coordinates (OpenCV).
        D: the 5 plumb_bob distortion coefficients (all zero: MuJoCo renders a pinhole).
        R: 3x3 rectification (identity).
        P: 3x4 projection matrix [K | 0].
        frame_id: the optical frame's name.
    """

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray
    distortion_model: str = "plumb_bob"
    frame_id: str = "camera_optical_frame"  # REP-103 optical frame (stack.tf)

    @property
    def fovy_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.height / (2.0 * self.K[1, 1])))

    @property
    def fovx_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width / (2.0 * self.K[0, 0])))


@dataclass(frozen=True)
class CameraPose:
    """The camera's pose in the map frame.

    Attributes:
        position_m: optical centre [m].
        rotation: 3x3, map from optical frame (x right, y down, z forward); a map point p
            is at ``rotation.T @ (p - position_m)`` in the optical frame.
    """

    position_m: np.ndarray
    rotation: np.ndarray


def camera_info_of(config: CameraConfig) -> CameraInfo:
    """Intrinsics of MuJoCo's camera: square pixels, principal point at the image centre.

    MuJoCo maps the vertical field of view exactly onto the image height, so
    fy = (height / 2) / tan(fovy / 2) and fx = fy. In OpenCV's convention (pixel centres
    at integers) the image centre is ((width - 1) / 2, (height - 1) / 2).

    Args:
        config: the camera's configuration.

    Returns:
        The intrinsics record.
    """
    w, h = config.width_px, config.height_px
    f = (h / 2.0) / math.tan(math.radians(config.fovy_deg) / 2.0)
    k = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    p = np.hstack([k, np.zeros((3, 1))])
    return CameraInfo(w, h, k, np.zeros(5), np.eye(3), p)


def project(info: CameraInfo, pose: CameraPose, points_m: np.ndarray) -> np.ndarray:
    """Project map points into the image.

    Args:
        info: intrinsics.
        pose: camera pose.
        points_m: (N, 3) map points [m].

    Returns:
        (N, 2) pixel coordinates (u right, v down); NaN for points behind the camera.
    """
    pts = np.atleast_2d(points_m).astype(float)
    cam = (pts - pose.position_m) @ pose.rotation
    uv = np.full((len(pts), 2), np.nan)
    ahead = cam[:, 2] > 1e-9
    proj = cam[ahead] @ info.K.T
    uv[ahead] = proj[:, :2] / proj[:, 2:3]
    return uv


@dataclass(frozen=True)
class LaserScan:
    """One planar scan, as sensor_msgs/LaserScan.

    Attributes:
        time_s: simulation time of the scan [s].
        ranges_m: (beams,) float32 ranges [m]; +inf where nothing was hit within
            range_max_m, -inf where the hit is closer than range_min_m (REP 117).
        angles_rad: (beams,) beam angles in the lidar frame (0 = robot forward, CCW).
        angle_min_rad, angle_max_rad, angle_increment_rad: as in LaserScan.
        range_min_m, range_max_m: the limits.
        geom_ids: (beams,) the MuJoCo geom each beam hit (-1: none) - ground truth for tests.
        frame_id: the lidar frame's name.
    """

    time_s: float
    ranges_m: np.ndarray
    angles_rad: np.ndarray
    angle_min_rad: float
    angle_max_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    geom_ids: np.ndarray
    frame_id: str = "laser"

    def points_m(self) -> np.ndarray:
        """(N, 2) Cartesian points of the finite returns in the lidar frame [m]."""
        ok = np.isfinite(self.ranges_m)
        r, a = self.ranges_m[ok], self.angles_rad[ok]
        return np.column_stack([r * np.cos(a), r * np.sin(a)])


class Lidar:
    """A planar scanner simulated with one ``mujoco.mj_multiRay`` call per scan.

    Args:
        config: the lidar's configuration.
        exclude_body: id of the body whose geoms the rays ignore (the robot).
    """

    def __init__(self, config: LidarConfig, exclude_body: int):
        self.config = config
        self.exclude_body = exclude_body
        fov = math.radians(config.fov_deg)
        n = config.beams
        # a full circle must not measure the same direction twice
        self.increment = fov / n if config.fov_deg >= 360.0 else fov / (n - 1)
        self.angles = (-fov / 2.0 + self.increment * np.arange(n)).astype(np.float64)
        self._dist = np.zeros(n)
        self._vec = np.zeros((n, 3))
        self._geomid = np.zeros(n, np.int32)

    def scan(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        origin_m: np.ndarray,
        yaw_rad: float,
        rng: np.random.Generator,
    ) -> LaserScan:
        """Cast all beams from ``origin_m`` in the horizontal plane.

        Args:
            model, data: the scene (kinematics up to date).
            origin_m: (3,) beam origin in the world [m].
            yaw_rad: lidar heading in the world [rad].
            rng: source of the range noise.

        Returns:
            The scan.
        """
        c = self.config
        world = self.angles + yaw_rad
        vec = self._vec  # (beams, 3) directions, z 0 (as np.column_stack made them)
        vec[:, 0] = np.cos(world)
        vec[:, 1] = np.sin(world)
        # flg_static=1: without it the walls and furniture are invisible to the rays
        mujoco.mj_multiRay(
            model,
            data,
            np.asarray(origin_m, np.float64),
            vec.ravel(),
            None,
            1,
            self.exclude_body,
            self._geomid,
            self._dist,
            None,
            c.beams,
            c.range_max_m,
        )
        ranges = self._dist.copy()
        hit = self._geomid >= 0
        if c.noise_std_m > 0:
            ranges[hit] += rng.normal(0.0, c.noise_std_m, int(hit.sum()))
        ranges[~hit | (ranges > c.range_max_m)] = np.inf
        ranges[hit & (ranges < c.range_min_m)] = -np.inf
        return LaserScan(
            time_s=float(data.time),
            ranges_m=ranges.astype(np.float32),
            angles_rad=self.angles.copy(),
            angle_min_rad=float(self.angles[0]),
            angle_max_rad=float(self.angles[-1]),
            angle_increment_rad=float(self.increment),
            range_min_m=c.range_min_m,
            range_max_m=c.range_max_m,
            geom_ids=self._geomid.copy(),
        )
