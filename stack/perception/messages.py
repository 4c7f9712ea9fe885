"""Conversions between ROS message objects and the perception library's types.

No rclpy import: the functions read message attributes only, so they are tested
with message objects built in-process (or any object with the same fields), with
no ROS graph. Malformed messages raise the library's errors (BadFrameError,
BadScanError, ValueError) for the node to log.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from stack.cells import Direction
from stack.geometry import yaw_from_quaternion
from stack.perception.camera import CameraPersonState, PersonStatus
from stack.perception.errors import BadFrameError
from stack.perception.legs import LegDetections, Pose2D, Scan, StaticMap
from stack.perception.observation import speed_class
from stack.perception.tracker import TrackEstimate

# encoding -> (channels, conversion to BGR or grey)
_ENCODINGS = {"bgr8": 3, "rgb8": 3, "mono8": 1, "bgra8": 4, "rgba8": 4}


def stamp_to_s(stamp: Any) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def image_from_msg(msg: Any) -> np.ndarray:
    """sensor_msgs/Image -> BGR (H, W, 3) or grey (H, W) uint8 array (a copy).

    Raises:
        BadFrameError: unsupported encoding, or a data size that does not match
            height, width and step.
    """
    enc = str(msg.encoding).lower()
    if enc not in _ENCODINGS:
        raise BadFrameError(
            f"unsupported image encoding {msg.encoding!r} (use {sorted(_ENCODINGS)})"
        )
    ch = _ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h == 0 or w == 0:
        raise BadFrameError(f"image is empty ({w} x {h})")
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if step < w * ch or data.size != h * step:
        raise BadFrameError(
            f"image data has {data.size} bytes, expected {h} rows x step {step} (>= {w * ch})"
        )
    img = data.reshape(h, step)[:, : w * ch].reshape(h, w, ch)
    if enc == "mono8":
        return img[:, :, 0].copy()
    if enc == "rgb8":
        return img[:, :, ::-1].copy()
    if enc == "rgba8":
        return img[:, :, 2::-1].copy()
    return img[:, :, :3].copy()


def scan_from_msg(msg: Any) -> Scan:
    """sensor_msgs/LaserScan -> Scan (raises BadScanError when malformed)."""
    return Scan(
        ranges_m=np.asarray(msg.ranges, dtype=float),
        angle_min_rad=float(msg.angle_min),
        angle_increment_rad=float(msg.angle_increment),
        range_min_m=float(msg.range_min),
        range_max_m=float(msg.range_max),
        stamp_s=stamp_to_s(msg.header.stamp),
    )


def pose_from_msg(pose: Any) -> Pose2D:
    """geometry_msgs/Pose -> Pose2D (raises ValueError for non-finite values)."""
    p = Pose2D(
        float(pose.position.x), float(pose.position.y), yaw_from_quaternion(pose.orientation)
    )
    if not all(math.isfinite(v) for v in (p.x_m, p.y_m, p.yaw_rad)):
        raise ValueError(f"pose is not finite: {p}")
    return p


def static_map_from_msg(msg: Any) -> StaticMap:
    """nav_msgs/OccupancyGrid -> StaticMap (map origin rotation is assumed 0)."""
    info = msg.info
    if abs(yaw_from_quaternion(info.origin.orientation)) > 1e-6:
        raise ValueError("occupancy grids with a rotated origin are not supported")
    return StaticMap.from_occupancy(
        np.asarray(msg.data, dtype=np.int16),
        int(info.width),
        int(info.height),
        float(info.resolution),
        (float(info.origin.position.x), float(info.origin.position.y)),
    )


def legs_to_dict(
    detections: LegDetections, tracks: tuple[TrackEstimate, ...], thresholds=(0.2, 0.7)
) -> dict[str, Any]:
    """JSON-ready summary of one scan: legs, people and tracks (with speed classes)."""
    stamp = detections.stamp_s
    return {
        "stamp_s": stamp,
        "valid_beams": detections.valid_beams,
        "segments": detections.segments,
        "on_obstacles": detections.on_obstacles,
        "legs": [[round(c, 3) for c in leg.center_m] for leg in detections.legs],
        "people": [[round(c, 3) for c in p.position_m] for p in detections.people],
        "tracks": [
            {
                "id": t.track_id,
                "position_m": [round(v, 3) for v in t.position_m],
                "velocity_mps": [round(v, 3) for v in t.velocity_mps],
                "speed_mps": round(t.speed_mps, 3),
                "speed_class": speed_class(t.speed_mps, thresholds).label,
                "hits": t.hits,
                "age_s": round(stamp - t.last_update_s, 3),
                "confirmed": t.confirmed,
            }
            for t in tracks
        ],
    }


def tracks_from_dict(data: dict[str, Any], now_s: float) -> tuple[TrackEstimate, ...]:
    """Tracks from :func:`legs_to_dict`'s JSON, re-timed to the receiver's clock.

    Args:
        data: the decoded JSON.
        now_s: the receiver's time at reception [s]; each track's last update is
            placed ``age_s`` before it, so publisher and receiver clocks need not agree.

    Raises:
        ValueError: missing or malformed fields.
    """
    try:
        return tuple(
            TrackEstimate(
                track_id=int(t["id"]),
                position_m=(float(t["position_m"][0]), float(t["position_m"][1])),
                velocity_mps=(float(t["velocity_mps"][0]), float(t["velocity_mps"][1])),
                speed_mps=float(t["speed_mps"]),
                hits=int(t["hits"]),
                last_update_s=now_s - float(t["age_s"]),
                confirmed=bool(t["confirmed"]),
            )
            for t in data["tracks"]
        )
    except (KeyError, TypeError, IndexError, OverflowError) as err:
        raise ValueError(f"malformed legs message: {err!r}") from err


def camera_state_from_json(text: str, now_s: float) -> CameraPersonState:
    """A camera state from :meth:`CameraPersonState.to_dict` JSON, stamped ``now_s``.

    Raises:
        ValueError: malformed JSON or fields.
    """
    try:
        d = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as err:
        raise ValueError(f"malformed person message: {err!r}") from err
    return camera_state_from_dict(d, now_s)


def camera_state_from_dict(d: Any, now_s: float) -> CameraPersonState:
    """A camera state from a :meth:`CameraPersonState.to_dict` record, stamped ``now_s``.

    Raises:
        ValueError: malformed fields.
    """
    try:
        status = PersonStatus(d["status"])
        directions = {x.label: x for x in Direction}
        pos = d.get("position_m")
        return CameraPersonState(
            stamp_s=now_s,
            status=status,
            position_m=None if pos is None else (float(pos[0]), float(pos[1])),
            cell=None if d.get("cell") is None else int(d["cell"]),
            direction=directions[d.get("direction", "Not moving")],
            missed_frames=int(d.get("missed_frames", 0)),
            warning=d.get("warning"),
            people_m=tuple((float(q[0]), float(q[1])) for q in d.get("people_m") or ()),
        )
    except (
        json.JSONDecodeError,
        KeyError,
        TypeError,
        IndexError,
        ValueError,
        OverflowError,
    ) as err:
        raise ValueError(f"malformed person message: {err!r}") from err
