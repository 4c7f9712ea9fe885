"""Goal inference for one person (:class:`GoalInference`) and for several
(:class:`IntentTracker`), and what they report (:class:`IntentEstimate`).

See :mod:`stack.planning.intent` for the model in words. Pure numpy.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stack.cells import CellGrid, ConfigError
from stack.planning.intent.model import (
    Displacements,
    IntentConfig,
    TrackObservation,
    distances_to,
    goal_spots,
    make_goals,
    spot_likelihood,
)

__all__ = ["CellForecast", "GoalInference", "IntentEstimate", "IntentTracker"]


@dataclass(frozen=True)
class CellForecast:
    """What one restricted cell can expect from this person.

    Attributes:
        cell: the restricted cell.
        probability: P(the person is heading there).
        distance_m: shortest-path distance to the cell (0 inside) [m].
        eta_s: predicted time to entry, distance / max(speed, eta_min_speed) [s].
    """

    cell: int
    probability: float
    distance_m: float
    eta_s: float


@dataclass(frozen=True)
class IntentEstimate:
    """The belief about one person's goal at time ``t``.

    Attributes:
        t: the time of the estimate [s].
        forecasts: one per restricted cell, in the task's order.
        p_elsewhere: P(heading anywhere but a restricted cell).
        inside: the restricted cell the person is in, else None.
        position_m: the last observed position [m] (None before any observation).
        speed_mps: the person's current speed estimate [m/s].
        moving: speed at or above ``stop_speed_mps``.
        age_s: time since the last observation [s] (inf before any).
        hypotheses: every internal hypothesis's probability by name (for logs).
    """

    t: float
    forecasts: tuple[CellForecast, ...]
    p_elsewhere: float
    inside: int | None
    position_m: tuple[float, float] | None
    speed_mps: float
    moving: bool
    age_s: float
    hypotheses: dict[str, float] = field(default_factory=dict)

    def p(self, cell: int | None) -> float:
        """P(goal = ``cell``); None: P(elsewhere)."""
        if cell is None:
            return self.p_elsewhere
        for f in self.forecasts:
            if f.cell == cell:
                return f.probability
        raise KeyError(f"cell {cell} is not a restricted cell of this model")

    def forecast(self, cell: int) -> CellForecast:
        for f in self.forecasts:
            if f.cell == cell:
                return f
        raise KeyError(f"cell {cell} is not a restricted cell of this model")

    @property
    def most_likely(self) -> int | None:
        """The likeliest goal: a restricted cell, or None for elsewhere."""
        best = max(self.forecasts, key=lambda f: f.probability)
        return best.cell if best.probability > self.p_elsewhere else None

    def changed(self, other: IntentEstimate | None, threshold: float = 0.15) -> bool:
        """Whether this estimate differs from ``other`` enough to decide again: a goal's
        probability moved by ``threshold`` or more, or the person entered or left a
        restricted cell (for planners that decide on evidence, not on a period)."""
        if other is None or self.inside != other.inside:
            return True
        return abs(self.p_elsewhere - other.p_elsewhere) >= threshold or any(
            abs(a.probability - b.probability) >= threshold
            for a, b in zip(self.forecasts, other.forecasts, strict=True)
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready (the step records)."""
        return {
            "t": round(self.t, 3),
            "p": {str(f.cell): round(f.probability, 4) for f in self.forecasts},
            "p_elsewhere": round(self.p_elsewhere, 4),
            "eta_s": {str(f.cell): _r(f.eta_s) for f in self.forecasts},
            "distance_m": {str(f.cell): round(f.distance_m, 3) for f in self.forecasts},
            "inside": self.inside,
            "speed_mps": round(self.speed_mps, 3),
            "moving": self.moving,
            "age_s": _r(self.age_s),
        }


def _r(x: float) -> float | None:
    return None if not math.isfinite(x) else round(x, 3)


# -- inference ---------------------------------------------------------------------------


