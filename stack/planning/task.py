"""The task file: the thesis's POMDP task (chapter 3, section 4.2) as validated dataclasses.

A task file is YAML with these sections (see ``config/task-r1.yaml`` and
``docs/MODEL.md`` for every parameter and the sentence of the thesis behind it):

- ``grid``: the cells (numbering, metric size; :class:`stack.cells.CellGrid`);
- ``restricted_cells``, ``rest_cell`` (a cell, or ``auto``: where a guard waits,
  :func:`stack.planning.standby.watch_cell`), ``people``, ``discount``;
- ``rewards``: table 4.1;
- ``robot``: the robot's transition model (figures A.5-A.6);
- ``person``: a person's direction and position transition models (section 3.2.1);
- ``observation``: the person's position and velocity observation models (section 3.2.4).

Every section is a :class:`stack.config.Config` dataclass, checked whether read from a
file or built in code; a bad value raises :class:`stack.cells.ConfigError`
naming the key, the value and the rule it breaks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from stack.cells import CellGrid, ConfigError
from stack.config import Config, from_mapping, load_yaml, read_text_capped
from stack.planning.anticipate import PERSON_MODELS, AnticipationConfig
from stack.planning.standby import watch_cell

DIRECTION_NAMES = ("north", "south", "east", "west", "not moving")

# per-field ranges (the task's cross-field rules are in _check_models)
_PROBABILITY = (lambda v: 0.0 < v <= 1.0, "must be a probability in (0, 1]")
_SHARE = (lambda v: 0.0 <= v <= 1.0, "must be a probability in [0, 1]")
_WEIGHT = (lambda v: v >= 0.0, "must be >= 0")
_CELL = (lambda v: v >= 1, "must be a cell number (>= 1)")


@dataclass(frozen=True)
class Rewards(Config):
    """Table 4.1 plus the move cost of section 4.2."""

    move: float = -0.2  # every North/South/East/West action
    rest_cell: float = 0.0  # robot at the rest (equidistant) cell
    restricted_guarded: float = 30.0  # robot at a restricted cell and a person at or heading to it
    restricted_idle: float = -10.0  # robot at a restricted cell, nobody there or heading there
    out_of_map: float = -30.0  # robot outside the map
    other_cell: float = -3.0  # robot anywhere else


@dataclass(frozen=True)
class RobotModel(Config):
    """The robot's position transition (section 3.2.1, appendix A figures A.5-A.6)."""

    move_success: float = 0.95  # reaches the neighbouring cell (or leaves the map at an edge)

    _rules = {"move_success": _PROBABILITY}


@dataclass(frozen=True)
class DirectionModel(Config):
    """P(D' | D): a person's movement direction from one decision step to the next.

    For a moving person: keep the direction, turn to each perpendicular one, turn
    back (the least likely, section 3.2.1), or stop (the remainder). A person at
    rest stays at rest or starts in any of the four directions alike.
    """

    keep: float = 0.6
    turn: float = 0.1  # each of the two perpendicular directions
    reverse: float = 0.05
    rest_stay: float = 0.7  # P(not moving -> not moving)

    _rules = dict.fromkeys(("keep", "turn", "reverse", "rest_stay"), _PROBABILITY)


@dataclass(frozen=True)
class PositionModel(Config):
    """P(P' | P, D): a person's cell from one decision step to the next.

    Weights (normalised per row) for where a person in a cell ends up, by the
    direction they were moving in. ``floor`` is spread over every cell so that no
    position is impossible (section 3.2.4: avoid zero probabilities).
    """

    moving_stay: float = 0.35  # still in the same cell (cells are large, section 3.2.1)
    moving_ahead: float = 0.45  # the adjacent cell in the direction of motion
    moving_ahead2: float = 0.1  # two cells ahead
    moving_side: float = 0.03  # each other 4-neighbour
    moving_diagonal: float = 0.02  # each diagonal neighbour ahead
    rest_stay: float = 0.9  # a resting person stays in the cell
    rest_side: float = 0.02  # each 4-neighbour of a resting person
    rest_diagonal: float = 0.005  # each diagonal neighbour of a resting person
    leave: float = 0.01  # leaves the region from any cell
    leave_at_edge: float = 0.5  # share of a move off the region's edge that leaves the region
    enter: float = 0.2  # P(no person -> a person somewhere), spread over the cells
    floor: float = 0.002  # total weight spread over all cells

    _rules = {
        **dict.fromkeys(
            ("moving_stay", "moving_ahead", "moving_ahead2", "moving_side", "moving_diagonal"),
            _WEIGHT,
        ),
        **dict.fromkeys(("rest_stay", "rest_side", "rest_diagonal", "floor"), _WEIGHT),
        **dict.fromkeys(("leave", "leave_at_edge", "enter"), _SHARE),
    }


