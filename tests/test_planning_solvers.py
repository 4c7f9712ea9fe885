"""Solvers: bounds, Perseus, policies, evaluation, and the CLI on public benchmark files."""

import json
from pathlib import Path

import numpy as np
import pytest

from stack.planning.bounds import blind_lower_bound, fast_informed_bound, qmdp
from stack.planning.evaluate import evaluate
from stack.planning.pbvi import Backup
from stack.planning.policy import AlphaPolicy, PolicyFileError
from stack.planning.pomdp import ModelError
from stack.planning.pomdp_format import read_pomdp
from stack.planning.solve import SolverConfig, solve
from vigil.cli import main as vigil

SHARED = Path(__file__).resolve().parents[2] / "shared" / "pomdp"
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason=f"{SHARED} not present")


@pytest.fixture(scope="module")
def tiger():
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} not present")
    return read_pomdp(SHARED / "Tiger.pomdp")


@pytest.fixture(scope="module")
def tiger_solution(tiger):
    return solve(tiger, SolverConfig(algorithm="perseus", beliefs=100, iterations=300, seed=1))


def test_bounds_are_ordered(tiger):
    Q = qmdp(tiger)
    F = fast_informed_bound(tiger, Q)
    L = blind_lower_bound(tiger)
    assert (F <= Q + 1e-9).all()
    b = tiger.b0
    assert (L @ b).max() <= (F.T @ b).max() <= (Q.T @ b).max()


def test_perseus_lower_bound_rises_and_stays_below_upper(tiger_solution):
    h = tiger_solution.history
    values = [s.value_b0 for s in h]
    assert all(b >= a - 1e-9 for a, b in zip(values, values[1:], strict=False))
    assert values[-1] > values[0]
    assert all(s.value_b0 <= s.upper_b0 + 1e-9 for s in h)
    assert tiger_solution.lower_bound <= tiger_solution.upper_bound


def test_tiger_reaches_the_known_optimum(tiger_solution):
    # SARSOP: 19.371 <= V* <= 19.372 on this file (../shared/pomdp/README.md); a lower
    # bound is never above V*, and 300 Perseus iterations come within 0.05 of it
    assert 19.32 <= tiger_solution.lower_bound <= 19.3721


def test_backup_never_lowers_value_at_its_belief(tiger):
    backup = Backup(tiger)
    alphas = blind_lower_bound(tiger)
    rng = np.random.default_rng(3)
    for _ in range(20):
        b = rng.dirichlet(np.ones(tiger.n_states))
        alpha, _, value = backup(alphas, b)
        assert alpha @ b == pytest.approx(value)
        assert value >= (alphas @ b).max() - 1e-9


def test_policy_file_round_trip(tmp_path, tiger_solution, tiger):
    path = tiger_solution.policy.save(tmp_path / "tiger")
    loaded = AlphaPolicy.load(path, n_states=tiger.n_states)
    np.testing.assert_array_equal(loaded.alphas, tiger_solution.policy.alphas)
    assert loaded.action(tiger.b0) == tiger_solution.policy.action(tiger.b0)
    assert loaded.meta["solver"] == "perseus"
    with pytest.raises(PolicyFileError, match="the model has 3"):
        AlphaPolicy.load(path, n_states=3)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a policy")
    with pytest.raises(PolicyFileError):
        AlphaPolicy.load(bad)


def test_evaluation_is_seeded_and_consistent_with_the_bound(tiger, tiger_solution):
    a = evaluate(tiger, tiger_solution.policy, episodes=200, horizon=100, seed=5)
    b = evaluate(tiger, tiger_solution.policy, episodes=200, horizon=100, seed=5)
    assert a.returns == b.returns
    assert a.mean + 3 * a.ci95 >= tiger_solution.lower_bound - 1.0


@needs_shared
def test_undiscounted_file_is_refused_clearly():
    pomdp = read_pomdp(SHARED / "bulkhead.A.POMDP")
    with pytest.raises(ModelError, match="discount 1.0 is not below 1"):
        solve(pomdp)


@needs_shared
def test_cli_solve_pomdp_prints_bounds(capsys):
    assert vigil(["solve-pomdp", str(SHARED / "4x3.95.POMDP"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["states"] == 11 and out["actions"] == 4
    assert out["lower_bound"] <= out["upper_bound"]
    # SARSOP: 1.8899 <= V* <= 1.8909
    assert out["lower_bound"] <= 1.8909 and out["upper_bound"] >= 1.8899
    assert out["stopped"] == "gap" and out["gap"] <= 1e-3  # no time limit: the gap rule


def test_cli_reports_bad_input_without_a_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.pomdp"
    bad.write_text("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0\n1 0\n")
    assert vigil(["solve-pomdp", str(bad)]) == 2
    assert "line" in capsys.readouterr().err


def test_cli_export_round_trips_the_task_model(tmp_path):
    out = tmp_path / "r1.pomdp"
    repo = Path(__file__).resolve().parents[1]
    assert vigil(["export-pomdp", str(repo / "config" / "task-r1.yaml"), "-o", str(out)]) == 0
    from stack.planning.model import build_model
    from stack.planning.task import load_task

    original = build_model(load_task(repo / "config" / "task-r1.yaml")).flat()
    back = read_pomdp(out)
    assert back.states == original.states and back.observations == original.observations
    for a in range(original.n_actions):
        assert abs(back.T[a] - original.T[a]).max() < 1e-9
        assert abs(back.O[a] - original.O[a]).max() < 1e-9
    np.testing.assert_allclose(back.R, original.R, atol=1e-9)
    np.testing.assert_allclose(back.b0, original.b0)


@needs_shared
def test_dense_and_sparse_value_solves_agree(monkeypatch):
    """Small models' QMDP and blind bounds are solved densely (no scipy.sparse.linalg
    on the solve path); the sparse solve of larger models gives the same values."""
    import stack.planning.bounds as bounds

    pomdp = read_pomdp(SHARED / "Hallway.pomdp")
    Q, L = qmdp(pomdp), blind_lower_bound(pomdp)
    monkeypatch.setattr(bounds, "_DENSE_SOLVE_MAX_STATES", 0)
    np.testing.assert_allclose(qmdp(pomdp), Q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(blind_lower_bound(pomdp), L, rtol=0, atol=1e-9)
