"""Configuration of the digital twin: frozen dataclasses validated from YAML mappings.

Every component has its own dataclass with the units in the field names. ``from_dict``
checks each key and value and raises :class:`stack.cells.ConfigError` naming the key,
the value and the broken rule, so that a typo in ``config/twin-scene.yaml`` fails at
start-up and not as a strange scene.

Frames: the world frame of the MuJoCo scene IS the map frame of ``stack.cells`` (x east,
y north, z up, metres). The room is laid around the cell region read from the task
file's ``grid`` section, so moving ``grid.origin_m`` moves the whole room with it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

import yaml

from stack.cells import CellGrid, ConfigError
from stack.config import Config, load_yaml, read_text_capped

Rule = tuple[Callable[[Any], bool], str]


def _positive(v: Any) -> bool:
    return v > 0


def _non_negative(v: Any) -> bool:
    return v >= 0


def _unit_rgb(v: Any) -> bool:
    return len(v) == 3 and all(0.0 <= c <= 1.0 for c in v)


POSITIVE: Rule = (_positive, "must be > 0")
NON_NEGATIVE: Rule = (_non_negative, "must be >= 0")
RGB: Rule = (_unit_rgb, "must be three numbers in [0, 1]")

# The fastest walker the twin animates: beyond ISO 13855's 1.6 m/s walking speed, up to
# a fast walk or a jog (issue 26). The gait's steps lengthen with speed (twin/person.py).
MAX_WALK_SPEED_MPS = 2.0


class _FromDict(Config):
    """The twin's configurations: :class:`stack.config.Config` (checked whenever built,
    from YAML or in code) with per-field ``_rules`` and cross-field ``check``; keys in
    errors are the field's own, ``from_dict`` prefixes the section."""


@dataclass(frozen=True)
class RoomConfig(_FromDict):
    """The LRM room laid around the cell region.

    The margins are measured from the region's edges to the inside faces of the walls.
    The ceiling camera hangs on the west (short) wall, so ``margin_west_m`` must leave
    room for its distance behind the region (FEASIBILITY mount "A": >= 3 m).
    """

    margin_west_m: float = 3.5
    margin_east_m: float = 2.0
    margin_south_m: float = 2.2
    margin_north_m: float = 2.2
    wall_height_m: float = 3.0
    wall_thickness_m: float = 0.12
    door_width_m: float = 0.9
    door_height_m: float = 2.1
    # door centre in the north wall, measured east of the region's east edge [m]
    door_offset_east_m: float = 1.0
    floor_tile_m: float = 0.6
    furniture: bool = True

    _rules: ClassVar[dict[str, Rule]] = {
        "margin_west_m": POSITIVE,
        "margin_east_m": POSITIVE,
        "margin_south_m": POSITIVE,
        "margin_north_m": POSITIVE,
        "wall_height_m": (lambda v: 2.2 < v <= 6.0, "must be in (2.2, 6] m"),
        "wall_thickness_m": (lambda v: 0.02 <= v <= 0.5, "must be in [0.02, 0.5] m"),
        "door_width_m": (lambda v: 0.6 <= v <= 2.0, "must be in [0.6, 2.0] m"),
        "door_height_m": (lambda v: 1.9 <= v <= 2.2, "must be in [1.9, 2.2] m"),
        "floor_tile_m": POSITIVE,
    }


