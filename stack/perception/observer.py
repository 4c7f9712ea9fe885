"""The observations node's behaviour without ROS: the latest camera state, laser tracks
and robot pose in; one observation record per decision step out.

:mod:`stack.perception.node_observations` (ROS) and :mod:`vigil.inprocess` (the
Monte-Carlo loop) both run it, so a study scores the system ``vigil run`` runs, one
person or several (person slots, :class:`stack.perception.multi.PeoplePerception`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from stack.cells import ConfigError
from stack.perception.camera import CameraPersonState
from stack.perception.config import load_config_file
from stack.perception.errors import CalibrationError
from stack.perception.homography import load_calibration
from stack.perception.legs import Pose2D
from stack.perception.multi import PeoplePerception
from stack.perception.observation import CombinerConfig, Observation, ObservationCombiner
from stack.perception.slots import SlotConfig, SlotPerson, slot_labels
from stack.perception.visibility import CameraVisibility, VisibilityConfig


class Observer:
    """Joins the camera, the laser tracks and the pose into the planner's observation.

    With several people the camera's frames move the person slots on
    (:meth:`on_camera`), and while the camera is blind (off, frozen, failed) the laser's
    fresh, confirmed tracks do, at each observation (:meth:`observe`).

    Args:
        config_file: the observations' configuration (optional ``grid``,
            ``observations``, ``visibility`` and ``slots`` sections).
        calibration_file: the camera's calibration ("": no visibility: a camera that
            sees nobody means nobody).
        people: the task's people (2 or more: one label pair per person slot).
        on_error: told when the calibration cannot be read (the observer runs without
            visibility); None: the error is raised.

    Raises:
        ConfigError: ``people`` below 1, or a bad configuration.
    """

    def __init__(
        self,
        config_file: str,
        calibration_file: str = "",
        people: int = 1,
        on_error: Callable[[str], None] | None = None,
    ):
        if people < 1:
            raise ConfigError("people", people, "must be >= 1")
        grid, sections = load_config_file(config_file)
        self.slots = (
            PeoplePerception(
                grid, SlotConfig.from_dict({**(sections.get("slots") or {}), "slots": people})
            )
            if people > 1
            else None
        )
        self.slot_people: tuple[SlotPerson, ...] = tuple(SlotPerson(k) for k in range(people))
        self._slots_stamp_s = -math.inf  # the slots' last update
        self.visibility: CameraVisibility | None = None
        if calibration_file:
            try:
                self.visibility = CameraVisibility(
                    load_calibration(calibration_file).homography,
                    grid,
                    VisibilityConfig.from_dict(sections.get("visibility")),
                )
            except (CalibrationError, ValueError, OSError) as err:
                if on_error is None:
                    raise
                on_error(
                    f"camera visibility off ({calibration_file}: {err}): the robot's shadow "
                    "is not known and a camera that sees nobody means nobody"
                )
        self.combiner = ObservationCombiner(
            grid, CombinerConfig.from_dict(sections.get("observations")), self.visibility
        )
        self.camera: CameraPersonState | None = None
        self.tracks: tuple = ()
        self.pose: Pose2D | None = None

    def on_camera(self, camera: CameraPersonState) -> None:
        """The camera people node's latest state (and the person slots moved on)."""
        self.camera = camera
        self._move_slots(camera.stamp_s, camera.people_m)

    def _move_slots(self, stamp_s: float, positions_m: Sequence[tuple[float, float]]) -> None:
        """The person slots' tracker moves on to ``stamp_s`` with these people, once an
        instant: two camera messages in one instant (the frame watchdog's "silent" and
        the first frame after an outage), or a frame no later than the laser's stand-in
        for a blind camera, move it on with the first only."""
        if self.slots is not None and stamp_s > self._slots_stamp_s:
            self._slots_stamp_s = stamp_s
            self.slots.track(stamp_s, positions_m)

    def on_tracks(self, tracks: tuple) -> None:
        self.tracks = tracks

    def on_pose(self, pose: Pose2D) -> None:
        self.pose = pose

    def observe(self, now_s: float) -> tuple[Observation, dict[str, Any]]:
        """The observation now and its record (the planner's message), the person slots'
        labels added with several people. A pose is used once: without a new one the
        robot's cell is the last one's.

        Raises:
            ValueError, ArithmeticError: an input that cannot be combined (the node logs
            and skips the step).
        """
        pose, self.pose = self.pose, None
        obs = self.combiner.combine(now_s, self.camera, self.tracks, pose)
        record = obs.to_dict()
        # the frame the labels come from: the latency from camera to decision (issue 25)
        record["frame_stamp_s"] = self.camera.stamp_s if self.camera is not None else None
        if self.slots is not None:
            if not self.combiner.camera_sees(now_s, self.camera):
                # a blind camera (off, frozen, failed): the laser's people stand in for
                # its detections, so that a person who comes in meanwhile is tracked
                # (one person: the combiner's laser-only rule)
                fresh = self.combiner.fresh_tracks(now_s, self.tracks)
                self._move_slots(now_s, [t.position_m for t in fresh])
            self.slot_people = self.slots.report(self.tracks)
            record["people"] = slot_labels(self.slot_people, obs.blind)
        return obs, record
