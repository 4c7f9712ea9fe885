"""The camera's pose in the map from its floor calibration, for the TF tree.

The calibration's homography maps image pixels to the floor (thesis eq. 4.4). Its
inverse maps floor points (X, Y, 1) to pixels and equals, up to scale, K [r1 r2 t]: the
intrinsics times the first two columns of the map-to-camera rotation and the
translation. With K from ``camera_info`` this gives the camera's full pose, which the
localisation stand-in publishes as the static ``map -> camera_link ->
camera_optical_frame`` (REP-103 optical frame: z forward, x right, y down).
"""

from __future__ import annotations

import math

import numpy as np

from stack.perception.errors import CalibrationError
from stack.tf import Transform, quaternion_from_matrix, quaternion_from_rpy

# camera_link (x forward, y left, z up) -> camera_optical_frame (z forward, x right, y down)
OPTICAL_IN_LINK = Transform((0.0, 0.0, 0.0), quaternion_from_rpy(-math.pi / 2, 0.0, -math.pi / 2))


def camera_pose_from_homography(
    image_to_map: np.ndarray, K: np.ndarray, floor_points_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The optical frame's position [m] and rotation (columns: its axes in the map).

    Args:
        image_to_map: the 3 x 3 homography, pixels -> floor metres.
        K: the 3 x 3 intrinsics of the same image size.
        floor_points_m: (N, 2) floor points in view (the calibration's), which fix the
            sign: they lie in front of the camera.

    Raises:
        CalibrationError: a matrix of the wrong shape or not finite, or points that do not
            lie on one side of the camera.
    """
    H = np.asarray(image_to_map, float)
    K = np.asarray(K, float)
    pts = np.atleast_2d(np.asarray(floor_points_m, float))
    if H.shape != (3, 3) or K.shape != (3, 3) or not np.all(np.isfinite(H) & np.isfinite(K)):
        raise CalibrationError("homography and K must be finite 3 x 3 matrices")
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
        raise CalibrationError(f"floor points must be (N, 2), got shape {pts.shape}")
    M = np.linalg.solve(K, np.linalg.inv(H))  # ~ [r1 r2 t]
    lam = 1.0 / math.sqrt(np.linalg.norm(M[:, 0]) * np.linalg.norm(M[:, 1]))
    depth = (lam * M @ np.c_[pts, np.ones(len(pts))].T)[2]
    if np.all(depth < 0):
        lam = -lam
    elif not np.all(depth > 0):
        raise CalibrationError("the floor points do not all lie in front of the camera")
    r1, r2, t = lam * M[:, 0], lam * M[:, 1], lam * M[:, 2]
    R = np.c_[r1, r2, np.cross(r1, r2)]
    u, _, vt = np.linalg.svd(R)  # the nearest rotation
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    rotation = R.T  # optical axes in the map
    position = -R.T @ t
    return position, rotation


def camera_transforms(
    image_to_map: np.ndarray, K: np.ndarray, floor_points_m: np.ndarray
) -> tuple[Transform, Transform]:
    """T_map_camera_link and T_camera_link_optical from the calibration (static TF)."""
    position, rotation = camera_pose_from_homography(image_to_map, K, floor_points_m)
    map_optical = Transform(tuple(position), quaternion_from_matrix(rotation))
    return map_optical.compose(OPTICAL_IN_LINK.inverse()), OPTICAL_IN_LINK