class GoalInference:
    """The goal belief of one person (see the module docstring).

    Args:
        grid: the cell geometry.
        restricted_cells: the task's restricted cells.
        config: the parameters.
        exits: extra destinations of "elsewhere" (map points, e.g. the doorway).

    With no other cells and no exits, "elsewhere" is wandering alone.

    Raises:
        ConfigError: a restricted cell not in the grid or listed twice, a bad exit.
    """

    def __init__(
        self,
        grid: CellGrid,
        restricted_cells: Sequence[int],
        config: IntentConfig | None = None,
        exits: Sequence[tuple[float, float]] = (),
    ):
        self.config = config = IntentConfig() if config is None else config
        self.grid = grid
        self.restricted = tuple(int(c) for c in restricted_cells)
        self.exits = tuple(exits)
        self.goals = make_goals(grid, self.restricted, exits, config.other_cells_as_goals)
        self._doors = np.array([(float(x), float(y)) for x, y in exits], dtype=float).reshape(-1, 2)
        self._rects = np.array([g.rect for g in self.goals if g.rect is not None], dtype=float)
        # the places a walker heading for each goal may walk to (config.goal_spots)
        parts = [goal_spots(r, config.goal_spots) for r in self._rects]
        self._spots = np.concatenate(parts)
        self._owner = np.repeat(np.arange(len(parts)), [len(x) for x in parts])
        n_r = len(self.restricted)
        n_dest = len(self.goals) - n_r - 1
        prior = np.empty(len(self.goals))
        prior[:n_r] = config.restricted_prior / n_r
        rest = 1.0 - config.restricted_prior
        wander = config.wander_share if n_dest else 1.0
        destinations = rest * (1.0 - wander)
        n_exits = sum(g.name.startswith("exit ") for g in self.goals)
        n_cells = n_dest - n_exits
        if n_exits and n_cells:
            prior[n_r : n_r + n_cells] = destinations * (1.0 - config.exit_share) / n_cells
            prior[n_r + n_cells : -1] = destinations * config.exit_share / n_exits
        else:
            prior[n_r:-1] = destinations / max(n_dest, 1)
        prior[-1] = rest * wander
        self.prior = prior / prior.sum()
        self._steps = Displacements(config)
        self.reset()

    @classmethod
    def for_task(
        cls,
        task: Any,
        config: IntentConfig | None = None,
        exits: Sequence[tuple[float, float]] = (),
    ) -> GoalInference:
        """For a :class:`stack.planning.task.Task` (its grid and restricted cells)."""
        return cls(task.grid, task.restricted_cells, config, exits)

    def fresh(self) -> GoalInference:
        """A new inference with the same parameters (grid, cells, config, exits), at
        the prior: another person's."""
        return type(self)(self.grid, self.restricted, self.config, self.exits)

    def reset(self) -> None:
        """Forget the person: the prior, no position."""
        self.belief = self.prior.copy()
        self.t: float | None = None
        self._steps.reset()
        self._visiting: int | None = None  # the restricted cell the person was last in

    # -- the two steps ------------------------------------------------------------------
    def _diffuse(self, t: float) -> None:
        if self.t is not None and t > self.t:
            keep = math.exp(-self.config.switch_rate_per_s * (t - self.t))
            self.belief = keep * self.belief + (1.0 - keep) * self.prior
        if self.t is None or t > self.t:
            self.t = t

    def evidence(self, x: np.ndarray, d: np.ndarray) -> np.ndarray:
        """The likelihood of displacement ``d`` from ``x`` under every hypothesis."""
        cfg = self.config
        lik = np.ones(len(self.goals))
        lik[:-1] = spot_likelihood(self._spots, self._owner, len(self._rects), x, d,
                                   cfg.directions, cfg.rationality_per_m, cfg.lapse)  # fmt: skip
        return lik

    def update(self, obs: TrackObservation) -> IntentEstimate:
        """Take one track estimate; return the belief at its time.

        An estimate older than the last one is stale: ignored (the current belief is
        returned at the last time).
        """
        if self.t is not None and obs.t < self.t - 1e-9:
            return self.estimate()
        self._diffuse(obs.t)
        step = self._steps.push(obs)
        inside = self._inside()
        self._renew_after_visit(inside)
        if step is not None and not self._in_door_zone(step[0]):
            post = self.belief * self.evidence(*step)
            total = post.sum()
            if total > 0 and np.isfinite(total):
                self.belief = post / total
        if inside is not None:
            k = self.restricted.index(inside)
            if self.belief[k] < self.config.inside_belief:
                others = 1.0 - self.belief[k]
                scale = (1.0 - self.config.inside_belief) / others if others > 0 else 0.0
                self.belief = self.belief * scale
                self.belief[k] = self.config.inside_belief
        return self.estimate()

    def _renew_after_visit(self, inside: int | None) -> None:
        """A person ``renew_after_visit_m`` out of the restricted cell they were in (now
        ``inside``, None: none) has reached that goal: the belief starts again from the
        prior."""
        margin = self.config.renew_after_visit_m
        pos = self._steps.position
        if inside is not None or pos is None:
            self._visiting = inside if margin >= 0 else None
            return
        if self._visiting is None:
            return
        k = self.restricted.index(self._visiting)
        if distances_to(self._rects[k : k + 1], pos)[0] >= margin:
            self.belief = self.prior.copy()
            self._visiting = None

    def predict(self, t: float) -> IntentEstimate:
        """The belief at ``t`` with no new observation (it diffuses toward the prior);
        a ``t`` before the last update gives the belief at that update."""
        self._diffuse(t)
        return self.estimate()

    def _in_door_zone(self, x: np.ndarray) -> bool:
        """``x`` lies within ``door_zone_m`` of an exit (see :class:`IntentConfig`)."""
        if len(self._doors) == 0 or self.config.door_zone_m <= 0:
            return False
        return bool((np.hypot(*(self._doors - x).T) <= self.config.door_zone_m).any())

    # -- reading ------------------------------------------------------------------------
    def _inside(self) -> int | None:
        pos = self._steps.position
        if pos is None:
            return None
        cell = self.grid.cell_at(float(pos[0]), float(pos[1]))
        return cell if cell in self.restricted else None

    def estimate(self) -> IntentEstimate:
        """The current belief (at the last update's or prediction's time)."""
        cfg = self.config
        now = 0.0 if self.t is None else self.t
        pos = self._steps.position
        speed = self._steps.speed
        n_r = len(self.restricted)
        if pos is None:
            dist = np.full(n_r, math.inf)
        else:
            dist = distances_to(self._rects[:n_r], pos)
        eta = dist / max(speed, cfg.eta_min_speed_mps)
        forecasts = tuple(
            CellForecast(c, float(self.belief[k]), float(dist[k]), float(eta[k]))
            for k, c in enumerate(self.restricted)
        )
        last = self._steps.last_t
        return IntentEstimate(
            t=now,
            forecasts=forecasts,
            p_elsewhere=float(self.belief[n_r:].sum()),
            inside=self._inside(),
            position_m=None if pos is None else (float(pos[0]), float(pos[1])),
            speed_mps=speed,
            moving=speed >= cfg.stop_speed_mps and pos is not None,
            age_s=math.inf if last is None else max(0.0, now - last),
            hypotheses={g.name: float(b) for g, b in zip(self.goals, self.belief, strict=True)},
        )


