"""The planner's observation per decision step (thesis 3.x observations, 4.5).

The solver receives three observations (thesis 4.3, tables 5.1-5.4):

- robot position: its cell, from the localisation pose ("Out of the map" outside);
- person position: a cell 1..p, or "No person";
- person velocity: "Not moving", or a direction and a speed class joined as in
  "East higher", "West 0.2-0.7", "South 0-0.2".

Rules of section 4.5, as the thesis gives them, where the camera sees the person:

- a person outside the region is no person for the planner ("not in the environment");
- the direction comes from the camera; when it is "Not moving" the velocity is
  "Not moving" whatever the laser says;
- the speed class comes from the laser track nearest the camera's person; when the
  laser has no such track (out of range, no data) the class is "0-0.2".

What vigil adds (docs/PERCEPTION.md, "Fusion"): the camera's silence means "no person"
only where the camera could have seen one.

- **Fused position.** When a confirmed laser track lies within ``association_gate_m``
  of the camera's person, the position is their inverse-variance mean
  (``camera_sigma_m``, ``laser_sigma_m``): the laser's legs correct a foot point the
  robot half hides. A position within ``border_margin_m`` outside the grid is put in
  the nearest cell (foot-point error), not dropped; so is the robot's (its body is still
  on the edge cell), whose observation would otherwise be "Out of the map", a state the
  task model's robot never reaches from inside.
- **Cannot see.** A camera that has sent nothing for ``max_camera_age_s`` (outage,
  frozen frames) or cannot tell (bad frames) sees nothing: every cell is hidden. With
  a calibration, the cells the robot hides from the camera and the floor outside the
  image are hidden in part (:mod:`stack.perception.visibility`); the cell where the
  person was last seen counts as wholly hidden while that spot is hidden.
- **Laser alone.** Where the camera cannot see (hidden fraction at least
  ``laser_only_min_hidden``), a confirmed laser track in the grid is the person: its
  cell, its direction (dominant axis of its velocity, "Not moving" below the slow
  threshold) and its speed class. A laser track where the camera sees nobody is
  furniture or noise and is ignored.
- Otherwise no person is seen: the label is "No person" with the hidden fractions
  beside it (the planner treats a hidden cell as unobserved), or "Unseen" when the
  camera saw nothing at all.
"""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from stack.cells import CellGrid, Direction
from stack.config import Config, require
from stack.perception.camera import CameraPersonState, PersonStatus
from stack.perception.legs import Pose2D
from stack.perception.tracker import TrackEstimate, nearest_track
from stack.perception.visibility import CameraVisibility
from stack.vocabulary import NO_PERSON, NOT_MOVING, OUT_OF_MAP, UNSEEN, parse_hidden

__all__ = ["NO_PERSON", "NOT_MOVING", "OUT_OF_MAP", "UNSEEN", "Observation", "ObservationCombiner"]