@dataclass(frozen=True)
class CameraConfig(_FromDict):
    """The ceiling AXIS P1344, mount "A" of FEASIBILITY.md.

    It hangs on the west wall behind the region's west end, on the region's long axis,
    looking east and tilted down. ``fovy_deg`` must stay within what the 3-8 mm
    varifocal lens gives (horizontal 34-80 deg; vertical about 22-54 deg at 16:10).
    """

    width_px: int = 640
    height_px: int = 400
    fovy_deg: float = 40.0
    tilt_deg: float = 22.0  # below horizontal; keeps a head at the far end in view
    height_m: float = 2.75
    distance_behind_m: float = 3.3  # from the region's west edge, along -x
    lateral_offset_m: float = 0.0  # along +y from the region's mid-line
    rate_hz: float = 10.0
    antialias_samples: int = 4
    # the lens's blur: a Gaussian of this many pixels (sigma) over the rendered image, 0:
    # none. With antialias_samples 0 it stands in for the multisampling at a third of
    # the render's CPU (docs/BENCHMARKS.md, perception)
    blur_sigma_px: float = 0.0
    # the key light casts shadows only when asked: they triple the render time on the
    # CPU and change neither detection nor cells (docs/BENCHMARKS.md, perception)
    shadows: bool = False

    _rules: ClassVar[dict[str, Rule]] = {
        "width_px": (lambda v: 16 <= v <= 1280, "must be in [16, 1280] (P1344 maximum)"),
        "height_px": (lambda v: 16 <= v <= 800, "must be in [16, 800] (P1344 maximum)"),
        "fovy_deg": (lambda v: 20.0 <= v <= 56.0, "must be in [20, 56] deg (3-8 mm lens)"),
        "tilt_deg": (lambda v: 0.0 <= v <= 89.0, "must be in [0, 89] deg"),
        "height_m": POSITIVE,
        "distance_behind_m": POSITIVE,
        "rate_hz": POSITIVE,
        "antialias_samples": (lambda v: v in (0, 1, 2, 4, 8, 16), "must be 0, 1, 2, 4, 8 or 16"),
        "blur_sigma_px": (lambda v: 0.0 <= v <= 5.0, "must be in [0, 5] px"),
    }


@dataclass(frozen=True)
class LidarConfig(_FromDict):
    """The planar laser scanner on the robot, simulated with mujoco.mj_multiRay."""

    beams: int = 720
    fov_deg: float = 270.0  # centred on the robot's forward axis
    range_min_m: float = 0.05
    range_max_m: float = 10.0
    noise_std_m: float = 0.01  # Gaussian range noise
    rate_hz: float = 10.0

    _rules: ClassVar[dict[str, Rule]] = {
        "beams": (lambda v: 2 <= v <= 10000, "must be in [2, 10000]"),
        "fov_deg": (lambda v: 0.0 < v <= 360.0, "must be in (0, 360] deg"),
        "range_min_m": NON_NEGATIVE,
        "range_max_m": POSITIVE,
        "noise_std_m": NON_NEGATIVE,
        "rate_hz": POSITIVE,
    }

    def check(self) -> None:
        if self.range_max_m <= self.range_min_m:
            raise ConfigError("range_max_m", self.range_max_m, "must exceed range_min_m")


@dataclass(frozen=True)
class RobotConfig(_FromDict):
    """The robot's base: start pose, limits and actuator gains.

    ``drive``: ``holonomic`` (the MBot's mecanum base) or ``diff`` (a differential
    drive: the planar joint is constrained to move along the heading only; a lateral
    command is dropped and lateral slip removed at every physics step).
    """

    start_cell: int = 7  # the thesis's rest position (section 4.2)
    start_yaw_rad: float = 0.0
    max_linear_mps: float = 0.5
    max_angular_radps: float = 1.2
    max_linear_accel_mps2: float = 1.0
    max_angular_accel_radps2: float = 3.0
    linear_gain_ns_per_m: float = 2000.0  # velocity actuator kv on the slides
    angular_gain_nms_per_rad: float = 100.0  # kv on the yaw hinge
    drive: str = "holonomic"

    _rules: ClassVar[dict[str, Rule]] = {
        "drive": (lambda v: v in ("holonomic", "diff"), "must be holonomic or diff"),
        "start_cell": POSITIVE,
        "max_linear_mps": POSITIVE,
        "max_angular_radps": POSITIVE,
        "max_linear_accel_mps2": POSITIVE,
        "max_angular_accel_radps2": POSITIVE,
        "linear_gain_ns_per_m": POSITIVE,
        "angular_gain_nms_per_rad": POSITIVE,
    }


@dataclass(frozen=True)
class OdometryConfig(_FromDict):
    """Wheel odometry: the true body-frame velocity plus Gaussian noise, integrated."""

    linear_noise_std_mps: float = 0.01
    angular_noise_std_radps: float = 0.01

    _rules: ClassVar[dict[str, Rule]] = {
        "linear_noise_std_mps": NON_NEGATIVE,
        "angular_noise_std_radps": NON_NEGATIVE,
    }


