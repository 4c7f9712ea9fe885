"""Message conversions, on message objects built in-process (no ROS graph)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

pytest.importorskip("sensor_msgs")
from nav_msgs.msg import OccupancyGrid  # noqa: E402
from sensor_msgs.msg import Image, LaserScan  # noqa: E402

from stack.cells import Direction  # noqa: E402
from stack.perception.camera import CameraPersonState, PersonStatus  # noqa: E402
from stack.perception.errors import BadFrameError, BadScanError  # noqa: E402
from stack.perception.legs import LegDetections  # noqa: E402
from stack.perception.messages import (  # noqa: E402
    camera_state_from_json,
    image_from_msg,
    legs_to_dict,
    scan_from_msg,
    static_map_from_msg,
    tracks_from_dict,
)
from stack.perception.tracker import TrackEstimate  # noqa: E402


def make_image(encoding, channels, width=4, height=3, pad=2):
    msg = Image()
    msg.height, msg.width, msg.encoding = height, width, encoding
    msg.step = width * channels + pad
    rows = [bytes(range(r * 10, r * 10 + width * channels)) + b"\0" * pad for r in range(height)]
    msg.data = b"".join(rows)
    return msg


def test_image_conversion_honours_encoding_and_step():
    rgb = image_from_msg(make_image("rgb8", 3))
    assert rgb.shape == (3, 4, 3) and rgb.dtype == np.uint8
    assert rgb[1, 0].tolist() == [12, 11, 10]  # RGB bytes 10, 11, 12 -> BGR
    mono = image_from_msg(make_image("mono8", 1))
    assert mono.shape == (3, 4) and mono[2, 3] == 23
    assert image_from_msg(make_image("bgra8", 4))[0, 1].tolist() == [4, 5, 6]
    with pytest.raises(BadFrameError, match="encoding"):
        image_from_msg(make_image("yuv422", 2))
    short = make_image("rgb8", 3)
    short.data = short.data[:-5]
    with pytest.raises(BadFrameError, match="bytes"):
        image_from_msg(short)
    with pytest.raises(BadFrameError, match="empty"):
        image_from_msg(make_image("rgb8", 3, width=0))


def test_scan_and_map_conversion():
    msg = LaserScan()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 3, 500_000_000
    msg.angle_min, msg.angle_increment = -1.0, 0.01
    msg.range_min, msg.range_max = 0.1, 8.0
    msg.ranges = [1.0, float("nan"), float("inf"), 9.0]
    scan = scan_from_msg(msg)
    assert scan.stamp_s == 3.5 and scan.valid.tolist() == [True, False, False, False]
    msg.angle_increment = 0.0
    with pytest.raises(BadScanError):
        scan_from_msg(msg)
    grid = OccupancyGrid()
    grid.info.width, grid.info.height, grid.info.resolution = 4, 2, 0.5
    grid.info.origin.position.x, grid.info.origin.orientation.w = -1.0, 1.0
    grid.data = [0, 0, 0, 100, -1, 0, 0, 0]
    smap = static_map_from_msg(grid)
    assert smap.distance_m(np.array([[0.75, 0.25]]))[0] == 0.0
    assert smap.distance_m(np.array([[-0.75, 0.75]]))[0] > 1.0
    assert math.isinf(smap.distance_m(np.array([[10.0, 0.0]]))[0])


def test_json_round_trips_between_nodes():
    state = CameraPersonState(12.0, PersonStatus.PERSON, (2.5, 0.7), 7, Direction.EAST)
    back = camera_state_from_json(json.dumps(state.to_dict()), now_s=50.0)
    assert back.stamp_s == 50.0 and back.cell == 7 and back.direction is Direction.EAST
    with pytest.raises(ValueError):
        camera_state_from_json('{"status": "maybe"}', 1.0)
    track = TrackEstimate(4, (1.0, 2.0), (0.5, 0.0), 0.5, 6, 9.8, True)
    det = LegDetections(10.0, 5, (), (), 0, 700)
    data = json.loads(json.dumps(legs_to_dict(det, (track,))))
    assert data["tracks"][0]["speed_class"] == "0.2-0.7"
    (again,) = tracks_from_dict(data, now_s=100.0)
    assert again.last_update_s == pytest.approx(99.8) and again.speed_mps == 0.5
    with pytest.raises(ValueError):
        tracks_from_dict({"tracks": [{"id": 1}]}, 1.0)
