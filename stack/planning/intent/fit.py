"""Fitting goal inference to walks, and walks drawn from its model.

:func:`fit_rationality` finds the rationality ``beta`` and the ``lapse`` share that
make walks of known goals likeliest (maximum likelihood): for each step of each walk,
the likelihood of the observed displacement given the walk's goal (the
Boltzmann-rational step model of :mod:`stack.planning.intent.model`). The
log-likelihood is concave in ``lapse`` and, for the walks people take, single-peaked
in ``beta``; the fit alternates golden-section searches on the two.

``beta`` is per metre, but the fit sees the steps as independent: a tracker's
velocity is smoothed, so successive steps of a real walk agree more than independent
draws would, and the fitted ``beta`` grows with the observation rate. Fit on tracks
at the rate the guard will feed the model.

:func:`simulate_goal_walk` draws a walk from the model itself (for tests, and to
check a fit recovers the value it was drawn with).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from stack.cells import CellGrid, ConfigError
from stack.planning.intent.inference import GoalInference
from stack.planning.intent.model import (
    Displacements,
    IntentConfig,
    TrackObservation,
    boltzmann_likelihood,
    distances_to,
    goal_spots,
    step_progress,
)

__all__ = [
    "CALIBRATION_BETAS",
    "LabelledTrack",
    "RationalityFit",
    "calibrate_rationality",
    "fit_rationality",
    "goal_log_score",
    "simulate_goal_walk",
    "track_log_likelihood",
]

GoalSpec = int | tuple[float, float]  # a cell number, or a map point [m]


@dataclass(frozen=True)
class LabelledTrack:
    """A walk whose goal is known.

    Attributes:
        goal: the cell the person walked to, or a map point (x, y) [m] (e.g. the door).
        observations: the track estimates, in time order.
    """

    goal: GoalSpec
    observations: tuple[TrackObservation, ...]


@dataclass(frozen=True)
class RationalityFit:
    """The result of :func:`fit_rationality`.

    Attributes:
        rationality_per_m: the fitted beta [1/m].
        lapse: the fitted lapse share (the given one when not fitted).
        log_likelihood: total log-likelihood of the steps at the fit (0 is what
            wandering with no goal scores; higher is better).
        steps: how many displacements the walks gave.
        config: the given configuration with the fitted values.
    """

    rationality_per_m: float
    lapse: float
    log_likelihood: float
    steps: int
    config: IntentConfig

    @property
    def log_likelihood_per_step(self) -> float:
        return self.log_likelihood / self.steps


def goal_rect(grid: CellGrid, goal: GoalSpec) -> tuple[float, float, float, float]:
    """The rectangle of a goal given as a cell number or a point.

    Raises:
        ConfigError: not a cell of the grid, nor a finite point (key ``goal``).
    """
    if isinstance(goal, int) and not isinstance(goal, bool):
        if goal not in grid.cells:
            raise ConfigError("goal", goal, f"is not a cell of the grid (1..{grid.n_cells})")
        return grid.bounds(goal)
    if (
        isinstance(goal, tuple | list)
        and len(goal) == 2
        and all(isinstance(v, int | float) and math.isfinite(v) for v in goal)
    ):
        x, y = float(goal[0]), float(goal[1])
        return (x, y, x, y)
    raise ConfigError("goal", goal, "must be a cell number or a finite (x, y) point")


def track_steps(
    track: LabelledTrack, grid: CellGrid, config: IntentConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Every displacement of ``track`` as the model sees it (the same rules as
    :class:`~stack.planning.intent.inference.GoalInference`): the progress toward
    each place of the track's goal (``config.goal_spots``; K = 1 for its nearest
    point), and the progress of the same length in each direction.

    Returns:
        (progress (N, K), candidates (N, K, directions)) [m].
    """
    spots = goal_spots(goal_rect(grid, track.goal), config.goal_spots)
    disp = Displacements(config)
    ps, qs = [], []
    for obs in track.observations:
        step = disp.push(obs)
        if step is not None:
            p, q = step_progress(spots, step[0], step[1], config.directions)
            ps.append(p)
            qs.append(q)
    if not ps:
        return np.zeros((0, len(spots))), np.zeros((0, len(spots), config.directions))
    return np.array(ps), np.array(qs)


