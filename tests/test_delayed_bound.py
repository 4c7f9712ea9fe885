"""The certified delay-2 revelation upper bound (stack/planning/delayed.py)."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stack.planning.delayed import DelayedBound, delayed_bound
from stack.planning.momdp_model import MixedModel, factored_fib, mdp_start
from stack.planning.sarsop import BeliefTreeSearch
from stack.planning.search_base import SearchConfig
from tests.test_solver_momdp import _b0, _flat, _mixed

REPO = Path(__file__).resolve().parents[1]


def _start(m: MixedModel, x: int = 0) -> np.ndarray:
    return _b0(m, x)[x * m.Y : (x + 1) * m.Y] / _b0(m, x).sum()


def _exact(m: MixedModel):
    return BeliefTreeSearch(
        _flat(m, _b0(m)), SearchConfig(time_limit_s=None, target_gap=1e-6, max_trials=300)
    ).run()


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_the_bound_lies_between_v_star_and_the_fast_informed_bound(seed):
    m = _mixed(seed, X=3, Y=3, A=2, Z=2, discount=0.9)
    exact = _exact(m)  # its lower bound: within ~0.02 of V* on these models
    Q = factored_fib(m, tol=1e-12, max_iterations=20000)
    b = _start(m)
    fib = float((b @ Q[0]).max())
    qmdp = float((b @ mdp_start(m, math.inf, sweeps=20000)[0]).max())
    r = delayed_bound(m, Q, [(0, b), (1, b)], plain=60, upward=200)
    assert r is not None
    # an upper bound on V* (above a near-optimal policy's value), never above the fast
    # informed bound (the delay-1 relaxation), itself below QMDP (delay 0)
    assert r.upper[0] >= exact.lower_bound - 1e-7
    assert r.upper[0] <= fib + 1e-6 <= qmdp + 2e-6
    assert r.eps < 1e-4  # the float32 sweeps converged (the certificate costs little)
    assert r.upper.shape == (2,)


def test_tighter_than_the_fast_informed_bound_where_information_comes_late():
    # a model whose fast informed bound is loose: the relaxation must gain something
    gains = []
    for seed in range(6):
        m = _mixed(seed, X=3, Y=4, A=2, Z=3, discount=0.9)
        Q = factored_fib(m, tol=1e-12, max_iterations=20000)
        b = _start(m)
        r = delayed_bound(m, Q, [(0, b)], plain=60, upward=200)
        gains.append(float((b @ Q[0]).max()) - r.upper[0])
    assert min(gains) > -1e-6
    assert max(gains) > 1e-3


def test_with_the_person_observed_exactly_every_relaxation_is_v_star():
    m0 = _mixed(2, X=3, Y=4, A=3, Z=2, discount=0.9)
    m = MixedModel(TX=m0.TX, TY=m0.TY, OY=np.eye(m0.Y), R=m0.R, discount=m0.discount)
    Q = factored_fib(m, tol=1e-12, max_iterations=20000)
    b = _start(m)
    r = delayed_bound(m, Q, [(0, b)], plain=80, upward=200)
    assert r.upper[0] == pytest.approx(float((b @ Q[0]).max()), abs=1e-4)


def test_the_certificate_covers_a_table_below_the_fixed_point():
    # a table far too low must not give a bound below V*: the float64 residual of
    # H W - W is large there, and the certified value lifts it back above V*
    m = _mixed(1, X=3, Y=3, A=2, Z=2, discount=0.9)
    exact = _exact(m)
    Q = factored_fib(m, tol=1e-12, max_iterations=20000)
    db = DelayedBound(m, Q)
    D = np.full(db.start.shape, -10.0)
    eps = db.residual64(db.start + D)
    assert eps > 0.5  # at least (1 - gamma) of the shift
    b = _start(m)
    assert db.at(D, 0, b) < exact.lower_bound  # the table alone is not a bound
    certified = db.at(D, 0, b) + m.discount**2 * eps / (1 - m.discount)
    assert certified >= exact.lower_bound - 1e-9


def test_no_time_for_the_certificate_gives_none():
    m = _mixed(0, X=3, Y=4, A=2, Z=3)
    Q = factored_fib(m)
    # the first sweep is always run (it times the sweeps); then nothing fits
    assert delayed_bound(m, Q, [(0, _start(m))], deadline=-1.0) is None


@pytest.mark.slow
def test_vigil_solve_reports_the_delayed_bound_below_the_search_s(tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "vigil.cli",
            "solve",
            str(REPO / "config" / "task-r1.yaml"),
            "-o",
            str(tmp_path / "r1.npz"),
            "--time-limit",
            "40",
            "--dual-paths",
            "0",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    d = json.loads(out.stdout)
    if "delayed_note" in d:  # a machine too loaded to certify in time says so
        assert "not certified" in d["delayed_note"]
        return
    assert d["lower_bound"] <= d["upper_bound"] == d["delayed_upper"] < d["search_upper"]
    assert (tmp_path / "r1.npz").exists()


def test_a_short_time_limit_says_why_there_is_no_delayed_bound(tmp_path):
    from stack.planning.solve import SolverConfig, solve_task_model
    from stack.planning.task import load_task

    task = load_task(REPO / "config" / "task-r1.yaml")
    cfg = SolverConfig(trials=2, beliefs=20, iterations=2, time_limit_s=5.0, delayed_bound=True)
    res = solve_task_model(task, cfg, require_progress=False).result
    assert res.delayed is None
    assert "20 s or more" in res.summary()["delayed_note"]


def test_a_failure_in_the_worker_thread_is_reported_not_lost(monkeypatch):
    import stack.planning.delayed as delayed
    from stack.planning.momdp import MixedSearch

    m = _mixed(0, X=3, Y=3, A=2, Z=2)
    b0 = _b0(m)
    pomdp = _flat(m, b0)
    from stack.planning.bounds import blind_lower_bound

    search = MixedSearch(
        m,
        SearchConfig(time_limit_s=30.0, max_trials=3, progress_every_s=0.0),
        (blind_lower_bound(pomdp), np.arange(m.A)),
        [b0],
    )

    def broken(*a, **k):
        raise ValueError("a broken table")

    monkeypatch.setattr(delayed, "delayed_bound", broken)
    w = delayed.DelayedWorker.start(search, 30.0, None)
    assert w is not None
    search.run()
    result, note = w.finish(search)
    assert result is None
    assert "ValueError: a broken table" in note


def test_a_solve_without_a_time_limit_stays_deterministic_and_says_so():
    from stack.planning.solve import SolverConfig, solve_task_model
    from stack.planning.task import load_task

    task = load_task(REPO / "config" / "task-r1.yaml")
    cfg = SolverConfig(trials=2, beliefs=20, iterations=2, delayed_bound=True)
    res = solve_task_model(task, cfg, require_progress=False).result
    assert res.delayed is None
    assert res.summary()["delayed_note"] == "delayed bound: only under a time limit"


def test_a_probability_too_small_for_float64_gives_no_bound_not_a_wrong_one():
    # P(z1, z2 | y) ~ 1e-320 (subnormal): 1 / P overflows; the bound must not come out
    # as a number (a NaN cap would be ignored silently, a finite one unproven)
    rng = np.random.default_rng(0)
    X, Y, A = 2, 3, 2
    TY = rng.dirichlet(np.ones(Y), size=Y)
    TY[0] = [1e-160, 0.5, 0.5 - 1e-160]
    OY = np.array([[1e-160, 1 - 1e-160], [0.0, 1.0], [0.0, 1.0]])
    m = MixedModel(
        TX=rng.dirichlet(np.ones(X), size=(A, X)),
        TY=TY,
        OY=OY,
        R=rng.normal(size=(X, Y, A)),
        discount=0.9,
    )
    Q = factored_fib(m, tol=1e-12, max_iterations=20000)
    with np.errstate(all="ignore"):
        r = delayed_bound(m, Q, [(0, np.array([0.5, 0.25, 0.25]))], plain=20, upward=20)
    assert r is None or np.isfinite(r.upper).all()


def test_a_cap_below_a_root_s_lower_bound_is_refused():
    from stack.planning.bounds import blind_lower_bound
    from stack.planning.momdp import MixedSearch

    m = _mixed(0, X=3, Y=3, A=2, Z=2)
    b0 = _b0(m)
    search = MixedSearch(
        m,
        SearchConfig(time_limit_s=None, max_trials=5, progress_every_s=0.0),
        (blind_lower_bound(_flat(m, b0)), np.arange(m.A)),
        [b0],
    )
    search.run()
    lb, ub = search.root.lb, search.root.ub
    search.root_caps = np.array([lb - 1.0])
    assert "below root 0's lower bound" in search.take_root_caps()
    assert search.root.ub == ub  # not taken
    search.root_caps = np.array([(lb + ub) / 2])
    assert search.take_root_caps() == ""
    assert search.root.ub == (lb + ub) / 2
    assert search.search_upper == ub
