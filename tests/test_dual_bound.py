"""The information-relaxation (dual) upper bound on exogenous-belief models."""

from pathlib import Path

import numpy as np
import pytest

from stack.planning.dual import default_horizon, dual_upper_bound
from stack.planning.momdp_model import MixedModel, factored_fib
from stack.planning.sarsop import BeliefTreeSearch
from stack.planning.search_base import SearchConfig
from tests.test_solver_momdp import _b0, _flat, _mixed


def _start(m: MixedModel, x: int = 0) -> np.ndarray:
    return _b0(m, x)[x * m.Y : (x + 1) * m.Y] / _b0(m, x).sum()


def test_with_the_exact_value_as_penalty_every_path_is_worth_exactly_v_star():
    # the person observed exactly after each move: the fast informed bound is then the
    # MDP's exact value, and a penalty from V* leaves the clairvoyant nothing to gain
    m0 = _mixed(1, X=3, Y=4, A=3, Z=2, discount=0.9)
    m = MixedModel(TX=m0.TX, TY=m0.TY, OY=np.eye(m0.Y), R=m0.R, discount=m0.discount)
    Q = factored_fib(m, tol=1e-12, max_iterations=20000)
    b = _start(m)
    d = dual_upper_bound(m, Q, 0, b, paths=40, seed=3)
    v = d.values
    v_star = float((b @ Q[0]).max())
    # to float32's rounding: the step's products run in float32 (dual.py)
    assert np.allclose(v, v_star, atol=1e-4)
    assert d.sd < 1e-4


@pytest.mark.parametrize("seed", [0, 2])
def test_the_dual_bound_lies_between_v_star_and_the_fast_informed_bound(seed):
    m = _mixed(seed, X=3, Y=3, A=2, Z=2, discount=0.9)
    b0 = _b0(m)
    exact = BeliefTreeSearch(
        _flat(m, b0), SearchConfig(time_limit_s=None, target_gap=1e-6, max_trials=300)
    ).run()
    Q = factored_fib(m, tol=1e-12, max_iterations=20000)
    b = _start(m)
    d = dual_upper_bound(m, Q, 0, b, paths=400, seed=seed)
    v = d.values
    fib = float((b @ Q[0]).max())
    # pathwise below the fast informed bound (a supersolution), in mean above V*
    assert (v <= fib + 1e-4).all()  # to float32's rounding
    assert d.mean + 2 * d.ci95 >= exact.lower_bound - 1e-9
    assert d.mean < fib  # the relaxation is tighter than the bound it is built from


def test_same_seed_same_bound_other_seed_other_paths():
    m = _mixed(4, X=3, Y=4, A=2, Z=3, discount=0.95)
    Q = factored_fib(m, tol=1e-10)
    b = _start(m)
    a = dual_upper_bound(m, Q, 0, b, paths=8, horizon=30, seed=1)
    again = dual_upper_bound(m, Q, 0, b, paths=8, horizon=30, seed=1)
    assert (again.mean, again.sd) == (a.mean, a.sd)
    assert dual_upper_bound(m, Q, 0, b, paths=8, horizon=30, seed=2).mean != a.mean
    assert dual_upper_bound(m, Q, 0, b, paths=8, horizon=30, seed=(1, 1)).mean != a.mean
    assert a.horizon == 30 and a.paths == 8


def test_bad_input_is_named():
    m = _mixed(0)
    Q = factored_fib(m)
    b = _start(m)
    with pytest.raises(ValueError, match="shape"):
        dual_upper_bound(m, Q[:, :, :1], 0, b)
    with pytest.raises(ValueError, match="start cell"):
        dual_upper_bound(m, Q, m.X, b)
    with pytest.raises(ValueError, match="distribution"):
        dual_upper_bound(m, Q, 0, b * 2)
    with pytest.raises(ValueError, match="paths"):
        dual_upper_bound(m, Q, 0, b, paths=1)
    with pytest.raises(ValueError, match="discount"):
        default_horizon(1.0)
    with pytest.raises(TimeoutError):
        dual_upper_bound(m, Q, 0, b, paths=4, deadline=-1.0)


def test_solver_config_checks_the_dual_paths():
    from stack.planning.solve import SolverConfig

    for bad in (15, 24, -16):
        with pytest.raises(ValueError, match="dual_paths"):
            SolverConfig(dual_paths=bad)
    assert SolverConfig(dual_paths=0).dual_paths == 0
    assert SolverConfig(dual_paths=32).dual_paths == 32


def test_t_quantile_widens_the_interval_for_few_paths():
    from stack.planning.dual import t95

    assert t95(15) == pytest.approx(2.1314, abs=1e-3)
    assert t95(63) == pytest.approx(1.9983, abs=1e-3)
    assert t95(3) == pytest.approx(3.182)
    assert t95(10_000) == pytest.approx(1.96, abs=1e-3)
    with pytest.raises(ValueError, match="dof"):
        t95(0)


@pytest.mark.slow
def test_task_r1_solve_reports_a_dual_bound_between_its_bounds():
    from stack.planning.solve import SolverConfig, solve_task_model
    from stack.planning.task import load_task

    task = load_task(Path(__file__).resolve().parents[1] / "config" / "task-r1.yaml")
    config = SolverConfig(algorithm="sarsop", trials=30, beliefs=20, iterations=2, dual_paths=32)
    r = solve_task_model(task, config).result
    assert r.dual is not None and r.dual.paths == 32
    # an upper bound on V*: above the policy's value, below the fast informed bound
    assert r.lower_bound <= r.dual.upper
    assert r.dual.mean <= r.upper_bound
    s = r.summary()
    assert s["dual_upper"] == pytest.approx(r.dual.upper)
    assert s["dual_relative_gap"] < s["relative_gap"]
