"""The mixed-observability belief-tree search (stack/planning/momdp.py)."""

import numpy as np
import pytest

from stack.planning.bounds import blind_lower_bound, fast_informed_bound, qmdp
from stack.planning.momdp import MixedSearch
from stack.planning.momdp_model import MixedModel, factored_fib, mixed_from_task
from stack.planning.pomdp import dense_to_pomdp
from stack.planning.sarsop import BeliefTreeSearch
from stack.planning.search_base import SearchConfig


def _mixed(seed: int, X=3, Y=3, A=2, Z=2, discount=0.9) -> MixedModel:
    rng = np.random.default_rng(seed)
    return MixedModel(
        TX=rng.dirichlet(np.ones(X), size=(A, X)),
        TY=rng.dirichlet(np.ones(Y), size=Y),
        OY=rng.dirichlet(np.ones(Z), size=Y),
        R=rng.normal(size=(X, Y, A)),
        discount=discount,
    )


def _flat(m: MixedModel, b0: np.ndarray):
    """The same model multiplied out: x observed exactly beside the person observation."""
    T = np.stack([np.kron(m.TX[a], m.TY) for a in range(m.A)])
    O1 = np.kron(np.eye(m.X), m.OY)
    O = np.stack([O1] * m.A)
    return dense_to_pomdp(T, O, m.R.reshape(m.X * m.Y, m.A), m.discount, b0=b0)


def _b0(m: MixedModel, x: int = 0) -> np.ndarray:
    b = np.zeros(m.X * m.Y)
    b[x * m.Y : (x + 1) * m.Y] = np.arange(1, m.Y + 1) / np.arange(1, m.Y + 1).sum()
    return b


def _search(m, b0, sawtooth=False, beliefs=0, rounds=0, **kw):
    pomdp = _flat(m, b0)
    kw.setdefault("time_limit_s", None)
    kw.setdefault("progress_every_s", 0.0)
    seeds = (blind_lower_bound(pomdp), np.arange(m.A))
    search = MixedSearch(
        m, SearchConfig(**kw), seeds, [b0], sawtooth=sawtooth, beliefs=beliefs, rounds=rounds
    )
    return search.run(), pomdp


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(("sawtooth", "rounds"), [(False, 0), (True, 0), (False, 5)])
def test_bounds_bracket_the_flat_solution(seed, sawtooth, rounds):
    m = _mixed(seed)
    b0 = _b0(m)
    r, pomdp = _search(
        m, b0, sawtooth=sawtooth, beliefs=20, rounds=rounds, target_gap=1e-4, max_trials=300
    )
    flat = BeliefTreeSearch(
        pomdp, SearchConfig(time_limit_s=None, target_gap=1e-6, max_trials=300)
    ).run()
    # both searches bracket V*(b0), so each one's interval meets the other's
    assert r.lower_bound <= flat.upper_bound + 1e-9
    assert r.upper_bound >= flat.lower_bound - 1e-9
    first = r.history[0]
    assert r.upper_bound - r.lower_bound < first.upper - first.lower  # refined
    # the flat policy holds the reported bound: its value at b0 is the lower bound
    assert r.policy.value(b0) == pytest.approx(r.lower_bound, abs=1e-9)


def test_lower_bound_never_decreases_and_upper_never_increases():
    m = _mixed(3, X=4, Y=4, A=3, Z=3, discount=0.95)
    r, _ = _search(m, _b0(m, 1), target_gap=1e-6, max_trials=200)
    lows = [h.lower for h in r.history]
    ups = [h.upper for h in r.history]
    assert all(b >= a - 1e-12 for a, b in zip(lows, lows[1:], strict=False))
    assert all(b <= a + 1e-12 for a, b in zip(ups, ups[1:], strict=False))
    assert lows[-1] > lows[0]


def test_rounds_over_sampled_beliefs_raise_the_lower_bound_and_are_deterministic():
    m = _mixed(7, X=4, Y=5, A=3, Z=4, discount=0.95)
    b0 = _b0(m)
    plain, _ = _search(m, b0, target_gap=0.0, max_trials=1)
    r1, _ = _search(m, b0, beliefs=40, rounds=10, target_gap=0.0, max_trials=1)
    r2, _ = _search(m, b0, beliefs=40, rounds=10, target_gap=0.0, max_trials=1)
    assert r1.lower_bound > plain.lower_bound
    assert r1.lower_bound <= r1.upper_bound
    assert np.array_equal(r1.policy.alphas, r2.policy.alphas)
    lows = [h.lower for h in r1.history]
    assert all(b >= a - 1e-12 for a, b in zip(lows, lows[1:], strict=False))


def test_factored_fib_is_the_flat_fast_informed_bound():
    m = _mixed(4, X=3, Y=4, A=3, Z=3)
    pomdp = _flat(m, _b0(m))
    flat = fast_informed_bound(pomdp, qmdp(pomdp), max_iterations=2000, tol=1e-10)
    ours = factored_fib(m, tol=1e-10)
    assert np.allclose(ours.reshape(-1, m.A), flat, atol=1e-6)