@dataclass(frozen=True)
class PositionObservationModel(Config):
    """P(O_P | P'): the camera's cell for a person (section 3.2.4)."""

    correct: float = 0.8  # the true cell
    miss: float = 0.05  # a person present but not detected: "No person"
    near_decay: float = 0.2  # relative weight of a cell one step further away
    false_positive: float = 0.05  # nobody there, yet a cell is reported (spread uniformly)

    _rules = {
        **dict.fromkeys(("correct", "miss", "false_positive"), _PROBABILITY),
        "near_decay": (lambda v: v > 0, "must be > 0"),
    }


@dataclass(frozen=True)
class VelocityObservationModel(Config):
    """P(O_V | P', D'): direction and speed class observed for a person (section 3.2.4).

    The observed direction is the true one, a perpendicular one, the opposite one,
    or "Not moving"; the speed class given a direction is drawn from ``moving_speed``
    (for the true direction of a moving person: higher speeds likelier) or
    ``other_speed`` (slow speeds likelier).
    """

    moving_direction: float = 0.7  # observed direction = true direction
    moving_turn: float = 0.06  # each perpendicular direction
    moving_reverse: float = 0.02
    # remainder: "Not moving"
    moving_speed: tuple[float, float, float] = (0.5, 0.3, 0.2)  # higher, 0.2-0.7, 0-0.2
    other_speed: tuple[float, float, float] = (0.1, 0.3, 0.6)
    rest_not_moving: float = 0.7  # a resting person observed "Not moving"
    absent_not_moving: float = 0.97  # nobody there: "Not moving"

    _rules = dict.fromkeys(
        (
            "moving_direction",
            "moving_turn",
            "moving_reverse",
            "rest_not_moving",
            "absent_not_moving",
        ),
        _PROBABILITY,
    )


@dataclass(frozen=True)
class Initial(Config):
    """The initial state, known with certainty as in every experiment of chapter 5."""

    robot: int = 7  # robot cell
    person: int | None = 11  # person cell, None for "no person"

    _rules = {"robot": _CELL, "person": _CELL}
    direction: str = "not moving"  # north, south, east, west or not moving


def _auto_rest_cell(data: Mapping[str, Any]) -> int:
    """``rest_cell: auto``: :func:`stack.planning.standby.watch_cell` of the file's
    grid, restricted cells and, from its ``anticipation`` section, the room's exits and
    the robot's trip speed (0, refused by :meth:`Task.check` with the real error, when
    they are not valid)."""
    grid = from_mapping(CellGrid, data.get("grid"), "grid")
    restricted = data.get("restricted_cells", Task.restricted_cells)
    if not isinstance(restricted, (list, tuple)) or not all(
        type(c) is int and c in grid.cells for c in restricted
    ):
        return 0
    try:
        ant = from_mapping(AnticipationConfig, data.get("anticipation"), "anticipation")
    except ConfigError:
        return 0
    try:
        return watch_cell(grid, tuple(restricted), ant.exits_m, ant.robot_speed_mps, ant.motion)
    except ValueError:
        return 0