class IntentTracker:
    """Goal inference for several people, keyed by track id: each person's
    :class:`GoalInference` is a :meth:`~GoalInference.fresh` copy of ``template``.

    Args:
        template: the inference every new person starts as (its grid, restricted
            cells, config and exits; e.g. ``GoalInference(grid, cells)``).
        drop_after_s: a track not observed for this long is forgotten.
    """

    def __init__(self, template: GoalInference, drop_after_s: float = 10.0):
        if not drop_after_s > 0:
            raise ConfigError("drop_after_s", drop_after_s, "must be > 0 s")
        self.template = template
        self.drop_after_s = drop_after_s
        self.people: dict[int, GoalInference] = {}

    def update(
        self, t: float, observations: Iterable[TrackObservation]
    ) -> dict[int, IntentEstimate]:
        """Take the observations of time ``t`` (any number of tracks); return every
        known person's estimate at ``t`` (unobserved ones predicted), dropping tracks
        unseen for ``drop_after_s``."""
        for obs in observations:
            person = self.people.get(obs.track_id)
            if person is None:
                person = self.people[obs.track_id] = self.template.fresh()
            person.update(obs)
        return self.predict(t)

    def predict(self, t: float) -> dict[int, IntentEstimate]:
        """Every known person's estimate at ``t``."""
        out = {}
        for tid in sorted(self.people):
            est = self.people[tid].predict(t)
            if est.age_s > self.drop_after_s:
                del self.people[tid]
            else:
                out[tid] = est
        return out
