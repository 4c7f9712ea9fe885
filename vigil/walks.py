"""Random walks for Monte-Carlo studies: the distribution (a YAML file a user can write)
and the scenario each episode draws from it.

Every walk enters through the door, does what its *behaviour* says, and leaves through
the door. The behaviours (``behaviours:`` maps each to a weight; one is drawn per walk):

==============  ===============================================================
``targets``     one to ``targets`` targets, each a restricted cell with
                probability ``p_restricted``, else another cell (the first
                generator's walks: same seed, same walks)
``direct``      straight to a restricted cell, a stay, out
``wander``      one or two other cells first, then a restricted cell
``hesitate``    to the border of a restricted cell, a stop there, then in
``two_visits``  two restricted visits with another cell between
``decoy``       towards a restricted cell, a stop at its border, then away to
                another cell: never inside (a guard that goes is a needless trip)
``pass_by``     other cells only
==============  ===============================================================

Speeds: each walk is a *runner* with probability ``runner_share`` (speeds from
``runner_speed_mps``), a *slow walker* with probability ``slow_share`` (from
``slow_speed_mps``), else a walker (``speed_mps``); each leg draws its speed from the
walk's range. A point in a cell keeps off its borders; a border point lies
``border_gap_m`` outside the restricted cell, on the side of the cell it is reached from.

Each person of the task walks (``people`` in the file: another number of walkers, 1 to
4), each drawing a behaviour and a speed class of their own; the second and later
wait outside and set off ``start_gap_s`` after the first.

With probability ``p_fault`` an episode also has one camera or lidar outage.
Every draw comes from the episode's own generator: the same seed gives the same walks.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from stack.cells import ConfigError
from stack.planning.task import Task
from twin.config import MAX_WALK_SPEED_MPS
from vigil.scenario import Fault, Leg, Scenario, Walker

DEFAULT_WALKS = Path(__file__).resolve().parents[1] / "config" / "walks.yaml"
BEHAVIOURS = ("targets", "direct", "wander", "hesitate", "two_visits", "decoy", "pass_by")
PAIRS = (
    "speed_mps",
    "runner_speed_mps",
    "slow_speed_mps",
    "pause_s",
    "other_pause_s",
    "border_pause_s",
    "outage_s",
    "outage_at_s",
    "start_gap_s",
)


@dataclass(frozen=True)
class StudyConfig:
    """The walk distribution of a study (see the module doc; the defaults are the first
    generator's).

    Attributes:
        speed_mps, runner_speed_mps, slow_speed_mps: (low, high) walking speeds [m/s].
        runner_share, slow_share: the share of runners and of slow walkers.
        pause_s: (low, high) stay in a restricted cell [s].
        other_pause_s: (low, high) stay in another cell [s].
        border_pause_s: (low, high) stop at a restricted cell's border (hesitate, decoy).
        border_gap_m: how far outside the restricted cell a border point lies [m].
        targets: (fewest, most) targets of a ``targets`` walk.
        p_restricted: the chance that a ``targets`` target is a restricted cell.
        behaviours: behaviour -> weight.
        p_fault: the chance of one sensor outage in an episode.
        outage_s: (low, high) outage length [s]; it starts within ``outage_at_s``.
        tail_s: the episode runs this long after the person has left.
        max_sim_s: no episode runs longer (simulated seconds).
        people: walkers per episode (None: the task's ``people``), each with a walk of
            their own; the second and later set off ``start_gap_s`` after the first.
        start_gap_s: (low, high) how much later than the first each other walker starts.
    """

    speed_mps: tuple[float, float] = (0.4, 1.4)
    runner_speed_mps: tuple[float, float] = (1.6, 2.0)
    slow_speed_mps: tuple[float, float] = (0.2, 0.4)
    runner_share: float = 0.0
    slow_share: float = 0.0
    pause_s: tuple[float, float] = (2.0, 8.0)
    other_pause_s: tuple[float, float] = (0.0, 3.0)
    border_pause_s: tuple[float, float] = (1.0, 4.0)
    border_gap_m: float = 0.3
    targets: tuple[int, int] = (1, 2)
    p_restricted: float = 0.6
    behaviours: Mapping[str, float] = field(default_factory=lambda: {"targets": 1.0})
    p_fault: float = 0.25
    outage_s: tuple[float, float] = (2.0, 8.0)
    outage_at_s: tuple[float, float] = (3.0, 15.0)
    tail_s: float = 5.0
    max_sim_s: float = 60.0
    people: int | None = None
    start_gap_s: tuple[float, float] = (0.0, 10.0)

    def __post_init__(self) -> None:
        for name in PAIRS:
            pair = getattr(self, name)
            if not _pair(pair) or not 0 <= pair[0] <= pair[1]:
                raise ConfigError(name, pair, "must be [low, high], finite, 0 <= low <= high")
        for name in ("speed_mps", "runner_speed_mps", "slow_speed_mps"):
            lo, hi = getattr(self, name)
            if lo < 0.1 or hi > MAX_WALK_SPEED_MPS:
                raise ConfigError(name, (lo, hi), f"must lie in [0.1, {MAX_WALK_SPEED_MPS}] m/s")
        t = self.targets
        if not (len(t) == 2 and all(isinstance(v, int) for v in t) and 1 <= t[0] <= t[1] <= 5):
            raise ConfigError("targets", t, "must be [fewest, most] with 1 <= fewest <= most <= 5")
        for name in ("p_restricted", "p_fault", "runner_share", "slow_share"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 <= v <= 1.0):
                raise ConfigError(name, v, "must be a probability in [0, 1]")
        if self.runner_share + self.slow_share > 1.0:
            raise ConfigError("runner_share + slow_share", self.runner_share + self.slow_share,
                              "must be <= 1")  # fmt: skip
        if not (_finite(self.border_gap_m) and 0.05 <= self.border_gap_m <= 1.0):
            raise ConfigError("border_gap_m", self.border_gap_m, "must lie in [0.05, 1.0] m")
        if not isinstance(self.behaviours, Mapping) or not self.behaviours:
            raise ConfigError("behaviours", self.behaviours, "must map behaviours to weights")
        for name, w in self.behaviours.items():
            if name not in BEHAVIOURS:
                raise ConfigError(f"behaviours.{name}", w, f"unknown; one of {BEHAVIOURS}")
            if not (_finite(w) and w >= 0):
                raise ConfigError(f"behaviours.{name}", w, "must be a weight >= 0")
        if sum(self.behaviours.values()) <= 0:
            raise ConfigError("behaviours", dict(self.behaviours), "need a positive weight")
        if not (_finite(self.tail_s) and 0 <= self.tail_s <= 600):
            raise ConfigError("tail_s", self.tail_s, "must lie in [0, 600] s")
        if not (_finite(self.max_sim_s) and 0 < self.max_sim_s <= 3600):
            raise ConfigError("max_sim_s", self.max_sim_s, "must lie in (0, 3600] s")
        if self.people is not None and not (
            isinstance(self.people, int) and not isinstance(self.people, bool)
            and 1 <= self.people <= 4
        ):  # fmt: skip
            raise ConfigError("people", self.people, "must be 1 to 4 walkers (or absent)")


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _pair(v: Any) -> bool:
    return isinstance(v, tuple | list) and len(v) == 2 and all(_finite(x) for x in v)


def load_walks(path: str | Path, **overrides: Any) -> StudyConfig:
    """A walk distribution from a YAML file; errors name the file and the key.

    Keys are :class:`StudyConfig`'s; a pair is a two-element list. ``overrides`` (not
    None) replace the file's values.
    """
    from stack.config import read_yaml

    path = Path(path)
    try:
        data = dict(read_yaml(path))
    except ConfigError as err:
        raise ConfigError(f"{path}: {err.key}", err.value, err.rule) from None
    known = {f.name for f in fields(StudyConfig)}
    for key in data:
        if key not in known:
            raise ConfigError(f"{path}: {key}", data[key], f"unknown key; known: {sorted(known)}")
    data.update({k: v for k, v in overrides.items() if v is not None})
    for key in (*PAIRS, "targets"):
        if key in data:
            if not isinstance(data[key], list | tuple):
                raise ConfigError(f"{path}: {key}", data[key], "must be a [low, high] list")
            data[key] = tuple(data[key])
    if "behaviours" in data and not isinstance(data["behaviours"], dict):
        raise ConfigError(f"{path}: behaviours", data["behaviours"], "must be a mapping")
    try:
        return StudyConfig(**data)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err.key}", err.value, err.rule) from None
    except TypeError as err:
        raise ConfigError(str(path), None, f"malformed: {err}") from None


# -- drawing a walk ------------------------------------------------------------------------------


@functools.cache
def _door_m() -> tuple[float, float]:
    """Where a walk comes in: "door" of the twin's room (``vigil.scenario``)."""
    from twin.config import TwinConfig
    from twin.scene import layout_of

    x, y = layout_of(TwinConfig()).door_center_m
    return x, y - 0.8


def _uniform(rng: np.random.Generator, bounds: tuple[float, float], nd: int = 2) -> float:
    return round(float(rng.uniform(bounds[0], bounds[1])), nd)


class _Walk:
    """The legs of one walk as the behaviours add them."""

    def __init__(self, task: Task, rng: np.random.Generator, study: StudyConfig, speeds):
        self.task, self.rng, self.study, self.speeds = task, rng, study, speeds
        self.grid = task.grid
        self.legs: list[Leg] = [Leg("door", self.speed())]
        self.kinds: list[str] = []
        restricted = list(task.restricted_cells)
        self.restricted = restricted
        self.others = [c for c in self.grid.cells if c not in restricted and c != task.rest_cell]
        self.at: tuple[float, float] | None = None  # the last point walked to

    def speed(self) -> float:
        return _uniform(self.rng, self.speeds)

    def pick(self, cells: list[int]) -> int:
        return int(cells[int(self.rng.integers(len(cells)))])

    def point_in(self, cell: int) -> tuple[float, float]:
        x0, y0, x1, y1 = self.grid.bounds(cell)
        u, v = self.rng.uniform(0.25, 0.75, 2)  # keep inside the cell, off its borders
        return (round(float(x0 + u * (x1 - x0)), 2), round(float(y0 + v * (y1 - y0)), 2))

    def go(self, point: tuple[float, float], pause_s: float, kind: str) -> None:
        self.legs.append(Leg(point, self.speed(), pause_s))
        self.kinds.append(kind)
        self.at = point

    def visit(self, cell: int) -> None:
        restricted = cell in self.restricted
        point = self.point_in(cell)
        pause = _uniform(self.rng, self.study.pause_s if restricted else self.study.other_pause_s)
        self.go(point, pause, f"{'R' if restricted else 'o'}{cell}")

    def border(self, cell: int) -> tuple[float, float]:
        """A point ``border_gap_m`` outside ``cell``, on the side of the neighbour nearest
        to where the person is (the door's side on the way in)."""
        here = self.at or _door_m()
        x0, y0, x1, y1 = self.grid.bounds(cell)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        gap = self.study.border_gap_m
        sides = []
        for px, py in (((x0 - gap), cy), ((x1 + gap), cy), (cx, (y0 - gap)), (cx, (y1 + gap))):
            c = self.grid.cell_at(px, py)
            if c is not None and c not in self.restricted:
                sides.append((math.dist((px, py), here), (px, py)))
        if not sides:
            raise ConfigError("behaviours", cell, "restricted cell with no free side to stop at")
        _, (px, py) = min(sides)
        # anywhere along that side, off the corners
        if px in (x0 - gap, x1 + gap):
            py = float(self.rng.uniform(y0 + 0.2 * (y1 - y0), y1 - 0.2 * (y1 - y0)))
        else:
            px = float(self.rng.uniform(x0 + 0.2 * (x1 - x0), x1 - 0.2 * (x1 - x0)))
        return (round(px, 2), round(py, 2))

    def stop_at_border(self, cell: int, kind: str) -> None:
        self.go(self.border(cell), _uniform(self.rng, self.study.border_pause_s), kind)


def _behave(w: _Walk, behaviour: str) -> None:
    s, rng = w.study, w.rng
    if behaviour == "targets":
        for _ in range(int(rng.integers(s.targets[0], s.targets[1] + 1))):
            w.visit(w.pick(w.restricted if rng.random() < s.p_restricted else w.others))
    elif behaviour == "direct":
        w.visit(w.pick(w.restricted))
    elif behaviour == "wander":
        for _ in range(int(rng.integers(1, 3))):
            w.visit(w.pick(w.others))
        w.visit(w.pick(w.restricted))
    elif behaviour == "hesitate":
        cell = w.pick(w.restricted)
        w.stop_at_border(cell, f"h{cell}")
        w.visit(cell)
    elif behaviour == "two_visits":
        w.visit(w.pick(w.restricted))
        w.visit(w.pick(w.others))
        w.visit(w.pick(w.restricted))
    elif behaviour == "decoy":
        cell = w.pick(w.restricted)
        w.stop_at_border(cell, f"d{cell}")
        w.visit(w.pick(w.others))
    elif behaviour == "pass_by":
        for _ in range(int(rng.integers(1, 3))):
            w.visit(w.pick(w.others))
    else:  # pragma: no cover - StudyConfig refuses unknown behaviours
        raise ConfigError("behaviours", behaviour, "unknown")


def random_scenario(
    task_path: Path, task: Task, rng: np.random.Generator, index: int, study: StudyConfig
) -> Scenario:
    """One random walk (and maybe a fault) as a scenario; every draw from ``rng``.

    The robot starts at the task's rest cell; the planner believes nobody is there.
    """
    walkers: list[tuple[tuple[Leg, ...], str]] = [_draw_walk(task, rng, study)]
    for _ in range((study.people or task.people) - 1):
        legs, what = _draw_walk(task, rng, study)
        gap = _uniform(rng, study.start_gap_s)  # then this walker sets off
        walkers.append(((Leg("outside", legs[0].speed_mps, gap), *legs), what))
    faults: list[Fault] = []
    fault = ""
    if rng.random() < study.p_fault:
        kind = "camera_off" if rng.random() < 0.5 else "lidar_off"
        at, dur = _uniform(rng, study.outage_at_s), _uniform(rng, study.outage_s)
        faults.append(Fault(kind, at_s=at, duration_s=dur))
        fault = f" {kind.split('_')[0]}-{dur:g}s"
    others = "".join(f" | {what}" for _, what in walkers[1:])
    return Scenario(
        name=f"mc-{index:03d}",
        title=f"random walk {index}: {walkers[0][1]}{fault}{others}",
        task=Path(task_path).resolve(),
        seed=int(rng.integers(0, 2**31 - 1)),
        steps=0,  # until the episode ends
        robot_cell=task.rest_cell,
        belief_person=None,
        belief_direction="not moving",
        start="outside",
        walk=walkers[0][0],
        faults=tuple(faults),
        others=tuple(Walker("outside", legs) for legs, _ in walkers[1:]),
    )


def _draw_walk(
    task: Task, rng: np.random.Generator, study: StudyConfig
) -> tuple[tuple[Leg, ...], str]:
    """One walker's walk from the door and back out: its legs and its description
    ("runner decoy d1 o6": speed class, behaviour, the stops)."""
    names = [b for b in BEHAVIOURS if study.behaviours.get(b, 0) > 0]
    behaviour = "targets"
    if names != ["targets"]:  # one behaviour alone draws nothing (the first generator's walks)
        weights = np.array([study.behaviours[b] for b in names], float)
        behaviour = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    speeds, tag = study.speed_mps, ""
    if study.runner_share > 0 or study.slow_share > 0:
        u = rng.random()
        if u < study.runner_share:
            speeds, tag = study.runner_speed_mps, "runner "
        elif u < study.runner_share + study.slow_share:
            speeds, tag = study.slow_speed_mps, "slow "
    w = _Walk(task, rng, study, speeds)
    _behave(w, behaviour)
    speed = w.speed()
    label = "" if behaviour == "targets" else f"{behaviour} "
    legs = (*w.legs, Leg("door", speed), Leg("outside", speed))
    return legs, f"{tag}{label}" + " ".join(w.kinds)
