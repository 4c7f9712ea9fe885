"""What the recorder writes into ``trace.jsonl``, without ROS (pure).

:mod:`vigil.node_recorder` (ROS) and :mod:`vigil.inprocess` (the Monte-Carlo loop) both
keep one :class:`TraceRecords` and write the records it returns, so the two transports
leave the same trace: one record per camera detection message, and while the camera
is silent (an outage) one per :data:`TRUTH_GAP_S` of ground truth with ``camera`` null,
so that the metrics keep seeing where robot and people are.
"""

from __future__ import annotations

from typing import Any

from stack.geometry import Pose2D

TRUTH_GAP_S = 0.25  # camera silent this long: trace the ground truth without it
CAMERA_KEYS = ("status", "position_m", "cell", "direction", "boxes", "foot_px")


class TraceRecords:
    """The latest truth, odometry, legs and warnings, joined into trace records."""

    def __init__(self) -> None:
        self.truth: dict[str, Any] | None = None
        self.odom: list[float] | None = None
        self.legs: list = []
        self.speech: list[str] = []
        self.last_t = 0.0  # the last record's time

    def on_truth(self, truth: dict[str, Any]) -> dict[str, Any] | None:
        """The twin's ground truth; a record without the camera when it has been silent
        for :data:`TRUTH_GAP_S`, else None."""
        self.truth = truth
        t = truth.get("t")
        if isinstance(t, int | float) and t - self.last_t >= TRUTH_GAP_S - 1e-9:
            return self.record(float(t), None)
        return None

    def on_odom(self, pose: Pose2D | None) -> None:
        """The odometry's pose (None: a pose that could not be read)."""
        self.odom = (
            None
            if pose is None
            else [round(pose.x_m, 4), round(pose.y_m, 4), round(pose.yaw_rad, 4)]
        )

    def on_legs(self, data: dict[str, Any]) -> None:
        """The legs node's message: its confirmed tracks' positions."""
        tracks = data.get("tracks", [])
        self.legs = [t["position_m"] for t in tracks if t.get("confirmed") and "position_m" in t]

    def on_warning(self, text: str) -> None:
        self.speech.append(text or "warning")  # every one: two may come between records

    def on_person(self, camera: dict[str, Any]) -> tuple[dict[str, Any], float] | None:
        """The camera people node's message: its record, and the frame's stamp (the
        frame that goes with it in the video); None before the twin's first truth (the
        camera's watchdog stating "unknown" while the world waits for the nodes to come
        up, in real time: no time to put it at, nothing true to hold)."""
        if self.truth is None:
            return None
        stamp = round(float(camera.get("stamp_s") or 0.0), 6)
        t = (self.truth or {}).get("t", stamp)
        return self.record(t, {k: camera.get(k) for k in CAMERA_KEYS}), stamp

    def record(self, t: float, camera: dict[str, Any] | None) -> dict[str, Any]:
        """One trace record at ``t``: the latest truth, odometry, legs, the warnings since
        the last record, and the camera's detection (None: silent)."""
        truth = self.truth or {}
        record = {
            "t": t,
            "robot": truth.get("robot"),
            "robot_cell": truth.get("robot_cell"),
            "person": truth.get("person"),
            "person_cell": truth.get("person_cell"),
            "person_velocity": truth.get("person_velocity"),
            "odom": self.odom,
            "camera": camera,
            "legs": self.legs,
            "speech": self.speech or None,
        }
        if truth.get("people"):  # several walkers (issue 16): each one's truth
            record["people"] = truth["people"]
        self.speech = []
        self.last_t = float(t)
        return record
