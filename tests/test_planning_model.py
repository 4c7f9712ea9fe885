"""The task model: task files, factored and flat forms, rewards, belief updates."""

from pathlib import Path

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError, Direction
from stack.planning import belief as B
from stack.planning.model import ModelSizeError, build_model, velocity_index
from stack.planning.task import Task, load_task
from stack.vocabulary import ACTIONS

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def r1():
    model = build_model(load_task(REPO / "config" / "task-r1.yaml"))
    return model, model.flat()


def test_shipped_task_files_load_with_the_thesis_settings():
    for name, restricted in (("r1", (1,)), ("r2", (1, 12))):
        task = load_task(REPO / "config" / f"task-{name}.yaml")
        assert task.restricted_cells == restricted
        assert task.rest_cell == 7 and task.people == 1 and task.discount == 0.99
        assert task.grid.numbering == ((12, 10, 8, 6, 4, 2), (11, 9, 7, 5, 3, 1))
        assert task.rewards.move == -0.2 and task.rewards.out_of_map == -30


def test_sizes_of_the_case_study(r1):
    model, pomdp = r1
    assert (pomdp.n_states, pomdp.n_actions, pomdp.n_observations) == (845, 5, 2197)
    pomdp.validate(1e-9)


def test_every_factor_is_a_distribution(r1):
    model, _ = r1
    np.testing.assert_allclose(model.robot_T.sum(-1), 1, atol=1e-9)
    np.testing.assert_allclose(model.direction_T.sum(-1), 1, atol=1e-9)
    np.testing.assert_allclose(model.position_T.sum(-1), 1, atol=1e-9)
    np.testing.assert_allclose(model.obs_position.sum(-1), 1, atol=1e-9)
    np.testing.assert_allclose(model.obs_velocity.sum(-1), 1, atol=1e-9)


def test_person_models_have_no_zero_probabilities(r1):
    """Section 3.2.4: "exact values of 0 and 1 must be avoided"."""
    model, _ = r1
    assert (model.direction_T > 0).all()
    assert (model.position_T > 0).all()
    assert (model.obs_position > 0).all()
    assert (model.obs_velocity > 0).all()


def test_direction_model_keeps_direction_and_rarely_reverses(r1):
    model, _ = r1
    T = model.direction_T
    for d in (Direction.NORTH, Direction.SOUTH, Direction.EAST, Direction.WEST):
        assert T[d].argmax() == d
        assert T[d, d.opposite] == T[d, :4].min()


def test_robot_transition_matches_appendix_a(r1):
    model, _ = r1
    g = model.task.grid
    east = ACTIONS.index("East")
    i9, i7 = g.cells.index(9), g.cells.index(7)
    assert model.robot_T[east, i9, i7] == pytest.approx(0.95)
    assert model.robot_T[east, i9, i9] == pytest.approx(0.05)
    # North from 12 leaves the map; out of the map is absorbing
    north = ACTIONS.index("North")
    out = model.n_cells
    assert model.robot_T[north, g.cells.index(12), out] == pytest.approx(0.95)
    assert model.robot_T[:, out, out] == pytest.approx(1.0)


def test_rewards_follow_table_4_1(r1):
    model, _ = r1
    R = model.reward_table()
    ri, pi = model.robot_index, model.position_index
    nm, east, west = Direction.NOT_MOVING, Direction.EAST, Direction.WEST
    nothing = ACTIONS.index("Do nothing")
    assert R[ri(7), pi(3), nm, nothing] == 0
    assert R[ri(1), pi(1), nm, nothing] == 30  # at the restricted cell
    assert R[ri(1), pi(3), nm, nothing] == 30  # adjacent, not moving away
    assert R[ri(1), pi(3), west, nothing] == -10  # adjacent, moving away
    assert R[ri(1), pi(5), east, nothing] == 30  # two cells away, moving towards
    assert R[ri(1), pi(6), east, nothing] == 30
    assert R[ri(1), pi(5), west, nothing] == -10
    assert R[ri(1), pi(None), nm, nothing] == -10
    assert R[ri(4), pi(1), nm, nothing] == -3
    assert R[ri(None), pi(1), nm, nothing] == -30
    assert R[ri(7), pi(1), nm, ACTIONS.index("East")] == pytest.approx(-0.2)


def test_two_restricted_cells_reward_cell_12(r1):
    task = load_task(REPO / "config" / "task-r2.yaml")
    R = build_model(task).reward_table()
    m = build_model(task)
    assert R[m.robot_index(12), m.position_index(11), Direction.NOT_MOVING, 4] == 30
    assert R[m.robot_index(12), m.position_index(8), Direction.WEST, 4] == 30
    r1_model, _ = r1
    assert r1_model.reward_table()[r1_model.robot_index(12), 0, 0, 4] == -3


def test_belief_update_is_normalised_and_leaves_input_untouched(r1):
    model, pomdp = r1
    b = model.initial_belief(7, [(11, "not moving")])
    before = b.copy()
    z = model.observation_index(7, [(9, "East higher")])
    b1 = B.update(pomdp, b, ACTIONS.index("Do nothing"), z)
    assert b1.sum() == pytest.approx(1.0, abs=1e-12)
    assert (b1 >= 0).all()
    np.testing.assert_array_equal(b, before)


