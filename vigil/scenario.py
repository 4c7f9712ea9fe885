"""A scenario file: one experiment of chapter 5 (or a new one), end to end.

A scenario names the task, the robot's start cell, the planner's initial belief
about the person, the person's walk in the twin, how many decision steps to run, the
seed, and faults to inject. Waypoints are written in the terms the thesis uses::

    name: "5.2.2"
    title: Experiment 2 with two restricted areas
    thesis_table: "5.4"          # the table to set beside the run's (stack.planning.replay)
    task: ../config/task-r2.yaml # relative to this file
    seed: 0
    steps: 17
    robot_cell: 9
    belief: {person: none, direction: not moving}   # the planner's initial belief
    person:
      start: outside             # outside | door | a cell | [x, y]
      walk:
        - {to: door, speed_mps: 1.0}
        - {to: 1, speed_mps: 0.6, pause_s: 8}  # a cell's centre
        - {to: [2.3, 0.4], speed_mps: 0.4}       # a map point [m]
        - {to: outside, speed_mps: 1.0}
    faults:
      - {kind: camera_off, at_s: 20, duration_s: 4}
      - {kind: lidar_off, at_s: 30, duration_s: 5}
      - {kind: kill, node: planner, after_step: 3}
      - {kind: obstacle, cell: 5}               # a box on the cell's waypoint

"door" is just inside the doorway, "outside" beyond it (the person is out of the
room and out of the camera's view). Errors name the key and the rule
(:class:`stack.cells.ConfigError`).

Several people (issue 16): ``people:`` is a list of walks, each with its own
``start`` and ``walk`` (the same keys as ``person:``); a file gives ``person:`` or
``people:``, not both. ``belief`` is then every person's initial belief::

    task: ../../config/task-r2-n2.yaml
    people:
      - {start: outside, walk: [{to: door}, {to: 1, speed_mps: 0.8, pause_s: 6}]}
      - start: outside
        walk:
          - {to: door, speed_mps: 0.9}
          - {to: 12, speed_mps: 0.8, pause_s: 6}

Errors name the key as ``people[1].walk[0].to``. :attr:`Scenario.walkers` lists
every person's walk; ``start`` and ``walk`` are the first person's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stack.cells import CellGrid, ConfigError
from stack.config import read_yaml
from twin.config import MAX_WALK_SPEED_MPS

FAULT_KINDS = ("camera_off", "lidar_off", "kill", "obstacle")
# the twin-mode nodes a kill fault may name (vigil.system starts them; the bridge and the
# recorder are not restarted, so killing them would end the run, not test a restart)
KILLABLE = ("camera_people", "legs", "observations", "navigation", "speech", "planner")
DIRECTIONS = ("north", "south", "east", "west", "not moving")
MAX_SEED = 2**32 - 1  # numpy's legacy seeds and every ROS integer parameter take it
MAX_STEPS = 10_000  # decision steps of one run (each takes seconds of simulated time)
MAX_TIME_S = 1e6  # fault times, durations and pauses [s]
MAX_COORD_M = 1e3  # a map point's coordinates [m]
MAX_CELL = 10**6  # a cell number (then checked against the task's grid)


@dataclass(frozen=True)
class Leg:
    """One leg of the person's walk: go to ``to`` at ``speed_mps``, wait ``pause_s``."""

    to: Any  # "door" | "outside" | int cell | (x, y)
    speed_mps: float = 1.0
    pause_s: float = 0.0


@dataclass(frozen=True)
class Walker:
    """One person's walk: where they start and the legs they walk."""

    start: Any  # "door" | "outside" | int cell | (x, y)
    walk: tuple[Leg, ...]


@dataclass(frozen=True)
class Fault:
    kind: str
    at_s: float = 0.0
    duration_s: float = 0.0
    node: str = ""
    after_step: int = 0
    cell: int = 0


@dataclass(frozen=True)
class Scenario:
    name: str
    title: str
    task: Path
    seed: int
    steps: int
    robot_cell: int
    belief_person: int | None
    belief_direction: str
    start: Any
    walk: tuple[Leg, ...]
    faults: tuple[Fault, ...] = ()
    thesis_table: str = ""
    source: Path | None = None
    others: tuple[Walker, ...] = ()  # the second, third, ... person (``people:``)

    @property
    def walkers(self) -> tuple[Walker, ...]:
        """Every person's walk, the first (``start``, ``walk``) first."""
        return (Walker(self.start, self.walk), *self.others)

    def people_waypoints(
        self, grid: CellGrid, door_m: tuple[float, float], inside_m: float = 0.8
    ) -> list[list[dict[str, float]]]:
        """Every person's walk as twin waypoints (see :meth:`person_waypoints`)."""
        return [
            _waypoints(w, grid, door_m, inside_m, "person" if not self.others else f"people[{i}]")
            for i, w in enumerate(self.walkers)
        ]

    def person_waypoints(
        self, grid: CellGrid, door_m: tuple[float, float], inside_m: float = 0.8
    ) -> list[dict[str, float]]:
        """The (first) person's walk as twin waypoints (``twin.config.Waypoint`` mappings).

        Args:
            grid: the cell geometry.
            door_m: the doorway's centre on the north wall (twin SceneLayout.door_center_m).
            inside_m: how far inside the room "door" is (outside is 1.5 times that).
        """
        return self.people_waypoints(grid, door_m, inside_m)[0]