@dataclass(frozen=True)
class Task(Config):
    """Everything needed to build the POMDP of a task."""

    name: str = "task"
    grid: CellGrid = field(default_factory=CellGrid)
    restricted_cells: tuple[int, ...] = (1,)
    rest_cell: int = 7
    people: int = 1
    discount: float = 0.99
    rewards: Rewards = field(default_factory=Rewards)
    robot: RobotModel = field(default_factory=RobotModel)
    direction: DirectionModel = field(default_factory=DirectionModel)
    position: PositionModel = field(default_factory=PositionModel)
    obs_position: PositionObservationModel = field(default_factory=PositionObservationModel)
    obs_velocity: VelocityObservationModel = field(default_factory=VelocityObservationModel)
    initial: Initial = field(default_factory=Initial)
    # the person model of the run-time layer (not of the POMDP): "thesis" (the policy
    # alone) or "goal" (stack.planning.anticipate: head for the cell a person walks to)
    person_model: str = "thesis"
    anticipation: AnticipationConfig = field(default_factory=AnticipationConfig)

    def check(self) -> None:
        cells = set(self.grid.cells)
        if not self.restricted_cells:
            raise ConfigError(
                "restricted_cells", list(self.restricted_cells), "needs at least one cell"
            )
        for c in self.restricted_cells:
            if c not in cells:
                raise ConfigError(
                    "restricted_cells", c, f"is not a cell of the grid (1..{len(cells)})"
                )
        if len(set(self.restricted_cells)) != len(self.restricted_cells):
            raise ConfigError("restricted_cells", list(self.restricted_cells), "lists a cell twice")
        if self.rest_cell not in cells:
            raise ConfigError(
                "rest_cell", self.rest_cell, f"is not a cell of the grid (1..{len(cells)})"
            )
        if self.rest_cell in self.restricted_cells:
            raise ConfigError("rest_cell", self.rest_cell, "must not be a restricted cell")
        if not isinstance(self.people, int) or isinstance(self.people, bool) or self.people < 1:
            raise ConfigError("people", self.people, "must be a positive integer")
        if not 0.0 < self.discount < 1.0:
            raise ConfigError(
                "discount", self.discount, "must be in (0, 1) for an infinite horizon"
            )
        _check_models(self)
        ini = self.initial
        if ini.robot not in cells:
            raise ConfigError("initial.robot", ini.robot, "is not a cell of the grid")
        if ini.person is not None and ini.person not in cells:
            raise ConfigError("initial.person", ini.person, "is not a cell of the grid (or 'none')")
        if self.person_model not in PERSON_MODELS:
            raise ConfigError("person_model", self.person_model, f"must be one of {PERSON_MODELS}")
        if ini.direction not in DIRECTION_NAMES:
            raise ConfigError(
                "initial.direction", ini.direction, f"must be one of {DIRECTION_NAMES}"
            )

    def replace(self, **changes: Any) -> Task:
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, key: str | None = None) -> Task:
        """Build and validate a task from a parsed YAML mapping.

        Raises:
            ConfigError: for an unknown key, a wrong type or a value out of range.
        """
        if not isinstance(data, Mapping):
            raise ConfigError("task", data, "must be a mapping")
        data = {k: v for k, v in data.items() if k != "observations"}  # older files
        if isinstance(data.get("initial"), Mapping):
            data["initial"] = _initial_labels(data["initial"])
        if data.get("rest_cell") == "auto":
            data["rest_cell"] = _auto_rest_cell(data)
        return from_mapping(cls, data, "")

    def to_dict(self) -> dict[str, Any]:
        """The task as plain data, in the layout of a task file."""
        out: dict[str, Any] = {
            "name": self.name,
            "grid": {
                "numbering": [list(r) for r in self.grid.numbering],
                "cell_size_m": list(self.grid.cell_size_m),
                "origin_m": list(self.grid.origin_m),
            },
            "restricted_cells": list(self.restricted_cells),
            "rest_cell": self.rest_cell,
            "people": self.people,
            "discount": self.discount,
        }
        for key in ("rewards", "robot", "direction", "position", "obs_position", "obs_velocity"):
            sec = dataclasses.asdict(getattr(self, key))
            out[key] = {k: list(v) if isinstance(v, tuple) else v for k, v in sec.items()}
        if self.person_model != "thesis":
            out["person_model"] = self.person_model
            out["anticipation"] = dataclasses.asdict(self.anticipation)
        ini = self.initial
        out["initial"] = {
            "robot": ini.robot,
            "person": "none" if ini.person is None else ini.person,
            "direction": ini.direction,
        }
        return out