def test_zero_probability_observation_raises_and_keeps_belief(r1):
    model, pomdp = r1
    b = model.initial_belief(7, [(11, "not moving")])
    before = b.copy()
    # the robot cannot be observed at 1 after "Do nothing" at 7 (deterministic robot obs)
    z = model.observation_index(1, [(9, "East higher")])
    with pytest.raises(B.ZeroProbabilityObservation, match="probability 0"):
        B.update(pomdp, b, ACTIONS.index("Do nothing"), z)
    np.testing.assert_array_equal(b, before)
    assert np.isfinite(b).all()


def test_factored_belief_equals_flat_belief(r1):
    model, pomdp = r1
    b = model.initial_belief(8, [(None, "not moving")])
    fb = B.FactoredBelief(model, b.reshape(model.state_shape))
    for action, robot, person, vel in [
        ("South", 7, None, "Not moving"),
        ("Do nothing", 7, 10, "East 0-0.2"),
        ("Do nothing", 7, 5, "East 0-0.2"),
    ]:
        a = ACTIONS.index(action)
        z = model.observation_index(robot, [(person, vel)])
        b = B.update(pomdp, b, a, z)
        fb = fb.update(a, tuple(int(i) for i in np.unravel_index(z, model.obs_shape)))
    np.testing.assert_allclose(fb.flat(), b, atol=1e-12)


def test_two_people_build_and_track(r1):
    """The general model builds for n = 2: factored on the case-study grid, flat on a small one."""
    task = load_task(REPO / "config" / "task-r1.yaml").replace(people=2)
    model = build_model(task)
    assert model.n_states == 13 * (13 * 5) ** 2
    with pytest.raises(ModelSizeError, match="FactoredBelief"):
        model.flat()
    fb = B.FactoredBelief.certain(model, 7, [(11, "not moving"), (None, "not moving")])
    z = (
        model.robot_index(7),
        model.position_index(9),
        velocity_index("East", "higher"),
        model.position_index(2),
        0,
    )
    fb2 = fb.update(ACTIONS.index("Do nothing"), z)
    assert fb2.tensor.sum() == pytest.approx(1.0)
    # people are independent: person 1's marginal equals the one-person belief
    one, one_flat = r1
    b = B.update(
        one_flat,
        one.initial_belief(7, [(11, "not moving")]),
        ACTIONS.index("Do nothing"),
        one.observation_index(7, [(9, "East higher")]),
    )
    np.testing.assert_allclose(
        fb2.marginal(1), b.reshape(one.state_shape).sum(axis=(0, 2)), atol=1e-12
    )
    # person 2, certainly absent before, seen entering at 2: cell 2 becomes the likeliest
    # cell, far above an entering person's ~1 % per cell (with the fitted 14 % false
    # positives one sighting may leave "No person" likelier still)
    m = fb2.marginal(3)
    cells = [model.position_index(c) for c in range(1, 13)]
    assert max(cells, key=lambda i: m[i]) == model.position_index(2)
    assert m[model.position_index(2)] > 10 * m[model.position_index(3)]

    small = Task(
        grid=CellGrid(numbering=((2,), (1,))),
        restricted_cells=(1,),
        rest_cell=2,
        people=2,
        initial=task.initial.__class__(robot=2, person=None),
    )
    flat = build_model(small).flat()
    assert flat.n_states == 3 * (3 * 5) ** 2
    flat.validate(1e-9)


@pytest.mark.parametrize(
    "patch, key",
    [
        ({"discount": 1.5}, "discount"),
        ({"restricted_cells": [13]}, "restricted_cells"),
        ({"rest_cell": 1}, "rest_cell"),
        ({"people": 0}, "people"),
        ({"direction": {"keep": 0.9, "turn": 0.1}}, "direction"),
        ({"direction": {"reverse": 0.15}}, "direction.reverse"),
        ({"obs_position": {"correct": 1.2}}, "obs_position.correct"),
        ({"obs_velocity": {"moving_speed": [1, 2]}}, "obs_velocity.moving_speed"),
        ({"position": {"floor": 0}}, "position.floor"),
        ({"rewards": {"move": "cheap"}}, "rewards.move"),
        ({"rewardz": {}}, "rewardz"),
        ({"grid": {"numbering": [[1, 2], [3]]}}, "grid.numbering[1]"),
        ({"grid": {"numbering": [[1, 2], [2, 4]]}}, "grid.numbering"),
        ({"initial": {"person": "nobody"}}, "initial.person"),
        ({"rewards": {"restricted_guarded": float("nan")}}, "rewards.restricted_guarded"),
        ({"discount": float("inf")}, "discount"),
        ({"initial": {"direction": "up"}}, "initial.direction"),
    ],
)
def test_bad_task_values_are_rejected_naming_the_key(patch, key):
    with pytest.raises(ConfigError) as err:
        Task.from_dict(patch)
    assert err.value.key == key
    assert key in str(err.value)


def test_a_task_built_in_code_is_checked_like_a_file():
    from stack.planning.task import Rewards

    with pytest.raises(ConfigError, match="move: nan"):
        Rewards(move=float("nan"))  # was solved into a NaN policy (issue 13)
    with pytest.raises(ConfigError, match="people"):
        Task(people=True)  # type: ignore[arg-type]


def test_malformed_task_file_names_the_problem(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("grid: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_task(bad)
