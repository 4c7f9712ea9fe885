"""The motion and observation model of goal inference: goals, the Boltzmann-rational
step likelihood, and track estimates turned into displacements.

See :mod:`stack.planning.intent` for the model in words. Pure numpy.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from stack.cells import CellGrid, ConfigError
from stack.config import Config, setting

__all__ = [
    "WANDER",
    "Goal",
    "IntentConfig",
    "TrackObservation",
    "boltzmann_likelihood",
    "distances_to",
    "goal_spots",
    "make_goals",
    "spot_likelihood",
    "step_progress",
]

WANDER = "wander"
SMOOTHING_S = 0.3  # time constant of the position smoothing when a track has no velocity [s]
# A position further from the last than a person can walk (this speed times the time
# between them, plus the slack) is a false detection, unless the next one agrees with it
JUMP_SPEED_MPS = 3.0
JUMP_SLACK_M = 0.5


@dataclass(frozen=True)
class IntentConfig(Config):
    """Parameters of goal inference (a task's or a planner's ``intent`` section).

    Attributes:
        rationality_per_m: beta, the Boltzmann rationality [1/m]: how strongly a
            person's steps point along the shortest path to their goal.
        lapse: share of steps that ignore the goal (noise, sidesteps), in [0, 1).
        restricted_prior: prior probability that the person is heading for a
            restricted cell (shared equally by the restricted cells).
        wander_share: share of the "elsewhere" prior given to wandering with no goal;
            the rest is spread over the other cells and the exits.
        exit_share: of that rest, the share of the exits (each exit an equal part;
            the other cells share the remainder): leaving is one of the commonest
            reasons to walk, not one destination among a dozen cells.
        other_cells_as_goals: the non-restricted cells are destinations of "elsewhere".
        switch_rate_per_s: rate at which a person draws a new goal from the prior; it
            is what makes the belief diffuse toward the prior without observations.
        stop_speed_mps: below this speed a person is stopped and shows no direction.
        position_step_m: with positions only (no velocity), the displacement of the
            smoothed position used as one piece of evidence (smaller displacements are
            the track's jitter). 0.15 m: the belief moves within a step or two of a
            person setting off (0.3 m cost a third of a second more; on 1,000 r2 walks
            0.15 m was first 3 points more often and 0.12 s less late, and the
            calibrated rationality stays 10-20, docs/EXPERIMENTS.md).
        eta_min_speed_mps: the speed a time to entry assumes at least (a stopped
            person may walk on).
        inside_belief: a person inside a restricted cell has that cell as goal with at
            least this probability.
        directions: directions averaged in the normaliser Z (numerical integration).
        max_gap_s: observations further apart than this are not one displacement (the
            track was lost and found again): no evidence from the jump.
        door_zone_m: steps that begin within this distance of an exit are no evidence
            of a goal: a person coming in walks straight through the doorway, whatever
            they came for (everyone entering the twin's room first walks south, towards
            the restricted cell below the door). 0: every step counts.
        goal_spots: how a person heads for a cell: 0, for its nearest point (the
            cost-to-go is the distance to the cell); n >= 1, for one of n x n spots
            spread evenly over it, each equally likely (a person walks to a place in
            the cell, a machine or a shelf, not to its nearest corner: a step is
            likely under the cell when it heads for any of its spots).
        renew_after_visit_m: a person who was inside a restricted cell and is this far
            out of it again has reached that goal: they draw a new one, and the belief
            starts again from the prior (a visitor walking out is not still heading for
            the cell they leave). Negative (the default): never, the belief learns it
            from their steps (docs/EXPERIMENTS.md, issue 26: a wash on the studies).
    """

    section = "intent"

    rationality_per_m: float = setting(10.0, "in [0, 100] per metre")
    lapse: float = setting(0.05, "a probability in [0, 1)")
    restricted_prior: float = setting(0.5, "a probability in (0, 1)")
    wander_share: float = setting(0.3, "a probability in [0, 1]")
    exit_share: float = setting(0.5, "a probability in [0, 1]")
    other_cells_as_goals: bool = True
    switch_rate_per_s: float = setting(0.05, "in [0, 10] per second")
    stop_speed_mps: float = setting(0.15, "in [0, 1) m/s")
    position_step_m: float = setting(0.15, "in (0, 2] m")
    eta_min_speed_mps: float = setting(0.5, "in (0, 3] m/s")
    inside_belief: float = setting(0.9, "a probability in [0, 1)")
    directions: int = setting(32, "in [8, 720]")
    max_gap_s: float = setting(2.0, "> 0 s")
    door_zone_m: float = setting(1.0, "in [0, 5] m")
    goal_spots: int = setting(0, "in [0, 10] (0: the nearest point)")
    renew_after_visit_m: float = setting(-1.0, "in [-1, 5] m (negative: never)")


# -- goals -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Goal:
    """One hypothesis of where the person is heading.

    Attributes:
        name: "cell 1", "exit 1", "wander".
        rect: (x_min, y_min, x_max, y_max) of the goal on the map [m] (a point is a
            rectangle of size 0); None for wandering.
        cell: the cell, when the goal is one.
        restricted: whether it is a restricted cell (else part of "elsewhere").
    """

    name: str
    rect: tuple[float, float, float, float] | None
    cell: int | None = None
    restricted: bool = False


def make_goals(
    grid: CellGrid,
    restricted_cells: Sequence[int],
    exits: Sequence[tuple[float, float]] = (),
    other_cells: bool = True,
) -> tuple[Goal, ...]:
    """The hypotheses: restricted cells (in the given order), then the other cells
    (with ``other_cells``), the exits, and wandering last."""
    if not restricted_cells:
        raise ConfigError("restricted_cells", list(restricted_cells), "needs at least one cell")
    for c in restricted_cells:
        if c not in grid.cells:
            raise ConfigError(
                "restricted_cells", c, f"is not a cell of the grid (1..{grid.n_cells})"
            )
    if len(set(restricted_cells)) != len(restricted_cells):
        raise ConfigError("restricted_cells", list(restricted_cells), "lists a cell twice")
    goals = [Goal(f"cell {c}", grid.bounds(c), c, True) for c in restricted_cells]
    if other_cells:
        goals += [
            Goal(f"cell {c}", grid.bounds(c), c) for c in grid.cells if c not in restricted_cells
        ]
    for i, e in enumerate(exits):
        if len(e) != 2 or not all(math.isfinite(float(v)) for v in e):
            raise ConfigError(f"exits[{i}]", e, "must be a finite (x, y) point [m]")
        x, y = float(e[0]), float(e[1])
        goals.append(Goal(f"exit {i + 1}", (x, y, x, y)))
    goals.append(Goal(WANDER, None))
    return tuple(goals)


def distances_to(rects: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance from each point to each rectangle (0 inside): the open-floor cost-to-go.

    Args:
        rects: (G, 4) rows of (x_min, y_min, x_max, y_max) [m].
        points: (..., 2) map points [m].

    Returns:
        (G, ...) distances [m].
    """
    p = np.asarray(points, dtype=float)
    r = rects.reshape((rects.shape[0],) + (1,) * (p.ndim - 1) + (4,))
    dx = np.maximum(np.maximum(r[..., 0] - p[..., 0], 0.0), p[..., 0] - r[..., 2])
    dy = np.maximum(np.maximum(r[..., 1] - p[..., 1], 0.0), p[..., 1] - r[..., 3])
    return np.hypot(dx, dy)


def goal_spots(rect: Sequence[float], n: int) -> np.ndarray:
    """The places a person heading for ``rect`` may walk to (see
    ``IntentConfig.goal_spots``): with ``n`` >= 1 the n x n points at the centres of an
    even n x n split of it (a point rectangle: itself), as point rectangles; with 0 the
    rectangle itself. Returns (K, 4)."""
    x0, y0, x1, y1 = (float(v) for v in rect)
    if n <= 0 or (x0 == x1 and y0 == y1):
        return np.array([[x0, y0, x1, y1]], dtype=float)
    f = (np.arange(n) + 0.5) / n
    xs, ys = np.meshgrid(x0 + f * (x1 - x0), y0 + f * (y1 - y0), indexing="ij")
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1)
    return np.concatenate([pts, pts], axis=1)


