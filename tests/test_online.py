"""The online n-person planner and its baselines (issue 16). No wall-clock asserts:
decision times are measured in bench/bench_online.py."""

import json
from pathlib import Path

import numpy as np
import pytest

from stack.cells import CellGrid
from stack.planning.baselines import (
    GreedyPlanner,
    SinglePlanner,
    most_threatening,
    single_person_policy,
    step_toward,
)
from stack.planning.bounds import qmdp
from stack.planning.evaluate_people import evaluate_planners, run_episodes
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.model import build_model
from stack.planning.online import OnlineConfig, OnlinePlanner, people_mdp_values
from stack.planning.policy import AlphaPolicy
from stack.planning.solve import SolverConfig
from stack.planning.task import Initial, Task, load_task
from stack.vocabulary import ACTIONS

REPO = Path(__file__).resolve().parents[1]
NORTH, SOUTH, EAST, WEST, STAY = (ACTIONS.index(a) for a in ACTIONS)


@pytest.fixture(scope="module")
def pm():
    return PeopleModel.of(load_task(REPO / "config" / "task-r2-n2.yaml"))


def certain(pm, robot, persons):
    return PeopleBelief.certain(pm, robot, persons)


# -- the task file ----------------------------------------------------------------------


def test_the_two_person_task_is_task_r2_with_two_people(pm):
    r2 = load_task(REPO / "config" / "task-r2.yaml")
    assert pm.task.people == 2
    assert pm.task.replace(people=1, name=r2.name) == r2


# -- the leaf values ---------------------------------------------------------------------


@pytest.mark.parametrize("people", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_factored_mdp_values_are_the_flat_models_qmdp(people):
    task = Task(
        name=f"small{people}",
        grid=CellGrid(numbering=((4, 2), (3, 1))),
        restricted_cells=(1, 4),
        rest_cell=3,
        people=people,
        initial=Initial(robot=3, person=None),
    )
    pm = PeopleModel.of(task)
    V = people_mdp_values(pm, people, tolerance=1e-9)
    Q = qmdp(pm.model.flat())
    np.testing.assert_allclose(V.ravel(), Q.max(axis=1), atol=1e-4)


# -- the planner's choices in hand-made beliefs ------------------------------------------


@pytest.mark.parametrize("leaf", ["mdp", "single"])
def test_online_goes_to_the_restricted_cell_where_someone_certainly_is(pm, leaf, single):
    cfg = OnlineConfig(depth=2, samples=16, leaf=leaf)
    planner = OnlinePlanner(pm, cfg, single=single)
    # person 1 resting in restricted cell 1, person 2 resting in the middle (cell 7)
    assert planner.action(certain(pm, 3, [(1, "not moving"), (7, "not moving")])) == EAST
    assert planner.action(certain(pm, 1, [(1, "not moving"), (7, "not moving")])) == STAY
    # the same with the people's slots swapped: the planner does not care which is which
    assert planner.action(certain(pm, 3, [(7, "not moving"), (1, "not moving")])) == EAST
    # the other restricted cell (12, north-west corner), the other person absent
    assert planner.action(certain(pm, 10, [(None, "not moving"), (12, "not moving")])) == WEST
    assert planner.action(certain(pm, 11, [(None, "not moving"), (12, "not moving")])) == NORTH


def test_online_prefers_the_cell_someone_is_in_over_the_empty_one(pm):
    planner = OnlinePlanner(pm, OnlineConfig(depth=2, samples=16))
    # robot at 7 (middle, south row), one person in 12 (north-west corner), the other
    # gone: head there (North and West are equally short routes)
    d = planner.decide(certain(pm, 7, [(12, "not moving"), (None, "not moving")]))
    assert d.action in (NORTH, WEST) and d.values[WEST] > d.values[EAST]
    d = planner.decide(certain(pm, 7, [(None, "not moving"), (1, "not moving")]))
    assert d.action == EAST and d.values[EAST] > d.values[WEST]


def test_online_never_leaves_the_map(pm):
    planner = OnlinePlanner(pm, OnlineConfig(depth=1))
    # cell 1 is in the south-east corner: South and East would leave the map
    d = planner.decide(certain(pm, 1, [(None, "not moving"), (None, "not moving")]))
    assert d.action not in (SOUTH, EAST)


def test_online_is_deterministic_for_a_seed(pm):
    rng = np.random.default_rng(5)
    beliefs = []
    for _ in range(6):
        p = rng.random((2, pm.n_person)) ** 6
        beliefs.append(PeopleBelief(int(rng.integers(12)), p / p.sum(axis=1, keepdims=True)))
    cfg = OnlineConfig(depth=3, samples=6, seed=11)

    def run(c):
        planner = OnlinePlanner(pm, c)
        return [planner.decide(b) for b in beliefs]

    a, b = run(cfg), run(cfg)
    assert [d.action for d in a] == [d.action for d in b]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.values, y.values)
    # another seed draws other observations: other values (the actions may agree)
    c = run(OnlineConfig(depth=3, samples=6, seed=12))
    assert any(not np.array_equal(x.values, y.values) for x, y in zip(a, c, strict=True))
    # episodes too
    e1 = run_episodes(pm, OnlinePlanner(pm, OnlineConfig(samples=8)), 2, seed=3, horizon=15)
    e2 = run_episodes(pm, OnlinePlanner(pm, OnlineConfig(samples=8)), 2, seed=3, horizon=15)
    assert e1.returns == e2.returns