@dataclass(frozen=True)
class Waypoint(_FromDict):
    """One point of the person's script: walk here at ``speed_mps``, then wait ``pause_s``.

    The first waypoint is where the person starts; its speed is unused.
    """

    x_m: float = 0.0
    y_m: float = 0.0
    speed_mps: float = 1.0
    pause_s: float = 0.0

    _rules: ClassVar[dict[str, Rule]] = {
        "speed_mps": (
            lambda v: 0.1 <= v <= MAX_WALK_SPEED_MPS,
            f"must be in [0.1, {MAX_WALK_SPEED_MPS}] m/s (walking speeds, up to a jog)",
        ),
        "pause_s": NON_NEGATIVE,
    }


@dataclass(frozen=True)
class PersonConfig(_FromDict):
    """The person: body sizes, clothing colours and a scripted trajectory.

    With no waypoints the person enters through the door, walks through the region
    (cells 12, 7 and 1 of the default grid) with pauses, and leaves through the door.
    """

    present: bool = True
    height_m: float = 1.75
    waypoints: tuple[Waypoint, ...] = ()
    shirt_rgb: tuple[float, float, float] = (0.70, 0.12, 0.12)
    trousers_rgb: tuple[float, float, float] = (0.12, 0.16, 0.35)
    skin_rgb: tuple[float, float, float] = (0.87, 0.68, 0.55)
    hair_rgb: tuple[float, float, float] = (0.15, 0.09, 0.05)
    shoes_rgb: tuple[float, float, float] = (0.08, 0.08, 0.08)

    _rules: ClassVar[dict[str, Rule]] = {
        "height_m": (lambda v: 1.4 <= v <= 2.1, "must be in [1.4, 2.1] m"),
        "shirt_rgb": RGB,
        "trousers_rgb": RGB,
        "skin_rgb": RGB,
        "hair_rgb": RGB,
        "shoes_rgb": RGB,
    }


# Clothes of the second, third, ... walker when their file leaves the default colours
# (the first walker keeps PersonConfig's, so a one-person scene renders as before):
# (shirt, trousers), chosen far apart in hue and in grey level for the camera.
WALKER_CLOTHES: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
    ((0.14, 0.42, 0.70), (0.28, 0.26, 0.22)),  # blue shirt, dark khaki trousers
    ((0.20, 0.55, 0.22), (0.10, 0.10, 0.12)),  # green shirt, black trousers
    ((0.85, 0.70, 0.15), (0.30, 0.18, 0.10)),  # yellow shirt, brown trousers
)


def walker_config(person: PersonConfig, index: int) -> PersonConfig:
    """The ``index``-th walker (0-based) with distinct clothes if it kept the defaults.

    Args:
        person: the walker's configuration.
        index: its place in ``TwinConfig.walkers``.

    Returns:
        ``person`` itself for index 0 or colours of its own; otherwise a copy dressed
        from :data:`WALKER_CLOTHES`.
    """
    default = PersonConfig()
    if index == 0 or (person.shirt_rgb, person.trousers_rgb) != (
        default.shirt_rgb,
        default.trousers_rgb,
    ):
        return person
    shirt, trousers = WALKER_CLOTHES[(index - 1) % len(WALKER_CLOTHES)]
    return replace(person, shirt_rgb=shirt, trousers_rgb=trousers)


@dataclass(frozen=True)
class Obstacle(_FromDict):
    """A box standing on the floor (e.g. a crate left on a cell's waypoint)."""

    x_m: float = 0.0
    y_m: float = 0.0
    half_size_m: float = 0.35
    height_m: float = 0.8

    _rules: ClassVar[dict[str, Rule]] = {"half_size_m": POSITIVE, "height_m": POSITIVE}


@dataclass(frozen=True)
class MapConfig(_FromDict):
    """The occupancy map made from the twin's static geometry.

    A cell is occupied where any static geom occupies some height in
    [z_min_m, z_max_m]: by default everything the robot (1.25 m tall) could hit, so
    desks show as their whole footprint while the lidar sees only their legs.
    """

    resolution_m: float = 0.05
    z_min_m: float = 0.02
    z_max_m: float = 1.3
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196

    _rules: ClassVar[dict[str, Rule]] = {
        "resolution_m": (lambda v: 0.005 <= v <= 1.0, "must be in [0.005, 1] m"),
        "occupied_thresh": (lambda v: 0.0 < v < 1.0, "must be in (0, 1)"),
        "free_thresh": (lambda v: 0.0 < v < 1.0, "must be in (0, 1)"),
    }

    def check(self) -> None:
        if self.z_max_m <= self.z_min_m:
            raise ConfigError("z_max_m", self.z_max_m, "must exceed z_min_m")
        if self.free_thresh >= self.occupied_thresh:
            raise ConfigError("free_thresh", self.free_thresh, "must be < occupied_thresh")


