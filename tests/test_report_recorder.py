"""The recorder node in-process: raw records only (trace lines, frames), every warning,
and ground truth kept while the camera is silent."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vigil.frames import decode, read_frames

pytestmark = pytest.mark.ros


def test_recorder_writes_raw_records(tmp_path):
    import rclpy
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import Image

    from stack.ros_msgs import camera_to_msg, truth_to_msg, warning_to_msg
    from vigil.node_recorder import RecorderNode
    from vigil.trace_records import TRUTH_GAP_S

    rclpy.init()
    try:
        node = RecorderNode(parameter_overrides=[Parameter("out_dir", value=str(tmp_path))])

        def truth(t):
            body = {"t": t, "robot": [2.5, 0.7, 0.0], "robot_cell": 7, "person": [5.5, 0.7],
                    "person_cell": 1, "person_velocity": [0.0, 0.0]}  # fmt: skip
            node.on_truth(truth_to_msg(body))

        def image(t):
            msg = Image(height=4, width=6, encoding="bgr8", step=18)
            msg.data = bytes(np.full((4, 6, 3), 200, np.uint8).tobytes())
            msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round(t % 1 * 1e9))
            return msg

        for k in range(50):  # truth at 25 Hz, a camera record every 0.4 s until 1.0 s, then none
            t = round(k * 0.04, 6)
            truth(t)
            if k % 10 == 0 and t < 1.0:
                node.on_image(image(t))
                node.on_warning(warning_to_msg("first", 1, None, t))
                node.on_warning(warning_to_msg("second", 2, None, t))
                node.on_person(camera_to_msg({"stamp_s": t, "status": "person"}))
        node.destroy_node()
    finally:
        rclpy.shutdown()
    lines = [json.loads(x) for x in (tmp_path / "trace.jsonl").read_text().splitlines()]
    with_camera = [r["t"] for r in lines if r["camera"] is not None]
    assert with_camera == [0.0, 0.4, 0.8]
    assert all(r["speech"] == ["first", "second"] for r in lines if r["camera"] is not None)
    silent = [r["t"] for r in lines if r["camera"] is None]
    assert silent and all(
        b - a >= TRUTH_GAP_S - 1e-9 for a, b in zip(silent, silent[1:], strict=False)
    )
    assert max(silent) > 1.5 and all(r["robot"] == [2.5, 0.7, 0.0] for r in lines)
    frames = list(read_frames(tmp_path / "camera_frames.bin"))
    assert [t for t, _ in frames] == [r["t"] for r in lines]
    assert decode(frames[0][1]).shape == (4, 6, 3) and frames[1][1] == b""


def test_a_camera_state_before_the_first_truth_makes_no_trace_record():
    """In real time the world waits for the nodes; the camera's watchdog may say
    "unknown" before the twin's first truth: no record then (it once made a record at
    t = 0 in a trace on the system clock)."""
    from vigil.trace_records import TraceRecords

    rec = TraceRecords()
    assert rec.on_person({"stamp_s": 0.0, "status": "unknown"}) is None
    assert rec.on_truth({"t": 1795782584.5, "robot": [1.0, 2.0, 0.0]}) is not None
    record, stamp = rec.on_person({"stamp_s": 1795782584.55, "status": "no person"})
    assert record["t"] == 1795782584.5 and record["robot"] == [1.0, 2.0, 0.0]
    assert stamp == 1795782584.55