def load_task(path: str | Path) -> Task:
    """Read and validate a task file.

    Raises:
        FileNotFoundError: no such file.
        ConfigError: the file is not valid YAML or a value breaks a rule.
    """
    path = Path(path)
    try:
        text = read_text_capped(path)
    except ValueError as exc:
        raise ConfigError(str(path), "<file>", str(exc)) from None
    try:
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(str(path), "<file>", f"is not valid YAML: {exc}") from None
    if data is None:
        raise ConfigError(str(path), "<empty>", "a task file needs at least a grid")
    return Task.from_dict(data)


# -- validation helpers -----------------------------------------------------------


def _initial_labels(data: Mapping[str, Any]) -> dict[str, Any]:
    """The initial state's labels in the file's spelling -> the dataclass's values:
    person "none" / "no person" -> None, direction "Not_Moving" -> "not moving"."""
    out = dict(data)
    v = out.get("person")
    if isinstance(v, str) and v.lower() in ("none", "no person"):
        out["person"] = None
    d = out.get("direction")
    if isinstance(d, str):
        out["direction"] = d.lower().replace("_", " ")
    return out


def _prob(key: str, v: float, *, positive: bool = False) -> None:
    if not 0.0 <= v <= 1.0:
        raise ConfigError(key, v, "must be a probability in [0, 1]")
    if positive and v <= 0.0:
        raise ConfigError(key, v, "must be > 0 (the thesis avoids zero probabilities)")


def _check_models(task: Task) -> None:
    d = task.direction
    for name in ("keep", "turn", "reverse", "rest_stay"):
        _prob(f"direction.{name}", getattr(d, name), positive=True)
    stop = 1.0 - d.keep - 2 * d.turn - d.reverse
    if stop <= 0.0:
        raise ConfigError(
            "direction",
            dataclasses.asdict(d),
            "keep + 2 turn + reverse must be < 1 (stopping needs a chance)",
        )
    if d.reverse > d.turn or d.reverse > d.keep:
        raise ConfigError(
            "direction.reverse", d.reverse, "turning back must be the least likely change (3.2.1)"
        )
    if d.rest_stay >= 1.0:
        raise ConfigError(
            "direction.rest_stay", d.rest_stay, "must be < 1 (a resting person may start)"
        )

    p = task.position
    for name in dataclasses.asdict(p):
        v = getattr(p, name)
        if v < 0:
            raise ConfigError(f"position.{name}", v, "must be >= 0")
    for name in ("leave", "leave_at_edge", "enter"):
        _prob(f"position.{name}", getattr(p, name))
    if p.moving_stay + p.moving_ahead <= 0 or p.rest_stay <= 0:
        raise ConfigError("position", dataclasses.asdict(p), "stay/ahead weights must not all be 0")
    if p.floor <= 0:
        raise ConfigError("position.floor", p.floor, "must be > 0 (no cell may be impossible)")

    if not 0.0 < task.robot.move_success <= 1.0:
        raise ConfigError("robot.move_success", task.robot.move_success, "must be in (0, 1]")

    op = task.obs_position
    for name in ("correct", "miss", "false_positive"):
        _prob(f"obs_position.{name}", getattr(op, name), positive=True)
    if op.correct + op.miss >= 1.0:
        raise ConfigError("obs_position", dataclasses.asdict(op), "correct + miss must be < 1")
    if op.near_decay <= 0:
        raise ConfigError("obs_position.near_decay", op.near_decay, "must be > 0")

    ov = task.obs_velocity
    for name in (
        "moving_direction",
        "moving_turn",
        "moving_reverse",
        "rest_not_moving",
        "absent_not_moving",
    ):
        _prob(f"obs_velocity.{name}", getattr(ov, name), positive=True)
    if ov.moving_direction + 2 * ov.moving_turn + ov.moving_reverse >= 1.0:
        raise ConfigError(
            "obs_velocity",
            dataclasses.asdict(ov),
            "direction shares must leave room for 'Not moving'",
        )
    for name in ("moving_speed", "other_speed"):
        v = getattr(ov, name)
        if any(x <= 0 for x in v):
            raise ConfigError(f"obs_velocity.{name}", list(v), "speed class shares must be > 0")
    if ov.rest_not_moving >= 1.0 or ov.absent_not_moving >= 1.0:
        raise ConfigError("obs_velocity", dataclasses.asdict(ov), "'Not moving' shares must be < 1")