def _waypoints(
    walker: Walker, grid: CellGrid, door_m: tuple[float, float], inside_m: float, key: str
) -> list[dict[str, float]]:
    def point(to: Any, key: str) -> tuple[float, float]:
        if to == "door":
            return door_m[0], door_m[1] - inside_m
        if to == "outside":
            return door_m[0], door_m[1] + 1.5 * inside_m
        if isinstance(to, int):
            if to not in grid.cells:
                raise ConfigError(key, to, f"not a cell of the grid {grid.cells}")
            return grid.center(to)
        return float(to[0]), float(to[1])

    x0, y0 = point(walker.start, f"{key}.start")
    wps = [{"x_m": x0, "y_m": y0, "pause_s": 0.0}]
    for i, leg in enumerate(walker.walk):
        x, y = point(leg.to, f"{key}.walk[{i}].to")
        wps.append({"x_m": x, "y_m": y, "speed_mps": leg.speed_mps, "pause_s": leg.pause_s})
    return wps


def _where(value: Any, key: str, cells: frozenset[int] | None = None) -> Any:
    """door, outside, a cell of the task (``cells``; None: any cell number) or a finite
    map point [x, y]."""
    if isinstance(value, str) and value in ("door", "outside"):
        return value
    if isinstance(value, bool):
        raise ConfigError(key, value, "must be door, outside, a cell number or [x, y]")
    if isinstance(value, int):
        if cells is not None and value not in cells:
            raise ConfigError(key, value, f"not a cell of the task's grid {_span(cells)}")
        return value
    if (
        isinstance(value, list | tuple)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        if not all(math.isfinite(v) and abs(v) <= MAX_COORD_M for v in value):
            raise ConfigError(key, value, f"a map point needs finite |x|, |y| <= {MAX_COORD_M:g} m")
        return (float(value[0]), float(value[1]))
    raise ConfigError(key, value, "must be door, outside, a cell number or [x, y]")


def _span(cells: frozenset[int]) -> str:
    return f"({min(cells)}..{max(cells)})" if cells else "(none)"


def _number(
    data: dict,
    key: str,
    default: float,
    prefix: str,
    minimum: float = 0.0,
    maximum: float = MAX_TIME_S,
) -> float:
    """A finite number in [minimum, maximum] (NaN and inf never pass)."""
    v = data.get(key, default)
    if (
        isinstance(v, bool)
        or not isinstance(v, int | float)
        or not math.isfinite(v)
        or not minimum <= v <= maximum
    ):
        raise ConfigError(f"{prefix}.{key}", v, f"must be a number in [{minimum:g}, {maximum:g}]")
    return float(v)


def _integer(value: Any, key: str, low: int, high: int) -> int:
    """An integer (not a bool, not a float) in [low, high]."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(key, value, f"must be an integer in [{low}, {high}]")
    return value


def _task_cells(task: Path) -> frozenset[int]:
    """The cells of the task file's grid; the task is read and checked here."""
    from stack.planning.task import load_task

    try:
        return frozenset(load_task(task).grid.cells)
    except ConfigError as err:
        raise ConfigError("task", str(task), f"is not a valid task: {err}") from None
    except (OSError, ValueError) as err:
        raise ConfigError("task", str(task), f"cannot be read: {err}") from None


def _check_keys(data: Any, known: set[str], prefix: str) -> dict:
    if not isinstance(data, dict):
        raise ConfigError(prefix, data, "must be a mapping")
    for k in data:
        if k not in known:
            raise ConfigError(f"{prefix}.{k}", data[k], f"unknown key (known: {sorted(known)})")
    return data


def parse_scenario(data: Any, source: Path | None = None) -> Scenario:
    """Validate a scenario mapping.

    Raises:
        ConfigError: naming the key, the value and the rule.
    """
    known = {"name", "title", "thesis_table", "task", "seed", "steps", "robot_cell"}
    known |= {"belief", "person", "people", "faults"}
    d = _check_keys(data, known, "scenario")
    if "person" in d and "people" in d:
        raise ConfigError("people", d["people"], "give either person (one) or people (a list)")
    for key in ("name", "task"):
        if not isinstance(d.get(key), str) or not d[key]:
            raise ConfigError(key, d.get(key), "must be a non-empty string")
    name = d["name"]
    # the default run folder is runs/<name>: one plain folder name, nothing that climbs
    if name in (".", "..") or any(c in name for c in "/\\\0") or len(name) > 100:
        raise ConfigError("name", name, "must be a plain folder name (no / or \\, not . or ..)")
    for key in ("title", "thesis_table"):
        if key in d and not isinstance(d[key], str):
            raise ConfigError(key, d[key], "must be a string")
    table = d.get("thesis_table", "")
    if table:
        from stack.planning.replay import TABLES

        if table not in TABLES:
            raise ConfigError("thesis_table", table, f"unknown table (one of {sorted(TABLES)})")
    task = Path(d["task"])
    if not task.is_absolute() and source is not None:
        task = source.parent / task
    if not task.exists():
        raise ConfigError("task", str(task), "file not found")
    cells = _task_cells(task)
    seed = _integer(d.get("seed", 0), "seed", 0, MAX_SEED)
    steps = _integer(d.get("steps", 10), "steps", 1, MAX_STEPS)
    robot_cell = _integer(d.get("robot_cell", 7), "robot_cell", 1, MAX_CELL)
    if robot_cell not in cells:
        raise ConfigError("robot_cell", robot_cell, f"not a cell of the task's grid {_span(cells)}")
    belief = _check_keys(d.get("belief", {}), {"person", "direction"}, "belief")
    person = belief.get("person", "none")
    if person in ("none", None):
        person = None
    elif isinstance(person, bool) or not isinstance(person, int) or person not in cells:
        raise ConfigError(
            "belief.person", person, f"must be a cell of the task's grid {_span(cells)} or none"
        )
    direction = belief.get("direction", "not moving")
    if not isinstance(direction, str) or direction.lower() not in DIRECTIONS:
        raise ConfigError("belief.direction", direction, f"must be one of {DIRECTIONS}")
    direction = direction.lower()
    if "people" in d:
        raw_people = d["people"]
        if not isinstance(raw_people, list) or not raw_people:
            raise ConfigError("people", raw_people, "must be a non-empty list of walks")
        walkers = [_walker(w, f"people[{i}]", cells) for i, w in enumerate(raw_people)]
    else:
        walkers = [_walker(d.get("person", {}), "person", cells)]
    faults = []
    raw_faults = d.get("faults", []) or []
    if not isinstance(raw_faults, list):
        raise ConfigError("faults", raw_faults, "must be a list")
    for i, f in enumerate(raw_faults):
        key = f"faults[{i}]"
        f = _check_keys(f, {"kind", "at_s", "duration_s", "node", "after_step", "cell"}, key)
        kind = f.get("kind")
        if not isinstance(kind, str) or kind not in FAULT_KINDS:
            raise ConfigError(f"{key}.kind", kind, f"must be one of {FAULT_KINDS}")
        node = f.get("node", "")
        if not isinstance(node, str):
            raise ConfigError(f"{key}.node", node, "must be a node's name")
        fault = Fault(
            kind,
            _number(f, "at_s", 0, key),
            _number(f, "duration_s", 0, key),
            node,
            _integer(f.get("after_step", 0), f"{key}.after_step", 0, steps),
            _integer(f.get("cell", 0), f"{key}.cell", 0, MAX_CELL),
        )
        if kind == "kill" and (not fault.node or fault.after_step < 1):
            raise ConfigError(key, f, "kill needs node and after_step >= 1")
        if kind == "kill" and fault.node not in KILLABLE:
            raise ConfigError(
                f"{key}.node", fault.node, f"unknown node (one of {', '.join(KILLABLE)})"
            )
        if kind in ("camera_off", "lidar_off") and fault.duration_s <= 0:
            raise ConfigError(f"{key}.duration_s", fault.duration_s, "must be > 0")
        if kind == "obstacle" and fault.cell not in cells:
            raise ConfigError(
                f"{key}.cell", fault.cell, f"must name a cell of the task's grid {_span(cells)}"
            )
        faults.append(fault)
    return Scenario(
        name=name,
        title=str(d.get("title", name)),
        task=task.resolve(),
        seed=seed,
        steps=steps,
        robot_cell=robot_cell,
        belief_person=person,
        belief_direction=direction,
        start=walkers[0].start,
        walk=walkers[0].walk,
        faults=tuple(faults),
        thesis_table=str(d.get("thesis_table", "")),
        source=source,
        others=tuple(walkers[1:]),
    )


def _walker(data: Any, prefix: str, cells: frozenset[int] | None = None) -> Walker:
    """One ``person:`` mapping (or one entry of ``people:``), keys named from ``prefix``."""
    p = _check_keys(data, {"start", "walk"}, prefix)
    start = _where(p.get("start", "outside"), f"{prefix}.start", cells)
    walk = []
    legs = p.get("walk", [])
    if not isinstance(legs, list):
        raise ConfigError(f"{prefix}.walk", legs, "must be a list of legs")
    for i, leg in enumerate(legs):
        key = f"{prefix}.walk[{i}]"
        leg = _check_keys(leg, {"to", "speed_mps", "pause_s"}, key)
        speed = _number(leg, "speed_mps", 1.0, key, 0.1, MAX_WALK_SPEED_MPS)
        to = _where(leg.get("to"), f"{key}.to", cells)
        walk.append(Leg(to, speed, _number(leg, "pause_s", 0, key)))
    return Walker(start, tuple(walk))


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (see the module docstring).

    Every value is checked here, before any process starts: numbers finite and in
    range, integers integral, cells cells of the task's grid (the task file is read and
    checked too), the seed in [0, 2^32 - 1], the name a plain folder name.

    Raises:
        ConfigError: naming the key, the value and the rule.
    """
    path = Path(path).resolve()
    return parse_scenario(read_yaml(path), path)
