"""The planner's observation per decision step (thesis 3.x observations, 4.5).

The solver receives three observations (thesis 4.3, tables 5.1-5.4):

- robot position: its cell, from the localisation pose ("Out of the map" outside);
- person position: a cell 1..p, or "No person";
- person velocity: "Not moving", or a direction and a speed class joined as in
  "East higher", "West 0.2-0.7", "South 0-0.2".

Rules of section 4.5 applied here:

- the camera decides whether there is a person; when it says no person (two missed
  frames) or cannot tell, the velocity is "Not moving" and the laser is ignored;
- a person outside the region is no person for the planner ("not in the environment");
- the direction comes from the camera; when it is "Not moving" the velocity is
  "Not moving" whatever the laser says;
- the speed class comes from the laser track nearest the camera's person; when the
  laser has no such track (out of range, no data) the class is "0-0.2".
"""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from stack.cells import CellGrid, Direction
from stack.perception._config import from_mapping, require
from stack.perception.camera import CameraPersonState, PersonStatus
from stack.perception.legs import Pose2D
from stack.perception.tracker import TrackEstimate, nearest_track

NO_PERSON = "No person"
OUT_OF_MAP = "Out of the map"
NOT_MOVING = "Not moving"


class SpeedClass(enum.Enum):
    """The three speed classes of thesis 4.5; the value is the planner's label."""

    SLOW = "0-0.2"  # [0, 0.2) m/s: standing or about to stop
    MEDIUM = "0.2-0.7"  # [0.2, 0.7) m/s: walking slowly
    FAST = "higher"  # >= 0.7 m/s: walking somewhere at a steady pace

    @property
    def label(self) -> str:
        return self.value


def speed_class(speed_mps: float, thresholds_mps: tuple[float, float] = (0.2, 0.7)) -> SpeedClass:
    """Discretise a speed (eq. 4.8) into the thesis's classes.

    Args:
        speed_mps: speed [m/s], >= 0.
        thresholds_mps: (slow/medium, medium/fast) boundaries [m/s].

    Returns:
        SLOW below the first threshold, MEDIUM below the second, FAST otherwise.

    Raises:
        ValueError: a negative or non-finite speed.
    """
    if not (math.isfinite(speed_mps) and speed_mps >= 0.0):
        raise ValueError(f"speed {speed_mps!r} must be a finite number >= 0")
    if speed_mps < thresholds_mps[0]:
        return SpeedClass.SLOW
    if speed_mps < thresholds_mps[1]:
        return SpeedClass.MEDIUM
    return SpeedClass.FAST