def spot_likelihood(
    spots: np.ndarray,
    owner: np.ndarray,
    n_goals: int,
    x: np.ndarray,
    d: np.ndarray,
    directions: int,
    beta: float,
    lapse: float,
) -> np.ndarray:
    """The likelihood of displacement ``d`` from ``x`` under each of ``n_goals`` goals
    whose places are ``spots`` ((K, 4) rectangles; ``owner[k]`` the goal of spot k):
    the mean over a goal's spots of the Boltzmann likelihood toward each. Returns
    (n_goals,)."""
    p, q = step_progress(spots, x, d, directions)
    lik = boltzmann_likelihood(p, q, beta, lapse)
    if len(spots) == n_goals:  # one place a goal (goal_spots 0): its own likelihood
        return lik
    total = np.bincount(owner, weights=lik, minlength=n_goals)
    return total / np.maximum(np.bincount(owner, minlength=n_goals), 1)


def step_progress(
    rects: np.ndarray, x: np.ndarray, d: np.ndarray, directions: int
) -> tuple[np.ndarray, np.ndarray]:
    """Progress of displacement ``d`` from ``x`` toward each goal, and of the same
    length in each of ``directions`` directions (for the normaliser).

    Returns:
        (progress (G,), candidates (G, directions)) [m].
    """
    s = float(np.hypot(d[0], d[1]))
    ang = 2.0 * np.pi * np.arange(directions) / directions
    cand = x + s * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    here = distances_to(rects, x)
    return here - distances_to(rects, x + d), here[:, None] - distances_to(rects, cand)


