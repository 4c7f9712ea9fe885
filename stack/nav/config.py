"""Typed, validated configuration for navigation and speech.

Each dataclass is frozen, names its units and derives from :class:`stack.config.Config`:
it is checked whenever it is built, from YAML (``from_dict``) or in code, and an error
is :class:`stack.cells.ConfigError` naming the key, the value and the rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeVar

from stack.cells import ConfigError
from stack.config import Config, read_yaml
from stack.vocabulary import TRIP_INSET_M

T = TypeVar("T")


def _positive(obj: Any, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(name, v, "must be a finite number > 0")


def _non_negative(obj: Any, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        if not (math.isfinite(v) and v >= 0):
            raise ConfigError(name, v, "must be a finite number >= 0")


DRIVES = ("holonomic", "diff")


@dataclass(frozen=True)
class FollowerConfig(Config):
    """Limits and gains of the path follower.

    ``drive`` picks the base: ``holonomic`` (the MBot's mecanum wheels: any planar
    direction, heading held) or ``diff`` (differential drive: forward speed and yaw
    rate only; the robot turns towards the carrot, in place when it points more than
    ``turn_in_place_rad`` away). Body frame: x forward, y left, z up (REP 103).
    """

    section = "follower"  # errors name keys "follower.<field>"

    max_vx_mps: float = 0.5  # forward/backward speed limit [m/s]
    max_vy_mps: float = 0.4  # lateral speed limit; a mecanum base moves sideways [m/s]
    max_speed_mps: float = 0.5  # limit on the planar speed |(vx, vy)| [m/s]
    max_wz_radps: float = 1.0  # yaw rate limit [rad/s]
    max_accel_x_mps2: float = 0.8  # [m/s^2]
    max_accel_y_mps2: float = 0.8  # [m/s^2]
    max_accel_wz_radps2: float = 2.0  # [rad/s^2]
    decel_mps2: float = 0.5  # braking used to plan the approach to the goal [m/s^2]
    lookahead_m: float = 0.35  # carrot distance along the path [m]
    goal_tolerance_m: float = 0.08  # position tolerance; orientation is ignored [m]
    approach_gain_per_s: float = 1.5  # speed = gain * distance near the goal [1/s]
    heading_gain_per_s: float = 1.0  # holds the start heading while moving; 0 disables [1/s]
    robot_radius_m: float = 0.3  # [m]
    inflation_margin_m: float = 0.05  # added to the radius when inflating obstacles [m]
    person_radius_m: float = 0.3  # a person's footprint on the floor [m]
    stale_pose_s: float = 0.5  # pose older than this: zero velocity [s]
    timeout_s: float = 60.0  # whole task [s]
    blocked_timeout_s: float = 5.0  # waiting for a person to clear the way before BLOCKED [s]
    # a person standing on the waypoint: stop at the nearest free point of the target
    # cell at least this far inside its borders instead (the action is "go to the cell")
    region_margin_m: float = 0.1
    # a move is reported done once the robot is this far inside its target cell; it goes
    # on to the waypoint meanwhile, so the next decision comes while it still drives
    arrive_margin_m: float = 0.2
    # a trip ("To 1", issue 26) ends this far inside the cell, at the point nearest the
    # robot at least trip_clearance_m from every person, or the farthest from them
    # (stack.nav.waypoints.entry_point)
    trip_inset_m: float = TRIP_INSET_M
    trip_clearance_m: float = 0.6  # robot_radius_m + person_radius_m
    replan_period_s: float = 0.5  # retry interval while waiting [s]
    max_start_escape_m: float = 0.3  # start cell in the inflated zone: look this far for free [m]
    unknown_is_occupied: bool = True
    drive: str = "holonomic"  # holonomic (mecanum) or diff (differential drive)
    turn_gain_per_s: float = 2.5  # diff: yaw rate = gain * heading error [1/s]
    turn_in_place_rad: float = 0.8  # diff: heading errors beyond this turn on the spot [rad]

    _rules = {
        "drive": (lambda v: v in DRIVES, f"must be one of {DRIVES}"),
        "turn_in_place_rad": (lambda v: 0 < v <= math.pi / 2, "must be in (0, pi/2] rad"),
        "turn_gain_per_s": (lambda v: v > 0, "must be > 0"),
    }

    def check(self) -> None:
        """Check every value.

        Raises:
            ConfigError: the first value that breaks its rule.
        """
        _positive(
            self,
            "max_vx_mps",
            "max_vy_mps",
            "max_speed_mps",
            "max_wz_radps",
            "max_accel_x_mps2",
            "max_accel_y_mps2",
            "max_accel_wz_radps2",
            "decel_mps2",
            "lookahead_m",
            "goal_tolerance_m",
            "approach_gain_per_s",
            "stale_pose_s",
            "timeout_s",
            "replan_period_s",
        )
        _non_negative(
            self,
            "heading_gain_per_s",
            "robot_radius_m",
            "inflation_margin_m",
            "person_radius_m",
            "blocked_timeout_s",
            "max_start_escape_m",
            "arrive_margin_m",
            "region_margin_m",
            "trip_inset_m",
            "trip_clearance_m",
        )

    @property
    def inflation_radius_m(self) -> float:
        return self.robot_radius_m + self.inflation_margin_m


SPEECH_POLICIES = ("queue", "replace")
DEFAULT_WARNINGS = {
    "en": "Please do not stay here. This area is restricted.",
    "pt": "Por favor, não fique aqui. Esta área é restrita.",
}


@dataclass(frozen=True)
class SpeechConfig(Config):
    """The warning and how it is spoken (thesis 4.4: eSpeak)."""

    section = "speech"  # errors name keys "speech.<field>"

    voice: str = "en"  # espeak-ng voice: "en" (default) or "pt" (Portuguese)
    warning_text: str = ""  # empty: the built-in warning for the voice's language (en, pt)
    words_per_minute: int = 160  # espeak-ng -s
    pitch: int = 50  # espeak-ng -p, 0..99
    amplitude: int = 100  # espeak-ng -a, 0..200
    policy: str = "queue"  # a request while speaking: "queue" it or "replace" the current one
    max_queue: int = 4  # queued requests beyond this are dropped (oldest kept)
    espeak_path: str = "espeak-ng"  # executable name or path
    timeout_s: float = 10.0  # bound on one synthesis [s]
    emulate_playback: bool = True  # WAV output: stay "speaking" for the audio's duration
    restricted_cells: tuple[int, ...] = (1,)  # where the robot warns a person with it
    grace_s: float = 2.0  # a warning may start this long after the person left the cell [s]
    repeat_s: float = 8.0  # while the person stays, warn again after this long [s]
    confirm_s: float = 0.5  # the person is seen in the cell this long before a warning [s]
    max_text_chars: int = 300  # a longer request is refused (it would delay a warning)

    def check(self) -> None:
        """Check every value.

        Raises:
            ConfigError: the first value that breaks its rule.
        """
        if not self.voice.strip():
            raise ConfigError("voice", self.voice, "must name an espeak-ng voice")
        if not self.warning_text.strip() and self.language not in DEFAULT_WARNINGS:
            raise ConfigError(
                "warning_text",
                self.warning_text,
                f"must be given for voice {self.voice!r} (built-in: {sorted(DEFAULT_WARNINGS)})",
            )
        if not 80 <= self.words_per_minute <= 450:
            raise ConfigError("words_per_minute", self.words_per_minute, "80..450")
        if not 0 <= self.pitch <= 99:
            raise ConfigError("pitch", self.pitch, "must lie in 0..99")
        if not 0 <= self.amplitude <= 200:
            raise ConfigError("amplitude", self.amplitude, "must lie in 0..200")
        if self.policy not in SPEECH_POLICIES:
            raise ConfigError("policy", self.policy, f"must be one of {SPEECH_POLICIES}")
        if self.max_queue < 1:
            raise ConfigError("max_queue", self.max_queue, "must be >= 1")
        _positive(self, "timeout_s")
        for c in self.restricted_cells:
            if isinstance(c, bool) or not isinstance(c, int) or c < 1:
                raise ConfigError("restricted_cells", c, "cells are positive integers")
        for key in ("grace_s", "repeat_s", "confirm_s"):
            v = getattr(self, key)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ConfigError(key, v, "must be a finite number >= 0")
        if not 1 <= self.max_text_chars <= 10_000:
            raise ConfigError("max_text_chars", self.max_text_chars, "1..10000")

    @property
    def language(self) -> str:
        """The voice's language: ``en`` for ``en-gb+f3``, ``pt`` for ``pt-br``."""
        return self.voice.split("+", 1)[0].split("-", 1)[0].split("/")[-1].lower()

    @property
    def warning(self) -> str:
        """The text to say: ``warning_text``, or the built-in one for the language."""
        return self.warning_text.strip() or DEFAULT_WARNINGS[self.language]


def read_node_config(path: str, section: str, klass):
    """Read the ``grid`` section and one component section of a node's YAML file.

    Both are optional; an empty ``path`` gives the defaults.

    Returns:
        (CellGrid, klass instance).

    Raises:
        ConfigError: unreadable file or an invalid value.
    """
    from stack.cells import CellGrid

    if not path:
        return CellGrid(), klass()
    data = read_yaml(path)
    grid = CellGrid.from_mapping(data["grid"]) if "grid" in data else CellGrid()
    return grid, klass.from_dict(data.get(section))