@dataclass(frozen=True)
class Observation:
    """What the planner observes at one decision step.

    Attributes:
        stamp_s: decision time [s].
        person_cell: the person's cell, or None for "No person".
        direction: the person's movement direction (NOT_MOVING when no person).
        speed: the speed class; None exactly when the velocity is "Not moving".
        robot_cell: the robot's cell, or None for "Out of the map" / never localised.
        person_position_m: the camera's map position of the person, for display [m].
        speed_mps: the laser track's speed when one was associated, for display [m/s].
    """

    stamp_s: float
    person_cell: int | None
    direction: Direction
    speed: SpeedClass | None
    robot_cell: int | None
    person_position_m: tuple[float, float] | None = None
    speed_mps: float | None = None

    def __post_init__(self) -> None:
        if self.person_cell is None and self.direction is not Direction.NOT_MOVING:
            raise ValueError("no person must be 'Not moving'")
        if (self.direction is Direction.NOT_MOVING) != (self.speed is None):
            raise ValueError("speed is given exactly when the person moves in a direction")

    @property
    def person_label(self) -> str:
        """The cell number as text, or "No person"."""
        return NO_PERSON if self.person_cell is None else str(self.person_cell)

    @property
    def velocity_label(self) -> str:
        """ "Not moving" or "<North|South|East|West> <0-0.2|0.2-0.7|higher>"."""
        if self.speed is None:
            return NOT_MOVING
        return f"{self.direction.label} {self.speed.label}"

    @property
    def robot_label(self) -> str:
        """The robot's cell number as text, or "Out of the map"."""
        return OUT_OF_MAP if self.robot_cell is None else str(self.robot_cell)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the planner's labels and the display fields."""
        return {
            "stamp_s": self.stamp_s,
            "robot": self.robot_label,
            "person": self.person_label,
            "velocity": self.velocity_label,
            "person_position_m": (
                None if self.person_position_m is None else list(self.person_position_m)
            ),
            "speed_mps": self.speed_mps,
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    @classmethod
    def from_labels(cls, stamp_s: float, robot: str, person: str, velocity: str) -> Observation:
        """Parse the planner's three labels (inverse of the ``*_label`` properties).

        Raises:
            ValueError: a label outside the thesis's observation alphabet.
        """
        robot_cell = None if robot == OUT_OF_MAP else _cell_label(robot, "robot")
        person_cell = None if person == NO_PERSON else _cell_label(person, "person")
        if velocity == NOT_MOVING:
            return cls(stamp_s, person_cell, Direction.NOT_MOVING, None, robot_cell)
        parts = velocity.split(" ")
        directions = {d.label: d for d in Direction if d is not Direction.NOT_MOVING}
        speeds = {s.label: s for s in SpeedClass}
        if len(parts) != 2 or parts[0] not in directions or parts[1] not in speeds:
            raise ValueError(
                f"velocity {velocity!r} is not 'Not moving' or '<direction> <speed class>'"
            )
        return cls(stamp_s, person_cell, directions[parts[0]], speeds[parts[1]], robot_cell)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Observation:
        """Parse :meth:`to_dict`'s output (labels only are required)."""
        obs = cls.from_labels(
            float(data["stamp_s"]), str(data["robot"]), str(data["person"]), str(data["velocity"])
        )
        pos = data.get("person_position_m")
        speed = data.get("speed_mps")
        return cls(
            obs.stamp_s, obs.person_cell, obs.direction, obs.speed, obs.robot_cell,
            None if pos is None else (float(pos[0]), float(pos[1])),
            None if speed is None else float(speed),
        )  # fmt: skip


def _cell_label(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{what} label {text!r} is not a cell number") from None


@dataclass(frozen=True)
class CombinerConfig:
    """Attributes:
    speed_thresholds_mps: boundaries of the speed classes [m/s] (thesis: 0.2, 0.7).
    association_gate_m: a laser track farther than this from the camera's person
        is not the person [m].
    max_camera_age_s: a camera state older than this is "No person" [s].
    max_track_age_s: a laser track not updated for longer is "no laser data" [s].
    """

    speed_thresholds_mps: tuple[float, float] = (0.2, 0.7)
    association_gate_m: float = 1.0
    max_camera_age_s: float = 2.0
    max_track_age_s: float = 1.0

    def __post_init__(self) -> None:
        lo, hi = self.speed_thresholds_mps
        require(0 < lo < hi, "speed_thresholds_mps", self.speed_thresholds_mps,
                "needs 0 < slow/medium < medium/fast")  # fmt: skip
        require(self.association_gate_m > 0, "association_gate_m", self.association_gate_m,
                "must be > 0")  # fmt: skip
        require(self.max_camera_age_s > 0, "max_camera_age_s", self.max_camera_age_s,
                "must be > 0")  # fmt: skip
        require(self.max_track_age_s > 0, "max_track_age_s", self.max_track_age_s, "must be > 0")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, key: str = "observations") -> CombinerConfig:
        """Validate a mapping into a CombinerConfig; raises ConfigError."""
        return from_mapping(cls, data, key)


@dataclass
class ObservationCombiner:
    """Joins camera, laser and pose into one :class:`Observation` per decision step.

    The robot's cell is deterministic in the thesis; when no pose has arrived since
    the last step the previous cell is kept (the robot did not move), and before
    any pose the robot is "Out of the map".

    Args:
        grid: the cell geometry shared with the planner.
        config: association and freshness parameters.
    """

    grid: CellGrid
    config: CombinerConfig = field(default_factory=CombinerConfig)
    _robot_cell: int | None = field(default=None, init=False)

    def combine(
        self,
        stamp_s: float,
        camera: CameraPersonState | None,
        tracks: Iterable[TrackEstimate] = (),
        robot_pose: Pose2D | None = None,
    ) -> Observation:
        """The observation at one decision step.

        Args:
            stamp_s: the decision time [s].
            camera: the camera's latest state (None: no frame yet).
            tracks: the laser tracker's latest tracks.
            robot_pose: the robot's latest pose in the map frame (None: none new).

        Returns:
            The observation; "No person" / "Not moving" whenever the camera cannot
            vouch for a person in the region.
        """
        if robot_pose is not None:
            self._robot_cell = self.grid.cell_at(robot_pose.x_m, robot_pose.y_m)
        robot_cell = self._robot_cell
        cfg = self.config
        if (
            camera is None
            or camera.status is not PersonStatus.PERSON
            or camera.position_m is None
            or camera.cell is None
            or stamp_s - camera.stamp_s > cfg.max_camera_age_s
        ):
            return Observation(stamp_s, None, Direction.NOT_MOVING, None, robot_cell)
        fresh = [t for t in tracks if stamp_s - t.last_update_s <= cfg.max_track_age_s]
        track = nearest_track(fresh, camera.position_m, cfg.association_gate_m)
        speed_mps = None if track is None else track.speed_mps
        if camera.direction is Direction.NOT_MOVING:
            return Observation(
                stamp_s, camera.cell, Direction.NOT_MOVING, None, robot_cell,
                camera.position_m, speed_mps,
            )  # fmt: skip
        # Camera sees the person but the laser has no data: "0-0.2" (thesis 4.5).
        cls = (
            SpeedClass.SLOW
            if track is None
            else speed_class(track.speed_mps, cfg.speed_thresholds_mps)
        )
        return Observation(
            stamp_s, camera.cell, camera.direction, cls, robot_cell, camera.position_m, speed_mps
        )