def boltzmann_likelihood(
    progress: np.ndarray, candidates: np.ndarray, beta: float, lapse: float
) -> np.ndarray:
    """(1 - lapse) exp(beta p) / mean_k exp(beta q_k) + lapse, stably; any leading shape."""
    top = np.max(candidates, axis=-1)
    z = np.mean(np.exp(beta * (candidates - top[..., None])), axis=-1)
    return (1.0 - lapse) * np.exp(beta * (progress - top)) / z + lapse


# -- observations -----------------------------------------------------------------------


@dataclass(frozen=True)
class TrackObservation:
    """One track estimate of a person (from the camera or the leg tracker).

    Give ``velocity_mps``, or ``heading_rad`` with ``speed_mps``, when the tracker has
    them (the leg tracker's Kalman velocity); with the position alone the displacement
    is taken between positions ``position_step_m`` apart.

    Attributes:
        t: time of the estimate [s].
        position_m: (x, y) on the map [m].
        velocity_mps: (vx, vy) [m/s], or None.
        heading_rad: walking direction (0 east, counter-clockwise), with ``speed_mps``.
        speed_mps: speed [m/s] (with ``heading_rad``; ignored with ``velocity_mps``).
        track_id: which person (for :class:`IntentTracker`).
    """

    t: float
    position_m: tuple[float, float]
    velocity_mps: tuple[float, float] | None = None
    heading_rad: float | None = None
    speed_mps: float | None = None
    track_id: int = 0

    @property
    def velocity(self) -> np.ndarray | None:
        """(vx, vy) from the velocity or from heading and speed; None without either."""
        if self.velocity_mps is not None:
            return np.array(self.velocity_mps, dtype=float)
        if self.heading_rad is not None and self.speed_mps is not None:
            s = float(self.speed_mps)
            return np.array([s * math.cos(self.heading_rad), s * math.sin(self.heading_rad)])
        return None

    @classmethod
    def from_track(cls, est: Any, t: float | None = None) -> TrackObservation:
        """From a :class:`stack.perception.tracker.TrackEstimate` (or anything with
        ``position_m``, ``velocity_mps``, ``track_id`` and ``last_update_s``)."""
        return cls(
            t=float(est.last_update_s if t is None else t),
            position_m=tuple(map(float, est.position_m)),  # type: ignore[arg-type]
            velocity_mps=tuple(map(float, est.velocity_mps)),  # type: ignore[arg-type]
            track_id=int(est.track_id),
        )


# -- displacements -----------------------------------------------------------------------