def test_trial_limit_and_deterministic():
    m = _mixed(5, X=4, Y=5, A=3, Z=4, discount=0.95)
    r1, _ = _search(m, _b0(m), target_gap=0.0, max_trials=20)
    r2, _ = _search(m, _b0(m), target_gap=0.0, max_trials=20)
    assert r1.stopped == "trials" and r1.trials == 20
    assert np.array_equal(r1.policy.alphas, r2.policy.alphas)


@pytest.mark.slow
def test_task_r1_factored_bounds_improve_on_qmdp():
    from pathlib import Path

    from stack.planning.model import build_model
    from stack.planning.solve import SolverConfig, solve_task_model
    from stack.planning.task import load_task

    task = load_task(Path(__file__).resolve().parents[1] / "config" / "task-r1.yaml")
    sol = solve_task_model(task, SolverConfig(algorithm="sarsop", trials=30))
    pomdp = build_model(task).flat()
    q = float((qmdp(pomdp).T @ pomdp.b0).max())
    r = sol.result
    assert r.policy.meta["solver"] == "sarsop-momdp"
    assert r.lower_bound < r.upper_bound < q  # the factored fast informed bound is tighter
    assert r.policy.value(pomdp.b0) == pytest.approx(r.lower_bound)
    assert mixed_from_task(build_model(task)).split(pomdp.b0)[0] == sol.model.robot_index(
        task.initial.robot
    )


def test_time_limit_is_checked_inside_trials(monkeypatch):
    """With a clock that moves 10 ms per reading, the search stops within a few
    readings of the limit (the time goes to the clock, not to the search)."""
    from stack.planning import clock as clock_module

    m = _mixed(6, X=4, Y=6, A=3, Z=4, discount=0.99)
    b0 = _b0(m)
    seeds = (blind_lower_bound(_flat(m, b0)), np.arange(m.A))
    now = [0.0]

    def clock():
        now[0] += 0.01
        return now[0]

    monkeypatch.setattr(clock_module, "now", clock)
    cfg = SearchConfig(time_limit_s=3.0, target_gap=0.0, progress_every_s=0.0)
    r = MixedSearch(m, cfg, seeds, [b0], start=0.0).run()
    assert r.stopped == "time"
    assert r.seconds <= 3.0 + 0.2
    assert r.lower_bound <= r.upper_bound


def test_rounds_stop_at_a_plateau():
    """Rounds end once one gains less than ``plateau`` of the gap; with plateau 0 they
    all run. The plateau's lower bound is within that share of the gap of the rest."""
    m = _mixed(7, X=4, Y=5, A=3, Z=4, discount=0.95)
    b0 = _b0(m)
    pomdp = _flat(m, b0)
    seeds = (blind_lower_bound(pomdp), np.arange(m.A))
    cfg = SearchConfig(time_limit_s=None, progress_every_s=0.0, target_gap=0.0, max_trials=1)

    def run(plateau):
        s = MixedSearch(m, cfg, seeds, [b0], beliefs=40, rounds=60, plateau=plateau)
        return s, s.run()

    every, r_every = run(0.0)
    early, r_early = run(0.01)
    assert every.rounds_done == 60
    assert 1 <= early.rounds_done < 60
    assert r_early.lower_bound <= r_every.lower_bound + 1e-12


def test_growing_rounds_sample_more_beliefs_past_a_plateau():
    """With ``grow`` a plateau adds a batch of sampled beliefs instead of ending the
    rounds: the rounds run on and the lower bound is at least the plateau's."""
    m = _mixed(7, X=4, Y=5, A=3, Z=4, discount=0.95)
    b0 = _b0(m)
    pomdp = _flat(m, b0)
    seeds = (blind_lower_bound(pomdp), np.arange(m.A))
    cfg = SearchConfig(time_limit_s=None, progress_every_s=0.0, target_gap=0.0, max_trials=1)

    def run(grow):
        s = MixedSearch(m, cfg, seeds, [b0], beliefs=40, rounds=30, plateau=0.01, grow=grow)
        return s, s.run()

    plain, r_plain = run(False)
    grown, r_grown = run(True)
    assert plain.rounds_done < 30
    assert grown.rounds_done == 30 and grown._batches >= 1
    assert len(grown.nodes) > len(plain.nodes)
    assert r_grown.lower_bound >= r_plain.lower_bound - 1e-12


def test_a_cpu_time_limit_is_read_on_the_cpu_clock_everywhere():
    """Under --cpu-time the start and every deadline are CPU seconds; the fast informed
    bound once compared a CPU-time deadline with wall time and stopped at once."""
    from stack.planning import clock

    m = _mixed(8, X=3, Y=4, A=2, Z=3, discount=0.95)
    b0 = _b0(m)
    seeds = (blind_lower_bound(_flat(m, b0)), np.arange(m.A))
    clock.use_cpu_time(True)
    try:
        cfg = SearchConfig(time_limit_s=60.0, max_trials=3, progress_every_s=0.0)
        s = MixedSearch(m, cfg, seeds, [b0], start=clock.now())
        r = s.run()
    finally:
        clock.use_cpu_time(False)
    np.testing.assert_allclose(s.Q_upper, factored_fib(m), atol=1e-9)
    assert r.stopped != "time" and r.trials == 3