class FakeClock:
    """Every reading advances by ``tick`` seconds."""

    def __init__(self, tick: float):
        self.t, self.tick = 0.0, tick

    def __call__(self) -> float:
        self.t += self.tick
        return self.t


def test_anytime_stops_deepening_when_the_next_level_would_not_fit(pm):
    b = certain(pm, 7, [(5, "east"), (10, "west")])
    full = OnlinePlanner(pm, OnlineConfig(depth=3, samples=4)).decide(b)
    assert full.depth == 3 and full.nodes == 1 + 4 + 16
    # every clock reading costs 10 ms: a level "takes" 20 ms, the next 4 x as many
    cut = OnlinePlanner(
        pm, OnlineConfig(depth=3, samples=4, time_limit_s=0.05), clock=FakeClock(0.01)
    )
    d = cut.decide(b)
    assert d.depth == 1 and d.nodes == 1
    np.testing.assert_allclose(d.values, full.history[0])
    # a level that looked affordable but overran is abandoned midway: the clock stands
    # still for five readings (start, level 1, the next level's start), then jumps
    readings = iter([0.0] * 5 + [10.0] * 100)
    late = OnlinePlanner(
        pm, OnlineConfig(depth=3, samples=4, time_limit_s=1.0), clock=lambda: next(readings)
    )
    d = late.decide(b)
    assert d.depth == 1 and d.nodes == 1
    np.testing.assert_allclose(d.values, full.history[0])
    # three people: the pair leaf, and still an answer
    pm3 = PeopleModel.of(pm.task.replace(people=3))
    b3 = certain(pm3, 3, [(7, "not moving"), (1, "not moving"), (None, "not moving")])
    d3 = OnlinePlanner(pm3, OnlineConfig(depth=2, samples=8)).decide(b3)
    assert d3.action == EAST and d3.depth == 2


def test_three_people_pair_leaf_is_symmetric(pm):
    pm3 = PeopleModel.of(pm.task.replace(people=3))
    planner = OnlinePlanner(pm3, OnlineConfig(depth=1))
    people = [(12, "not moving"), (None, "not moving"), (8, "west")]
    q = planner.decide(certain(pm3, 7, people)).values
    q2 = planner.decide(certain(pm3, 7, people[::-1])).values
    np.testing.assert_allclose(q, q2, atol=1e-9)


# -- the baselines ----------------------------------------------------------------------


def test_step_toward_walks_a_shortest_route(pm):
    idx = pm.model.robot_index
    assert step_toward(pm, idx(7), 1) == SOUTH or step_toward(pm, idx(7), 1) == EAST
    assert step_toward(pm, idx(3), 1) == EAST
    assert step_toward(pm, idx(10), 12) == WEST
    assert step_toward(pm, idx(11), 12) == NORTH
    assert step_toward(pm, idx(12), 12) == STAY
    # from 12 to 1: rows first (south), then east
    assert step_toward(pm, idx(12), 1) == SOUTH


def test_greedy_heads_for_the_restricted_cell_nearest_the_likeliest_intruder(pm):
    g = GreedyPlanner(pm)
    # person 2 at cell 4 heading east (towards restricted cell 1): the intruder
    b = certain(pm, 9, [(7, "not moving"), (4, "east")])
    assert most_threatening(pm, b) == 1
    assert g.target(b) == 1 and g.action(b) == EAST
    # person 1 at 10 heading west (towards 12) is now the likelier intruder
    b = certain(pm, 7, [(10, "west"), (6, "not moving")])
    assert g.target(b) == 12 and g.action(b) == NORTH  # rows first, then west
    # at the target it waits
    assert g.action(certain(pm, 12, [(10, "west"), (None, "not moving")])) == STAY
    # nobody there: back to the rest cell (7)
    nobody = [(None, "not moving")] * 2
    assert g.target(certain(pm, 1, nobody)) == pm.task.rest_cell
    assert g.action(certain(pm, 1, nobody)) == WEST
    assert g.action(certain(pm, 7, nobody)) == STAY