def _log_likelihood(p: np.ndarray, q: np.ndarray, beta: float, lapse: float) -> float:
    """Steps' (N, K) progress toward a goal's K places and (N, K, directions)
    candidates: the sum over steps of the log of the mean likelihood of the places."""
    lik = boltzmann_likelihood(p, q, beta, lapse).mean(axis=-1)
    return float(np.sum(np.log(np.maximum(lik, 1e-300))))


def track_log_likelihood(
    tracks: Sequence[LabelledTrack], grid: CellGrid, config: IntentConfig | None = None
) -> float:
    """Total log-likelihood of the walks' steps under ``config``'s beta and lapse."""
    cfg = IntentConfig() if config is None else config
    total = 0.0
    for tr in tracks:
        p, q = track_steps(tr, grid, cfg)
        if len(p):
            total += _log_likelihood(p, q, cfg.rationality_per_m, cfg.lapse)
    return total


def _golden_max(f, lo: float, hi: float, iters: int = 60) -> float:
    """The maximiser of a single-peaked ``f`` on [lo, hi] (golden-section search)."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(iters):
        if fc >= fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    best = max((lo, f(lo)), (hi, f(hi)), ((a + b) / 2.0, f((a + b) / 2.0)), key=lambda x: x[1])
    return best[0]


def fit_rationality(
    tracks: Sequence[LabelledTrack],
    grid: CellGrid,
    config: IntentConfig | None = None,
    fit_lapse: bool = True,
    beta_max: float = 50.0,
    rounds: int = 6,
) -> RationalityFit:
    """Maximum-likelihood beta (and lapse) on walks of known goals.

    Args:
        tracks: the walks, each with its goal.
        grid: the cell geometry (goals given as cells).
        config: the other parameters (directions, stop speed, ...) and the starting
            lapse; default :class:`IntentConfig`.
        fit_lapse: fit the lapse too (else keep the config's).
        beta_max: the largest beta searched [1/m].
        rounds: alternations between the beta and the lapse searches.

    Raises:
        ConfigError: no tracks, a bad goal, ``beta_max`` out of (0, 100], or walks
            with no displacement at all (key ``tracks``).
    """
    cfg = IntentConfig() if config is None else config
    if not 0.0 < beta_max <= 100.0:
        raise ConfigError("beta_max", beta_max, "must be in (0, 100] per metre")
    if not tracks:
        raise ConfigError("tracks", [], "needs at least one walk")
    by_places: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for tr in tracks:  # goals with as many places together (a cell's spots, a point)
        p, q = track_steps(tr, grid, cfg)
        by_places.setdefault(p.shape[1], []).append((p, q))
    groups = [
        (np.concatenate([x[0] for x in g]), np.concatenate([x[1] for x in g]))
        for g in by_places.values()
    ]
    steps = sum(len(p) for p, _ in groups)
    if steps == 0:
        raise ConfigError("tracks", len(tracks), "the walks give no displacement to fit on")

    def total(beta: float, lapse: float) -> float:
        return sum(_log_likelihood(p, q, beta, lapse) for p, q in groups if len(p))

    beta, lapse = cfg.rationality_per_m, cfg.lapse
    for _ in range(max(1, rounds)):
        beta = _golden_max(lambda b, e=lapse: total(b, e), 0.0, beta_max)
        if fit_lapse:
            lapse = _golden_max(lambda e, b=beta: total(b, e), 0.0, 0.99)
    fitted = dataclasses.replace(cfg, rationality_per_m=float(beta), lapse=float(lapse))
    return RationalityFit(float(beta), float(lapse), total(beta, lapse), steps, fitted)


# the rationalities calibrate_rationality tries [1/m]
CALIBRATION_BETAS = (1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 14.0, 20.0, 30.0, 40.0)


def goal_log_score(tracks: Sequence[LabelledTrack], inference: GoalInference) -> float:
    """How well ``inference`` (its goals, prior and parameters) tells where each walk
    is going: the mean over the walks' observations of the log-probability its belief
    gives the walk's true goal, each walk from the prior (a fresh copy). A walk whose
    goal is no hypothesis of the inference (a point that is not one of its exits) is
    left out. Higher is better; 0 is certainty on the truth."""
    names = {g.cell: g.name for g in inference.goals if g.cell is not None}
    points = {g.rect[:2]: g.name for g in inference.goals if g.rect and g.cell is None}
    total, n = 0.0, 0
    for tr in tracks:
        if isinstance(tr.goal, int):
            name = names.get(tr.goal)
        else:
            near = [p for p in points if math.dist(p, tr.goal) < 1e-6]
            name = points[near[0]] if near else None
        if name is None:
            continue
        model = inference.fresh()
        for obs in tr.observations:
            est = model.update(obs)
            total += math.log(max(est.hypotheses[name], 1e-12))
            n += 1
    if n == 0:
        raise ConfigError("tracks", len(tracks), "no walk heads for a goal of the inference")
    return total / n


def calibrate_rationality(
    tracks: Sequence[LabelledTrack],
    inference: GoalInference,
    betas: Sequence[float] = CALIBRATION_BETAS,
) -> tuple[float, dict[float, float]]:
    """The rationality among ``betas`` whose beliefs score best on the walks
    (:func:`goal_log_score`), and every score. Unlike :func:`fit_rationality`, which
    scores each step as independent evidence, this scores the belief the guard acts
    on: the successive steps of a real walk agree with each other, and a beta fitted
    to them as independent makes the belief overconfident."""
    scores = {}
    for b in betas:
        cfg = dataclasses.replace(inference.config, rationality_per_m=float(b))
        model = GoalInference(inference.grid, inference.restricted, cfg, inference.exits)
        scores[float(b)] = goal_log_score(tracks, model)
    return max(scores, key=lambda b: scores[b]), scores


def simulate_goal_walk(
    grid: CellGrid,
    goal: GoalSpec,
    start_m: tuple[float, float],
    rng: np.random.Generator,
    rationality_per_m: float = 3.0,
    lapse: float = 0.0,
    speed_mps: float = 1.0,
    dt_s: float = 0.25,
    max_steps: int = 200,
) -> LabelledTrack:
    """A walk drawn from the Boltzmann-rational model toward ``goal``.

    Each step has length ``speed_mps * dt_s``; its direction is drawn (on a fine grid
    of 720 directions) with weight exp(beta * progress), or uniformly with probability
    ``lapse``. The walk ends inside the goal or after ``max_steps`` steps. Each
    observation carries the velocity of the step that led to it.
    """
    rect = np.array([goal_rect(grid, goal)], dtype=float)
    s = speed_mps * dt_s
    ang = 2.0 * np.pi * np.arange(720) / 720
    unit = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    x = np.array(start_m, dtype=float)
    obs = [TrackObservation(0.0, (float(x[0]), float(x[1])), (0.0, 0.0))]
    for k in range(1, max_steps + 1):
        if distances_to(rect, x)[0] <= 0.0:
            break
        if rng.random() < lapse:
            u = unit[rng.integers(720)]
        else:
            prog = distances_to(rect, x)[0] - distances_to(rect, x + s * unit)[0]
            w = np.exp(rationality_per_m * (prog - prog.max()))
            u = unit[rng.choice(720, p=w / w.sum())]
        x = x + s * u
        v = (float(u[0] * speed_mps), float(u[1] * speed_mps))
        obs.append(TrackObservation(k * dt_s, (float(x[0]), float(x[1])), v))
    return LabelledTrack(goal, tuple(obs))
