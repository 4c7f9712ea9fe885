"""Goal inference (stack.planning.intent) on synthetic tracks with known goals (issue 26)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError
from stack.planning.intent import (
    GoalInference,
    IntentConfig,
    IntentTracker,
    LabelledTrack,
    TrackObservation,
    distances_to,
    fit_rationality,
    simulate_goal_walk,
    track_log_likelihood,
)
from stack.planning.task import load_task

REPO = Path(__file__).resolve().parents[1]
GRID = CellGrid()  # cell 1: x 5..6, y 0..1.5 (south-east); cell 12: x 0..1, y 1.5..3
DOOR = (7.0, 4.4)  # just inside the twin's doorway (north wall, east of the region)


def walk(points, speed=1.2, hz=10.0, heading_noise_deg=10.0, pos_noise_m=0.03, seed=0, vel=True):
    """Observations of a walk along ``points`` at ``speed``, as a tracker reports it
    (noisy heading, speed and position): [(distance walked, observation)]."""
    rng = np.random.default_rng(seed)
    out, t, walked = [], 0.0, 0.0
    for a, b in zip(points, points[1:], strict=False):
        a, b = np.array(a, float), np.array(b, float)
        length = float(np.linalg.norm(b - a))
        u = (b - a) / length
        for k in range(int(length * hz / speed)):
            x = a + u * (k * speed / hz) + pos_noise_m * rng.standard_normal(2)
            th = math.atan2(u[1], u[0]) + math.radians(heading_noise_deg) * rng.standard_normal()
            s = speed * (1.0 + 0.05 * rng.standard_normal())
            v = (s * math.cos(th), s * math.sin(th)) if vel else None
            out.append((walked + k * speed / hz, TrackObservation(t, (x[0], x[1]), v)))
            t += 1.0 / hz
        walked += length
    return out


def feed(model, observations):
    """[(distance walked, estimate)] after each observation."""
    return [(d, model.update(o)) for d, o in observations]


def at(history, metres):
    """The estimate after ``metres`` of walking."""
    return [e for d, e in history if d <= metres + 1e-9][-1]


@pytest.mark.parametrize(
    "start",
    [DOOR, (0.3, 0.75), (2.5, 2.8), (3.0, -1.5)],
    ids=["from the door", "from cell 11", "from cell 8", "from the south"],
)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_straight_approach_to_cell_1_puts_most_belief_there_within_1_m(start, seed):
    model = GoalInference(GRID, [1])
    history = feed(model, walk([start, (5.5, 0.75)], seed=seed))
    est = at(history, 1.0)
    assert est.p(1) > 0.5 and est.most_likely == 1
    assert est.p(1) > est.p_elsewhere
    # and it only grows more certain on the way in
    assert at(history, 2.0).p(1) > est.p(1)
    assert history[-1][1].inside == 1 and history[-1][1].p(1) >= 0.9


def test_a_decoy_who_turns_away_sees_belief_in_cell_1_fall():
    model = GoalInference(GRID, [1])
    turn = (6.2, 2.2)  # 0.7 m north of cell 1, then west along the north row
    history = feed(model, walk([DOOR, turn, (2.5, 2.4)]))
    to_turn = math.dist(DOOR, turn)
    before = at(history, to_turn)
    assert before.p(1) > 0.7
    after = at(history, to_turn + 1.5)
    assert after.p(1) < 0.25 and after.p(1) < before.p(1) / 3
    assert after.most_likely is None
    assert all(e.inside is None for _, e in history)


def test_an_approach_to_cell_12_in_task_r2_goes_there():
    task = load_task(REPO / "config" / "task-r2.yaml")
    model = GoalInference.for_task(task)
    assert model.restricted == (1, 12)
    history = feed(model, walk([DOOR, (0.5, 2.25)]))
    # 6.6 m along the north row: cells 10, 8, 6 and 4 lie on the way too, so it takes
    # longer than to cell 1, but cell 1 is ruled out at once
    assert at(history, 2.0).p(1) < 0.05
    est = at(history, 3.0)
    assert est.most_likely == 12 and est.p(12) > 0.5
    last_outside = [e for _, e in history if e.inside is None][-1]
    assert last_outside.p(12) > 0.8
    assert history[-1][1].inside == 12
    # ... and one to cell 1 goes to cell 1
    model = GoalInference.for_task(task)
    est = at(feed(model, walk([DOOR, (5.5, 0.75)])), 2.0)
    assert est.most_likely == 1 and est.p(12) < 0.05


def test_the_evidence_accrues_per_metre_not_per_observation():
    p = []
    for hz in (5.0, 10.0, 30.0):
        history = feed(GoalInference(GRID, [1]), walk([DOOR, (5.5, 0.75)], hz=hz))
        p.append(at(history, 1.5).p(1))
    assert max(p) - min(p) < 0.1


def test_positions_alone_also_work():
    history = feed(GoalInference(GRID, [1]), walk([DOOR, (5.5, 0.75)], vel=False, pos_noise_m=0.05))
    assert at(history, 1.2).p(1) > 0.5
    # a standing person's jitter is not a walk
    model = GoalInference(GRID, [1])
    rng = np.random.default_rng(3)
    for k in range(100):
        x = np.array([3.0, 2.0]) + 0.05 * rng.standard_normal(2)
        est = model.update(TrackObservation(0.1 * k, (x[0], x[1])))
    assert est.p(1) == pytest.approx(0.5, abs=0.02) and not est.moving


def test_a_standing_person_with_jitter_and_false_detections_is_no_walk():
    """Positions only: 30 s of a person standing, seen with 5 cm of jitter and, every
    2 s, one false detection 1-2 m away (the camera's false positives reach the planner
    as the person's position) give no evidence of a goal. Before, the first,
    unsmoothed position was a step's start, and a false detection pulled the smoothed
    position into a step (in a study it sent the guard out of the cell it held)."""
    rng = np.random.default_rng(5)
    for trial in range(5):
        model = GoalInference(GRID, [1])
        for k in range(300):
            x = np.array([3.0, 2.0]) + 0.05 * rng.standard_normal(2)
            if k % 20 == 19:
                angle = rng.uniform(0, 2 * np.pi)
                x = x + rng.uniform(1.0, 2.0) * np.array([np.cos(angle), np.sin(angle)])
            est = model.update(TrackObservation(0.1 * k, (x[0], x[1])))
            assert est.p(1) == pytest.approx(0.5, abs=0.02), (trial, k)
            assert est.position_m is not None and math.dist(est.position_m, (3.0, 2.0)) < 0.3
        assert not est.moving


def test_a_person_who_is_really_elsewhere_is_followed_after_two_detections():
    """A jump no walker makes, seen twice in a row, is where the person is (the track
    had gone stale, as in a camera outage), and their walk from there is evidence at
    once: no new start-up of the smoothing."""
    model = GoalInference(GRID, [1])
    for k in range(10):
        model.update(TrackObservation(0.1 * k, (1.0, 2.5)))
    assert model.update(TrackObservation(1.0, (3.0, 0.75))).position_m == (1.0, 2.5)
    assert model.update(TrackObservation(1.1, (3.1, 0.75))).position_m == (3.1, 0.75)
    for k in range(2, 6):  # on east at 1 m/s, toward cell 1
        est = model.update(TrackObservation(1.0 + 0.1 * k, (3.0 + 0.1 * k, 0.75)))
    assert est.p(1) > 0.75 and est.moving


def test_a_walk_after_a_long_stop_is_evidence_at_once():
    """A person who stood 10 s and then walks to cell 1: their walk is measured from
    where they stood, not from where the track began (no slow average over the stop)."""
    model = GoalInference(GRID, [1])
    rng = np.random.default_rng(6)
    t = 0.0
    for _ in range(100):
        x = np.array([2.0, 0.75]) + 0.05 * rng.standard_normal(2)
        model.update(TrackObservation(t, (x[0], x[1])))
        t += 0.1
    start = t
    for k in range(1, 40):  # east along the row at 1 m/s
        est = model.update(TrackObservation(t, (2.0 + 0.1 * k, 0.75)))
        t += 0.1
        if est.p(1) > 0.8:
            break
    assert est.p(1) > 0.8 and t - start <= 1.2 and est.moving


def test_missing_observations_diffuse_toward_the_prior():
    model = GoalInference(GRID, [1])
    history = feed(model, walk([DOOR, (6.0, 2.5)]))
    est = history[-1][1]
    assert est.p(1) > 0.8
    later = [model.predict(est.t + dt) for dt in (1.0, 5.0, 20.0, 200.0)]
    assert [e.p(1) for e in later] == sorted((e.p(1) for e in later), reverse=True)
    assert later[0].p(1) > 0.75  # a short gap keeps most of it
    assert later[-1].p(1) == pytest.approx(0.5, abs=1e-3)  # the prior
    assert later[1].age_s == pytest.approx(5.0)
    # after the gap the person is found again elsewhere: the jump is no evidence
    jumped = model.update(TrackObservation(est.t + 201.0, (0.5, 0.5), (1.0, 0.0)))
    assert jumped.p(1) == pytest.approx(later[-1].p(1), abs=1e-3)


def test_a_person_who_stops_keeps_the_belief_and_has_an_eta_at_a_walking_pace():
    model = GoalInference(GRID, [1])
    history = feed(model, walk([DOOR, (6.3, 2.5)]))
    p_walk = history[-1][1].p(1)
    t0 = history[-1][1].t
    for k in range(1, 31):  # 3 s standing 1 m from the cell
        est = model.update(TrackObservation(t0 + 0.1 * k, (6.3, 2.5), (0.02, -0.03)))
    assert not est.moving and est.speed_mps < 0.1
    assert est.p(1) == pytest.approx(p_walk * math.exp(-0.15) + 0.5 * (1 - math.exp(-0.15)))
    f = est.forecast(1)
    assert f.distance_m == pytest.approx(math.hypot(0.3, 1.0))
    assert f.eta_s == pytest.approx(f.distance_m / IntentConfig().eta_min_speed_mps)


def test_inside_a_restricted_cell():
    model = GoalInference(GRID, [1, 12])
    est = model.update(TrackObservation(0.0, (5.5, 0.7)))
    assert est.inside == 1 and est.p(1) == pytest.approx(0.9)
    assert est.forecast(1).eta_s == 0.0 and est.forecast(1).distance_m == 0.0
    assert est.p(12) + est.p_elsewhere == pytest.approx(0.1)
    # walking out and away, the belief falls
    t = 0.0
    for _ in range(20):
        t += 0.1
        est = model.update(TrackObservation(t, (5.5 - 1.2 * t, 1.4), (-1.2, 0.0)))
    assert est.inside is None and est.p(1) < 0.2


def test_a_visitor_walking_out_has_reached_that_goal_and_may_head_for_the_other():
    """Out of cell 1 by ``renew_after_visit_m``, the visitor's belief starts from the
    prior again: P(1) falls at once (not over metres of walking away), and their walk on
    toward 12 counts for 12 from the first step. Never renewing, P(1) stays high for
    the first steps out (stepping back and forth over the border is one visit)."""
    out = walk([(5.5, 0.75), (5.5, 2.0), (1.0, 2.25)], speed=1.0, heading_noise_deg=0.0,
               pos_noise_m=0.0)  # fmt: skip
    histories = {}
    for margin in (0.3, -1.0):
        cfg = IntentConfig(renew_after_visit_m=margin, rationality_per_m=3.0)  # weak steps
        model = GoalInference(GRID, [1, 12], cfg)
        model.update(TrackObservation(-1.0, (5.5, 0.75)))  # inside 1, at the prior
        histories[margin] = feed(model, out)
    renewed, kept = histories[0.3], histories[-1.0]
    assert at(renewed, 0.5).inside == at(kept, 0.5).inside == 1  # still in: 0.9 both
    assert at(renewed, 0.5).p(1) == pytest.approx(0.9)
    # 0.35 m out of cell 1 (y 1.85): renewed is back near the prior, kept is not
    assert at(renewed, 1.1).p(1) < 0.3 < 0.5 < at(kept, 1.1).p(1)
    # heading west toward 12, the renewed belief gets there sooner
    assert at(renewed, 2.5).p(12) > at(kept, 2.5).p(12)


def test_eta_is_distance_over_speed_and_an_estimate_is_json_ready():
    model = GoalInference(GRID, [1])
    before = model.estimate()
    assert before.position_m is None and math.isinf(before.forecast(1).eta_s)
    est = model.update(TrackObservation(0.0, (2.0, 0.75), (1.0, 0.0)))
    assert est.forecast(1).distance_m == pytest.approx(3.0)
    assert est.forecast(1).eta_s == pytest.approx(3.0)
    d = json.loads(json.dumps(est.as_dict()))
    assert d["eta_s"] == {"1": 3.0} and d["inside"] is None
    assert est.changed(None) and not est.changed(est)
    assert sum(est.hypotheses.values()) == pytest.approx(1.0)
    # a stale estimate (older than the last) is ignored
    again = model.update(TrackObservation(-1.0, (0.5, 0.5), (1.0, 0.0)))
    assert again.position_m == (2.0, 0.75)


def test_distances_to_rectangles():
    rects = np.array([GRID.bounds(1), [7.0, 4.0, 7.0, 4.0]])
    d = distances_to(rects, np.array([[5.5, 0.5], [7.0, 2.5], [4.0, 3.0]]))
    assert d[0] == pytest.approx([0.0, math.hypot(1.0, 1.0), math.hypot(1.0, 1.5)])
    assert d[1] == pytest.approx([math.hypot(1.5, 3.5), 1.5, math.hypot(3.0, 1.0)])


def test_tracker_keeps_one_belief_per_person_and_forgets_the_lost():
    tracker = IntentTracker(GoalInference(GRID, [1, 12]), drop_after_s=5.0)
    east = walk([DOOR, (5.5, 0.75)], seed=1)
    west = walk([DOOR, (0.5, 2.25)], seed=2)
    for (_, a), (_, b) in zip(east[:25], west[:25], strict=True):
        b = TrackObservation(b.t, b.position_m, b.velocity_mps, track_id=7)
        out = tracker.update(a.t, [a, b])
    assert set(out) == {0, 7}
    assert out[0].most_likely == 1 and out[7].most_likely == 12
    t = east[24][1].t
    out = tracker.update(t + 3.0, [TrackObservation(t + 3.0, (4.0, 2.0), None, track_id=7)])
    assert set(out) == {0, 7}
    assert set(tracker.update(t + 6.0, [])) == {7}  # track 0 unseen for 6 s


def test_from_a_leg_tracker_estimate():
    from stack.perception.tracker import TrackEstimate

    est = TrackEstimate(4, (1.0, 2.0), (0.5, -0.5), math.hypot(0.5, 0.5), 9, 12.5, True)
    obs = TrackObservation.from_track(est)
    assert (obs.t, obs.track_id, obs.position_m) == (12.5, 4, (1.0, 2.0))
    assert obs.velocity == pytest.approx([0.5, -0.5])
    h = TrackObservation(0.0, (0.0, 0.0), heading_rad=math.pi / 2, speed_mps=2.0)
    assert h.velocity == pytest.approx([0.0, 2.0])


@pytest.mark.parametrize("beta,lapse,dt", [(5.0, 0.1, 0.5), (12.0, 0.05, 0.25)])
def test_rationality_fitted_on_walks_drawn_with_a_known_beta_comes_back(beta, lapse, dt):
    rng = np.random.default_rng(11)
    tracks = []
    for _ in range(80):
        goal = int(rng.integers(1, GRID.n_cells + 1))
        start = (float(rng.uniform(-1.0, 7.0)), float(rng.uniform(-1.0, 4.0)))
        tracks.append(simulate_goal_walk(GRID, goal, start, rng, beta, lapse, 1.0, dt, 60))
    fit = fit_rationality(tracks, GRID)
    assert fit.rationality_per_m == pytest.approx(beta, rel=0.15)
    assert fit.lapse == pytest.approx(lapse, abs=0.06)
    assert fit.steps > 300 and fit.log_likelihood_per_step > 0  # better than no goal
    assert fit.config.rationality_per_m == fit.rationality_per_m
    assert track_log_likelihood(tracks, GRID, fit.config) == pytest.approx(fit.log_likelihood)
    worse = IntentConfig(rationality_per_m=beta / 3, lapse=fit.lapse)
    assert track_log_likelihood(tracks, GRID, worse) < fit.log_likelihood
    # a goal given as a point (the door) works too
    door = simulate_goal_walk(GRID, DOOR, (1.0, 1.0), rng, beta, 0.0, 1.0, 0.25, 60)
    assert door.goal == DOOR and math.dist(door.observations[-1].position_m, DOOR) < 0.5


def test_a_cell_as_spots_a_walker_may_head_for():
    """``goal_spots``: a cell is n x n places; a step's likelihood under it is the mean
    over its places: a walk to the middle of cell 1 goes to cell 1, one out of it to
    cell 6 leaves it."""
    from stack.planning.intent import goal_spots, spot_likelihood

    assert goal_spots((5.0, 0.0, 6.0, 1.5), 0).tolist() == [[5.0, 0.0, 6.0, 1.5]]
    assert goal_spots((5.0, 0.0, 6.0, 1.5), 2)[:, :2].tolist() == [
        [5.25, 0.375], [5.25, 1.125], [5.75, 0.375], [5.75, 1.125]
    ]  # fmt: skip
    assert goal_spots((7.0, 5.2, 7.0, 5.2), 3).tolist() == [[7.0, 5.2, 7.0, 5.2]]  # a point
    spots = np.concatenate([goal_spots(GRID.bounds(1), 3), goal_spots(GRID.bounds(2), 3)])
    owner = np.repeat([0, 1], 9)
    x, d = np.array([4.0, 2.6]), np.array([0.3, -0.4]) * 0.6  # toward (5.5, 0.6)
    lik = spot_likelihood(spots, owner, 2, x, d, 32, 8.0, 0.05)
    each = [spot_likelihood(spots[k : k + 1], np.zeros(1, int), 1, x, d, 32, 8.0, 0.05)[0]
            for k in range(18)]  # fmt: skip
    assert lik == pytest.approx([np.mean(each[:9]), np.mean(each[9:])])
    walk_in = walk([(4.0, 2.6), (5.5, 0.6)], speed=1.0, pos_noise_m=0.0, heading_noise_deg=0.0)
    model = GoalInference(GRID, [1, 12], IntentConfig(goal_spots=3, rationality_per_m=8.0))
    assert at(feed(model, walk_in), 1.2).p(1) > 0.8
    model = GoalInference(GRID, [1, 12], IntentConfig(goal_spots=3, rationality_per_m=8.0))
    est = at(feed(model, walk([(5.5, 0.4), (2.5, 2.5)], speed=1.0)), 2.5)  # to cell 6
    assert est.p(1) < 0.05


def test_a_fit_with_spots_recovers_walks_drawn_to_places_in_cells():
    """Walks to a random place in a cell are likelier under its spots than under its
    nearest point (each model at its own best fit)."""
    rng = np.random.default_rng(5)
    tracks = []
    for _ in range(60):
        goal = int(rng.integers(1, GRID.n_cells + 1))
        x0, y0, x1, y1 = GRID.bounds(goal)
        place = (float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1)))
        start = (float(rng.uniform(-1.0, 7.0)), float(rng.uniform(-1.0, 4.0)))
        if math.dist(start, place) < 1.0:
            continue
        obs = [o for _, o in walk([start, place], speed=1.0, seed=int(rng.integers(1 << 30)))]
        tracks.append(LabelledTrack(goal, tuple(obs)))
    near = fit_rationality(tracks, GRID, IntentConfig(goal_spots=0))
    spots = fit_rationality(tracks, GRID, IntentConfig(goal_spots=3))
    assert spots.log_likelihood > near.log_likelihood


def test_the_calibrated_rationality_is_the_one_whose_beliefs_name_the_goal_best():
    """Walks drawn from the model at beta 5 toward random cells: the belief scores the
    true goal best near 5, worse at 1 (too vague) and at 40 (too sure); a walk to a
    point that is no goal of the inference is left out, and with none left it says
    so."""
    from stack.planning.intent import calibrate_rationality, goal_log_score

    rng = np.random.default_rng(3)
    tracks = []
    for _ in range(60):
        goal = int(rng.integers(1, GRID.n_cells + 1))
        start = (float(rng.uniform(-1.0, 7.0)), float(rng.uniform(-1.0, 4.0)))
        tracks.append(simulate_goal_walk(GRID, goal, start, rng, 5.0, 0.0, 1.0, 0.25, 60))
    model = GoalInference(GRID, [1, 12], IntentConfig(lapse=0.05))
    best, scores = calibrate_rationality(tracks, model, (1.0, 3.0, 5.0, 7.0, 40.0))
    assert best in (3.0, 5.0, 7.0) and scores[best] == max(scores.values())
    assert scores[1.0] < scores[best] and scores[40.0] < scores[best]
    assert all(v < 0 for v in scores.values())
    nowhere = simulate_goal_walk(GRID, (3.0, 5.0), (1.0, 1.0), rng, 5.0, 0.0, 1.0, 0.25, 30)
    assert goal_log_score([*tracks, nowhere], model) == pytest.approx(goal_log_score(tracks, model))
    with pytest.raises(ConfigError, match="tracks"):
        goal_log_score([nowhere], model)


@pytest.mark.parametrize(
    "make,key",
    [
        (lambda: IntentConfig(rationality_per_m=-1.0), "rationality_per_m"),
        (lambda: IntentConfig(lapse=1.0), "lapse"),
        (lambda: IntentConfig(restricted_prior=0.0), "restricted_prior"),
        (lambda: IntentConfig(switch_rate_per_s=-0.1), "switch_rate_per_s"),
        (lambda: IntentConfig(directions=4), "directions"),
        (lambda: IntentConfig(eta_min_speed_mps=0.0), "eta_min_speed_mps"),
        (lambda: IntentConfig(inside_belief=1.5), "inside_belief"),
        (lambda: IntentConfig(goal_spots=11), "goal_spots"),
        (lambda: IntentConfig(goal_spots=2.5), "goal_spots"),
        (lambda: IntentConfig(renew_after_visit_m=-2.0), "renew_after_visit_m"),
        (lambda: IntentConfig(rationality_per_m=float("nan")), "rationality_per_m"),
        (lambda: IntentConfig.from_dict({"lapse": 2}), "intent.lapse"),
        (lambda: IntentConfig.from_dict({"beta": 3}), "intent.beta"),
        (lambda: IntentConfig.from_dict({"directions": 2.5}), "intent.directions"),
        (lambda: GoalInference(GRID, [13]), "restricted_cells"),
        (lambda: GoalInference(GRID, [1, 1]), "restricted_cells"),
        (lambda: GoalInference(GRID, []), "restricted_cells"),
        (lambda: GoalInference(GRID, [1], exits=[(1.0, math.inf)]), "exits[0]"),
        (lambda: IntentTracker(GoalInference(GRID, [1]), drop_after_s=0.0), "drop_after_s"),
        (lambda: fit_rationality([], GRID), "tracks"),
        (lambda: fit_rationality([LabelledTrack(1, ())], GRID), "tracks"),
        (lambda: fit_rationality([LabelledTrack(99, ())], GRID), "goal"),
        (lambda: fit_rationality([LabelledTrack(1, ())], GRID, beta_max=0.0), "beta_max"),
    ],
)
def test_bad_parameters_are_refused_naming_the_key(make, key):
    with pytest.raises(ConfigError) as err:
        make()
    assert err.value.key == key
    assert key in str(err.value)


def test_elsewhere_without_destinations_is_wandering():
    cfg = IntentConfig(other_cells_as_goals=False, wander_share=0.0)
    model = GoalInference(GRID, [1], cfg)
    assert [g.name for g in model.goals] == ["cell 1", "wander"]
    est = at(feed(model, walk([DOOR, (5.5, 0.75)])), 1.0)
    assert est.p(1) > 0.5
    with_door = GoalInference(GRID, [1], exits=[(7.0, 5.2)])
    assert with_door.goals[-2].name == "exit 1"