class Displacements:
    """Turns a stream of track estimates into (from, displacement) evidence and a speed.

    With a velocity: displacement = velocity x time since the previous estimate, none
    when slower than ``stop_speed_mps`` or after a gap over ``max_gap_s``. With
    positions only: the positions are smoothed (exponentially, time constant
    :data:`SMOOTHING_S`) and a displacement is taken each time the smoothed position is
    ``position_step_m`` from where the last one ended (shorter moves are jitter), at
    ``stop_speed_mps`` or faster. The first displacement of a track starts once the
    smoothing has run for :data:`SMOOTHING_S` (from its first, unsmoothed position, a
    standing person's noise reads as a step), and a person slower than that speed is
    stopped: the start moves to where they stand (their jitter over seconds is not a
    walk, and a walk after a stop is measured from the stop). A position further from
    the last than a person can walk (:data:`JUMP_SPEED_MPS`, :data:`JUMP_SLACK_M`) is a
    false detection and ignored, unless the next one agrees with it: then the person
    is there (the positions before had gone stale, as in a camera outage) and their
    walk is measured from the first of the two.
    """

    def __init__(self, config: IntentConfig):
        self.config = config
        self.reset()

    def reset(self) -> None:
        self.last_t: float | None = None
        self.position: np.ndarray | None = None
        self.speed = 0.0
        self._anchor: np.ndarray | None = None
        self._anchor_t = 0.0
        self._smooth: np.ndarray | None = None
        self._jump: tuple[np.ndarray, float] | None = None  # held back: a false detection?

    def push(self, obs: TrackObservation) -> tuple[np.ndarray, np.ndarray] | None:
        """Take one estimate (not older than the previous); return (x, d) or None."""
        cfg = self.config
        pos = np.array(obs.position_m, dtype=float)
        if pos.shape != (2,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"position_m must be a finite (x, y): {obs.position_m!r}")
        gap = math.inf if self.last_t is None else obs.t - self.last_t
        prev = self.position
        self.last_t, self.position = obs.t, pos
        vel = obs.velocity
        if vel is not None:
            self.speed = float(np.hypot(vel[0], vel[1]))
            self._anchor, self._smooth = None, None  # positions again: smoothing restarts
            if prev is None or gap > cfg.max_gap_s or gap <= 0 or self.speed < cfg.stop_speed_mps:
                return None
            return prev, vel * gap
        if self._smooth is not None and gap <= cfg.max_gap_s and prev is not None:
            bound = JUMP_SPEED_MPS * max(gap, 0.0) + JUMP_SLACK_M
            if float(np.hypot(*(pos - prev))) > bound:
                held, self._jump = self._jump, (pos, obs.t)
                if held is None or float(np.hypot(*(pos - held[0]))) > bound:
                    self.position = prev  # a false detection: as if not seen
                    return None
                # two in a row agree: the person is there (the track before had gone
                # stale); the walk goes on from the first of the two
                self._smooth, self._anchor, self._anchor_t = held[0], held[0], held[1]
        self._jump = None
        if self._smooth is None or gap > cfg.max_gap_s:  # a new track: smoothing starts
            self._smooth, self._anchor, self._anchor_t, self.speed = pos, None, obs.t, 0.0
            return None
        a = 1.0 - math.exp(-max(gap, 0.0) / SMOOTHING_S)
        self._smooth = self._smooth + a * (pos - self._smooth)
        pos = self._smooth
        if self._anchor is None:  # the first start: once the smoothing has settled
            if obs.t - self._anchor_t >= SMOOTHING_S:
                self._anchor, self._anchor_t = pos, obs.t
            return None
        d = pos - self._anchor
        moved = float(np.hypot(d[0], d[1]))
        elapsed = obs.t - self._anchor_t
        if elapsed <= 0:
            return None
        if moved >= cfg.position_step_m and moved / elapsed >= cfg.stop_speed_mps:
            start = self._anchor
            self.speed = moved / elapsed
            self._anchor, self._anchor_t = pos, obs.t
            return start, d
        if elapsed > cfg.position_step_m / max(self.speed, cfg.stop_speed_mps, 1e-3):
            self.speed = moved / elapsed  # overdue: slower than the last step
        if elapsed > cfg.position_step_m / cfg.stop_speed_mps:  # stopped: start from here
            self._anchor, self._anchor_t = pos, obs.t
        return None