def test_single_applies_the_one_person_policy_to_the_most_threatening_person(pm):
    # a stand-in policy (one vector per action): the chooser is replaced by a spy
    policy = AlphaPolicy(np.zeros((5, pm.n_robot * pm.n_person)), np.arange(5))
    planner = SinglePlanner(pm, policy, flat=True)
    seen = []

    def spy(b):
        seen.append(b)
        return WEST, np.zeros(5)

    planner.choose = spy
    b = certain(pm, 7, [(6, "not moving"), (12, "not moving")])
    assert planner.action(b) == WEST
    assert most_threatening(pm, b) == 1
    np.testing.assert_array_equal(seen[-1], b.person_flat(pm, 1))
    b = certain(pm, 7, [(2, "east"), (None, "not moving")])
    planner.action(b)
    np.testing.assert_array_equal(seen[-1], b.person_flat(pm, 0))


@pytest.fixture(scope="module")
def single(pm, tmp_path_factory):
    """A quickly solved one-person policy (Perseus, few iterations)."""
    quick = SolverConfig(algorithm="perseus", beliefs=60, iterations=15, seed=0)
    return single_person_policy(pm.task, tmp_path_factory.mktemp("pol"), quick)


def test_single_with_a_solved_policy_guards_the_occupied_cell(pm, single):
    planner = SinglePlanner(pm, single)
    b = certain(pm, 3, [(None, "not moving"), (1, "not moving")])
    assert planner.action(b) == EAST


def test_single_factored_lookahead_chooses_as_the_flat_one(pm, single):
    fast, flat = SinglePlanner(pm, single), SinglePlanner(pm, single, flat=True)
    rng = np.random.default_rng(3)
    for _ in range(25):
        persons = rng.dirichlet(np.full(pm.n_person, 0.05), size=2)
        b = PeopleBelief(int(rng.integers(pm.n_cells)), persons)
        i = most_threatening(pm, b)
        _, q = flat.choose(b.person_flat(pm, i))
        np.testing.assert_allclose(fast.values(b.robot, persons[i]), q, rtol=1e-9, atol=1e-6)
        assert fast.action(b) == flat.action(b)


def test_the_one_person_policy_is_cached(pm, tmp_path):
    quick = SolverConfig(algorithm="perseus", beliefs=20, iterations=2, seed=0)
    p1 = single_person_policy(pm.task, tmp_path, quick)
    files = list(tmp_path.iterdir())
    assert len(files) == 1
    p2 = single_person_policy(pm.task, tmp_path, quick)
    np.testing.assert_array_equal(p1.alphas, p2.alphas)
    assert p1.n_states == build_model(pm.task.replace(people=1)).n_states


# -- the command's function ----------------------------------------------------------------


def test_evaluate_planners_prints_mean_and_ci95(pm):
    out = json.loads(
        evaluate_planners(pm.task, "greedy", episodes=3, seed=0, json=True, horizon=10)
    )
    assert {"mean", "ci95", "episodes", "decision_ms_median", "decision_ms_p99"} <= set(out)
    assert out["episodes"] == 3 and out["planner"] == "greedy"
    text = evaluate_planners(pm.task, ["greedy", "online"], episodes=2, seed=0, horizon=5)
    assert text.count("mean discounted return") == 2
    with pytest.raises(ValueError, match="unknown planner"):
        evaluate_planners(pm.task, "oracle", episodes=1, horizon=1)


def test_every_planner_meets_the_same_people(pm):
    """Common random numbers: the people's draws do not depend on the robot."""
    seen: dict[str, list] = {}

    class Recorder:
        def __init__(self, name, action):
            self.name, self.fixed = name, action

        def action(self, b):
            seen.setdefault(self.name, []).append(b.persons.copy())
            return self.fixed

    run_episodes(pm, Recorder("a", STAY), 1, seed=4, horizon=12)
    run_episodes(pm, Recorder("b", WEST), 1, seed=4, horizon=12)
    for x, y in zip(seen["a"], seen["b"], strict=True):
        np.testing.assert_allclose(x, y)


def test_vigil_evaluate_runs_a_planner(capsys):
    from vigil.cli import main

    task = str(REPO / "config" / "task-r2-n2.yaml")
    argv = ["evaluate", task, "--planner", "greedy", "--episodes", "2", "--horizon", "5"]
    assert main([*argv, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["planner"] == "greedy" and out["episodes"] == 2 and "ci95" in out
    # neither a policy nor a planner: a one-line error, exit 2
    assert main(["evaluate", task]) == 2
    assert "--planner" in capsys.readouterr().err