SOURCES = ("camera", "laser", "fused", "none")


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
        person_position_m: the camera's map position of the person [m]; also with
            "No person" when the camera sees them outside the region (the goal
            inference of ``person_model: goal`` reads it).
        speed_mps: the laser track's speed when one was associated, for display [m/s].
        source: what saw the person: "camera", "laser", "fused", or "none".
        hidden: (cell, fraction) for every cell the camera could not see, wholly or
            in part, at this step; all cells at 1.0 when the camera saw nothing.
        blind: the camera could not look at all (no frame, stale, failed): with no
            person from the laser the label is "Unseen", never "No person". A cell
            wholly hidden behind the robot while the camera sees the rest is not
            blindness: that is "No person" with the cell in ``hidden``.
    """

    stamp_s: float
    person_cell: int | None
    direction: Direction
    speed: SpeedClass | None
    robot_cell: int | None
    person_position_m: tuple[float, float] | None = None
    speed_mps: float | None = None
    source: str = "camera"
    hidden: tuple[tuple[int, float], ...] = ()
    blind: bool = False

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source {self.source!r} is not one of {SOURCES}")
        if self.person_cell is None and self.direction is not Direction.NOT_MOVING:
            raise ValueError("no person must be 'Not moving'")
        if (self.direction is Direction.NOT_MOVING) != (self.speed is None):
            raise ValueError("speed is given exactly when the person moves in a direction")

    @property
    def person_label(self) -> str:
        """The cell number as text, "No person", or "Unseen" (the camera saw nothing)."""
        if self.person_cell is not None:
            return str(self.person_cell)
        return UNSEEN if self.unseen else NO_PERSON

    @property
    def unseen(self) -> bool:
        """No person seen and the camera could not look at all."""
        return self.person_cell is None and self.blind

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
            "source": self.source,
            "hidden": {str(c): round(f, 3) for c, f in self.hidden},
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
        person_cell = None if person in (NO_PERSON, UNSEEN) else _cell_label(person, "person")
        if velocity == NOT_MOVING:
            return cls(
                stamp_s, person_cell, Direction.NOT_MOVING, None, robot_cell,
                blind=person == UNSEEN,
            )  # fmt: skip
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
        hidden = parse_hidden(data.get("hidden"))
        if str(data["person"]) == UNSEEN and obs.person_cell is None:
            hidden = tuple((c, 1.0) for c, _ in hidden)
        return cls(
            obs.stamp_s, obs.person_cell, obs.direction, obs.speed, obs.robot_cell,
            None if pos is None else (float(pos[0]), float(pos[1])),
            None if speed is None else float(speed),
            str(data.get("source", "camera")), hidden, obs.blind,
        )  # fmt: skip


def _cell_label(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{what} label {text!r} is not a cell number") from None


@dataclass(frozen=True)
class CombinerConfig(Config):
    """Attributes:
    speed_thresholds_mps: boundaries of the speed classes [m/s] (thesis: 0.2, 0.7).
    association_gate_m: a laser track farther than this from the camera's person
        is not the person [m].
    max_camera_age_s: a camera state older than this means the camera sees nothing [s].
    max_track_age_s: a laser track not updated for longer is "no laser data" [s].
    camera_sigma_m: the camera foot point's error [m] (twin walks: median 0.10 m, p90
        0.21 m; up to 0.6 m with the legs half hidden).
    laser_sigma_m: a leg track's position error [m].
    border_margin_m: a person or the robot this close outside the grid is in the
        nearest cell [m].
    laser_only_min_hidden: a laser track counts alone where the camera's hidden
        fraction is at least this.
    last_seen_memory_s: how long the place the person was last seen is remembered [s].
    """

    section = "observations"  # errors name keys "observations.<field>"

    speed_thresholds_mps: tuple[float, float] = (0.2, 0.7)
    association_gate_m: float = 1.0
    max_camera_age_s: float = 2.0
    max_track_age_s: float = 1.0
    camera_sigma_m: float = 0.25
    laser_sigma_m: float = 0.1
    border_margin_m: float = 0.3
    laser_only_min_hidden: float = 0.3
    last_seen_memory_s: float = 20.0

    def __post_init__(self) -> None:
        lo, hi = self.speed_thresholds_mps
        require(0 < lo < hi, "speed_thresholds_mps", self.speed_thresholds_mps,
                "needs 0 < slow/medium < medium/fast")  # fmt: skip
        for key in ("association_gate_m", "max_camera_age_s", "max_track_age_s",
                    "camera_sigma_m", "laser_sigma_m", "last_seen_memory_s"):  # fmt: skip
            v = getattr(self, key)
            require(math.isfinite(v) and v > 0, key, v, "must be a finite number > 0")
        require(0 <= self.border_margin_m < 1.0, "border_margin_m", self.border_margin_m,
                "must be in [0, 1) m")  # fmt: skip
        require(0 < self.laser_only_min_hidden <= 1, "laser_only_min_hidden",
                self.laser_only_min_hidden, "must be in (0, 1]")  # fmt: skip


def direction_of_velocity(vx: float, vy: float, still_below_mps: float) -> Direction:
    """The dominant axis of a velocity (map frame: x east, y north); NOT_MOVING if slow."""
    if not (math.isfinite(vx) and math.isfinite(vy)) or math.hypot(vx, vy) < still_below_mps:
        return Direction.NOT_MOVING
    if abs(vx) >= abs(vy):
        return Direction.EAST if vx > 0 else Direction.WEST
    return Direction.NORTH if vy > 0 else Direction.SOUTH


def _finite_track(t: TrackEstimate) -> bool:
    return all(math.isfinite(v) for v in (*t.position_m, *t.velocity_mps, t.speed_mps))


@dataclass
class ObservationCombiner:
    """Joins camera, laser, pose and what the camera can see into one :class:`Observation`.

    The robot's cell is deterministic in the thesis; when no pose has arrived since
    the last step the previous cell is kept (the robot did not move), and before
    any pose the robot is "Out of the map".

    Args:
        grid: the cell geometry shared with the planner.
        config: association, fusion and freshness parameters.
        visibility: the camera's view given the robot's pose (None: the camera is
            taken to see the whole grid whenever it works).
    """

    grid: CellGrid
    config: CombinerConfig = field(default_factory=CombinerConfig)
    visibility: CameraVisibility | None = None
    _robot_cell: int | None = field(default=None, init=False)
    _pose: Pose2D | None = field(default=None, init=False)
    _last_seen: tuple[float, float, float] | None = field(default=None, init=False)

    def cell_of(self, x: float, y: float) -> int | None:
        """The cell of a map point, or the nearest cell within ``border_margin_m``."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        return self.grid.cell_near(x, y, self.config.border_margin_m)

    def hidden(self, camera_sees: bool, stamp_s: float) -> dict[int, float]:
        """Each cell's fraction the camera cannot see now (only cells > 0)."""
        if not camera_sees:
            return {c: 1.0 for c in self.grid.cells}
        if self.visibility is None:
            return {}
        out = {c: f for c, f in self.visibility.hidden_fractions(self._pose).items() if f > 0}
        seen = self._last_seen
        if seen is not None and stamp_s - seen[2] <= self.config.last_seen_memory_s:
            cell = self.cell_of(seen[0], seen[1])
            if cell is not None and self.visibility.point_hidden(seen[0], seen[1], self._pose):
                out[cell] = 1.0
        return out

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
            tracks: the laser tracker's latest tracks, in the map frame.
            robot_pose: the robot's latest pose in the map frame (None: none new).

        Returns:
            The observation (see the module's rules).
        """
        if robot_pose is not None:
            # the robot's centre just past the region's edge (its body still on the edge
            # cell: an overshoot, a localisation wobble) is in that cell, as a person's
            # foot point is; further out it is "Out of the map"
            self._robot_cell = self.grid.cell_near(
                robot_pose.x_m, robot_pose.y_m, self.config.border_margin_m
            )
            self._pose = robot_pose
        robot_cell = self._robot_cell
        fresh = self.fresh_tracks(stamp_s, tracks)
        camera_sees = self.camera_sees(stamp_s, camera)
        outside: tuple[float, float] | None = None  # a person seen off the grid
        if (
            camera_sees
            and camera is not None
            and camera.status is PersonStatus.PERSON
            and camera.position_m is not None
        ):
            obs = self._camera_person(stamp_s, camera, fresh, robot_cell)
            if isinstance(obs, Observation):
                return obs
            outside = obs
        hidden = self.hidden(camera_sees, stamp_s)
        laser = self._laser_person(stamp_s, fresh, hidden, robot_cell)
        if laser is not None:
            return laser
        return Observation(
            stamp_s, None, Direction.NOT_MOVING, None, robot_cell, outside,
            source="none", hidden=tuple(sorted(hidden.items())), blind=not camera_sees,
        )  # fmt: skip

    def fresh_tracks(self, stamp_s: float, tracks: Iterable[TrackEstimate]) -> list[TrackEstimate]:
        """The laser's people at ``stamp_s``: confirmed tracks, finite, updated within
        ``max_track_age_s``."""
        age = self.config.max_track_age_s
        return [
            t
            for t in tracks
            if stamp_s - t.last_update_s <= age and t.confirmed and _finite_track(t)
        ]

    def camera_sees(self, stamp_s: float, camera: CameraPersonState | None) -> bool:
        """Whether the camera looks at ``stamp_s``: a state that is not "unknown" (no
        frame, failed) and no older than ``max_camera_age_s``; otherwise it is blind."""
        return (
            camera is not None
            and camera.status is not PersonStatus.UNKNOWN
            and stamp_s - camera.stamp_s <= self.config.max_camera_age_s
        )

    def _camera_person(
        self,
        stamp_s: float,
        camera: CameraPersonState,
        fresh: list[TrackEstimate],
        robot_cell: int | None,
    ) -> Observation | tuple[float, float]:
        """The observation of a person the camera sees in the region, or, outside it,
        their floor point alone (the label is "No person", as in the thesis; where
        they walk still tells where they are heading: :mod:`stack.planning.intent`)."""
        cfg = self.config
        assert camera.position_m is not None
        track = nearest_track(fresh, camera.position_m, cfg.association_gate_m)
        if track is None:
            pos, source = camera.position_m, "camera"
        else:
            wc, wl = cfg.camera_sigma_m**-2, cfg.laser_sigma_m**-2
            pos = tuple(  # type: ignore[assignment]
                (wc * c + wl * t) / (wc + wl)
                for c, t in zip(camera.position_m, track.position_m, strict=True)
            )
            source = "fused"
        cell = self.cell_of(pos[0], pos[1])
        if cell is None:
            return (float(pos[0]), float(pos[1]))  # outside the region: "No person"
        self._last_seen = (pos[0], pos[1], stamp_s)
        speed_mps = None if track is None else track.speed_mps
        position = (float(pos[0]), float(pos[1]))
        if camera.direction is Direction.NOT_MOVING:
            return Observation(
                stamp_s, cell, Direction.NOT_MOVING, None, robot_cell, position, speed_mps, source
            )
        # Camera sees the person but the laser has no data: "0-0.2" (thesis 4.5).
        cls = (
            SpeedClass.SLOW
            if track is None
            else speed_class(track.speed_mps, cfg.speed_thresholds_mps)
        )
        return Observation(
            stamp_s, cell, camera.direction, cls, robot_cell, position, speed_mps, source
        )

    def _laser_person(
        self,
        stamp_s: float,
        fresh: list[TrackEstimate],
        hidden: Mapping[int, float],
        robot_cell: int | None,
    ) -> Observation | None:
        cfg = self.config
        candidates = []
        for t in fresh:
            cell = self.cell_of(*t.position_m)
            if cell is not None and hidden.get(cell, 0.0) >= cfg.laser_only_min_hidden:
                candidates.append((t, cell))
        if not candidates:
            return None
        seen = self._last_seen
        if seen is not None:  # the track nearest where the person was last seen
            track, cell = min(candidates, key=lambda tc: math.dist(tc[0].position_m, seen[:2]))
        else:  # the longest-lived track
            track, cell = max(candidates, key=lambda tc: tc[0].hits)
        self._last_seen = (track.position_m[0], track.position_m[1], stamp_s)
        direction = direction_of_velocity(*track.velocity_mps, cfg.speed_thresholds_mps[0])
        cls = (
            None
            if direction is Direction.NOT_MOVING
            else speed_class(track.speed_mps, cfg.speed_thresholds_mps)
        )
        return Observation(
            stamp_s, cell, direction, cls, robot_cell, track.position_m, track.speed_mps, "laser",
            tuple(sorted(hidden.items())),
        )  # fmt: skip