@dataclass(frozen=True)
class TwinConfig(_FromDict):
    """Everything the twin needs. ``grid`` is the shared cell geometry (stack.cells).

    People: ``people`` lists the walkers (issue 16: several at once, each with its
    own script); when it is empty the single ``person`` is the one walker (or none
    when ``person.present`` is false). A file gives one of the two keys, not both.
    :attr:`walkers` is the list the scene and the twin use.
    """

    grid: CellGrid = field(default_factory=CellGrid)
    room: RoomConfig = field(default_factory=RoomConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    person: PersonConfig = field(default_factory=PersonConfig)
    people: tuple[PersonConfig, ...] = ()
    map: MapConfig = field(default_factory=MapConfig)
    obstacles: tuple[Obstacle, ...] = ()
    timestep_s: float = 0.002
    control_period_s: float = 0.02  # one Twin.step

    _rules: ClassVar[dict[str, Rule]] = {
        "timestep_s": (lambda v: 1e-4 <= v <= 0.01, "must be in [0.0001, 0.01] s"),
        "control_period_s": POSITIVE,
    }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, key: str | None = None) -> TwinConfig:
        """As :meth:`stack.config.Config.from_dict`; ``person`` and ``people`` exclude
        each other."""
        if isinstance(data, Mapping) and "person" in data and "people" in data:
            prefix = f"{key}." if key else ""
            raise ConfigError(
                f"{prefix}people", "<list>", "give either person (one) or people (a list)"
            )
        return super().from_dict(data, key)

    @property
    def walkers(self) -> tuple[PersonConfig, ...]:
        """The people in the scene, in order, dressed apart (:func:`walker_config`)."""
        listed = self.people if self.people else (self.person,)
        present = [p for p in listed if p.present]
        return tuple(walker_config(p, i) for i, p in enumerate(present))

    def check(self) -> None:
        steps = self.control_period_s / self.timestep_s
        if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
            raise ConfigError(
                "control_period_s",
                self.control_period_s,
                "must be a multiple of timestep_s",
            )
        if self.robot.start_cell not in self.grid.cells:
            raise ConfigError("robot.start_cell", self.robot.start_cell, "not a cell of the grid")
        if self.camera.distance_behind_m >= self.room.margin_west_m:
            raise ConfigError(
                "camera.distance_behind_m",
                self.camera.distance_behind_m,
                f"must be less than room.margin_west_m ({self.room.margin_west_m})",
            )
        if self.camera.height_m >= self.room.wall_height_m:
            raise ConfigError(
                "camera.height_m", self.camera.height_m, "must be below the wall height"
            )


def _read_yaml_file(path: str | Path) -> Any:
    try:
        return load_yaml(read_text_capped(path)) or {}
    except (ValueError, yaml.YAMLError) as exc:
        raise ConfigError(str(path), "<file>", f"is not a readable YAML file: {exc}") from None


def load_twin_config(path: str | Path, task_path: str | Path | None = None) -> TwinConfig:
    """Read a twin YAML file; take ``grid`` from a task file when one is given.

    Args:
        path: YAML file whose top level (or ``twin`` section) holds TwinConfig's keys.
        task_path: optional task file (e.g. config/task-r1.yaml); its ``grid`` section
            overrides any ``grid`` in ``path``. A missing task file is ignored so that
            the default ``CellGrid()`` applies.

    Returns:
        The validated configuration.

    Raises:
        ConfigError: any invalid key or value.
        OSError: ``path`` cannot be read.
    """
    data = _read_yaml_file(path)
    if isinstance(data, Mapping) and "twin" in data:
        data = data["twin"]
    if not isinstance(data, Mapping):
        raise ConfigError(str(path), data, "must hold a mapping")
    data = dict(data)
    if task_path is not None and Path(task_path).exists():
        task = _read_yaml_file(task_path)
        if isinstance(task, Mapping) and "grid" in task:
            data["grid"] = task["grid"]
    return TwinConfig.from_dict(data)
