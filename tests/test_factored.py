"""The per-person belief of the n-person task (issue 16) against the exact joint belief."""

import numpy as np
import pytest

from stack.cells import CellGrid
from stack.planning import belief as B
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.model import build_model
from stack.planning.task import Initial, Task


def small_task(people: int = 2) -> Task:
    # 2 x 2 cells: the flat two-person model (3,125 states) is small enough to build
    return Task(
        name="small",
        grid=CellGrid(numbering=((4, 2), (3, 1))),
        restricted_cells=(1, 4),
        rest_cell=3,
        people=people,
        initial=Initial(robot=3, person=None),
    )


@pytest.fixture(scope="module")
def small():
    model = build_model(small_task())
    return model, model.flat(), PeopleModel(model)


def test_factored_belief_matches_the_exact_joint_belief(small):
    model, pomdp, pm = small
    persons = [(2, "east"), (None, "not moving")]
    fb = PeopleBelief.certain(pm, 3, persons)
    tensor = B.FactoredBelief.certain(model, 3, persons)
    flat = model.initial_belief(3, persons)
    np.testing.assert_allclose(fb.joint(pm).ravel(), flat, atol=1e-15)
    rng = np.random.default_rng(7)
    for _ in range(12):
        a = int(rng.integers(5))
        p = B.observation_probabilities(pomdp, flat, a)
        z = int(rng.choice(len(p), p=p / p.sum()))
        parts = tuple(int(x) for x in np.unravel_index(z, model.obs_shape))
        flat = B.update(pomdp, flat, a, z)
        tensor = tensor.update(a, parts)
        fb = fb.update(pm, a, parts)
        np.testing.assert_allclose(fb.joint(pm).ravel(), flat, atol=1e-12)
        np.testing.assert_allclose(fb.joint(pm), tensor.tensor, atol=1e-12)
        np.testing.assert_allclose(fb.persons.sum(axis=1), 1.0)


def test_a_spread_belief_stays_exact(small):
    """From an uncertain (product) start the two stay equal too."""
    model, pomdp, pm = small
    rng = np.random.default_rng(3)
    persons = rng.random((2, pm.n_person))
    persons /= persons.sum(axis=1, keepdims=True)
    fb = PeopleBelief(pm.model.robot_index(1), persons)
    flat = fb.joint(pm).ravel()
    for a, z in ((4, 0), (3, 0), (0, 0)):
        p = B.observation_probabilities(pomdp, flat, a)
        z = int(np.argmax(p))  # the likeliest observation
        flat = B.update(pomdp, flat, a, z)
        fb = fb.update(pm, a, tuple(int(x) for x in np.unravel_index(z, model.obs_shape)))
        np.testing.assert_allclose(fb.joint(pm).ravel(), flat, atol=1e-12)


def test_expected_reward_is_the_reward_tables_expectation(small):
    model, _, pm = small
    rng = np.random.default_rng(1)
    persons = rng.random((2, pm.n_person)) ** 4
    persons /= persons.sum(axis=1, keepdims=True)
    R = model.reward_table()  # (R, P1, D1, P2, D2, A)
    b1, b2 = (p.reshape(model.n_cells + 1, 5) for p in persons)
    expected = np.einsum("rijkla,ij,kl->ra", R, b1, b2)
    np.testing.assert_allclose(pm.expected_reward(persons), expected, atol=1e-12)
    # batched
    both = np.stack([persons, persons[::-1]])
    np.testing.assert_allclose(pm.expected_reward(both)[0], expected, atol=1e-12)


def test_impossible_observations_are_refused(small):
    model, _, pm = small
    fb = PeopleBelief.certain(pm, 3, [(2, "east"), (None, "not moving")])
    stay = 4
    with pytest.raises(B.ZeroProbabilityObservation):
        fb.update(pm, stay, (model.robot_index(1), 0, 0, 0, 0))  # the robot jumped
    with pytest.raises(ValueError):
        fb.update(pm, stay, (model.robot_index(3), 0, 0))  # one person's parts missing


def test_one_person_matches_the_one_person_model():
    model = build_model(small_task(people=1))
    pomdp, pm = model.flat(), PeopleModel(model)
    fb = PeopleBelief.certain(pm, 3, [(4, "south")])
    flat = fb.joint(pm).ravel()
    # robot indices: cells 1..4 are 0..3 (stay at 3, North to 4, East to 2)
    for a, parts in ((4, (2, 1, 0)), (0, (3, 0, 4)), (2, (1, 3, 0))):
        z = int(np.ravel_multi_index(parts, model.obs_shape))
        flat = B.update(pomdp, flat, a, z)
        fb = fb.update(pm, a, parts)
        np.testing.assert_allclose(fb.joint(pm).ravel(), flat, atol=1e-12)
