"""Bad input to the planning files fails at the boundary, clearly (issue 13)."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from stack.cells import ConfigError
from stack.planning.policy import AlphaPolicy, PolicyFileError
from stack.planning.pomdp import dense_to_pomdp
from stack.planning.pomdp_format import PomdpFormatError, read_pomdp, read_text_capped
from stack.planning.solve import DegenerateSolveError, SolverConfig, solve_task_model
from stack.planning.task import load_task
from vigil.cli import main as vigil

REPO = Path(__file__).resolve().parents[1]
TIGER = "discount: 0.95\nvalues: reward\nstates: 2\nactions: 1\nobservations: 1\n"


def _two_models():
    T = np.array([[[0.9, 0.1], [0.1, 0.9]]])
    O = np.ones((1, 2, 1))
    a = dense_to_pomdp(T, O, np.array([[1.0], [0.0]]), 0.9)
    b = dense_to_pomdp(T, O, np.array([[0.0], [1.0]]), 0.9)  # same sizes, other rewards
    return a, b


def test_policy_for_another_model_is_refused(tmp_path):
    a, b = _two_models()
    policy = AlphaPolicy(np.array([[1.0, 0.0]]), np.array([0]), {"model_sha256": a.fingerprint()})
    path = policy.save(tmp_path / "p.npz")
    assert AlphaPolicy.load(path, 2, model_hash=a.fingerprint()).n_states == 2
    with pytest.raises(PolicyFileError, match="another model"):
        AlphaPolicy.load(path, 2, model_hash=b.fingerprint())


def test_task_policies_differ_in_hash():
    from stack.planning.model import build_model

    r1 = build_model(load_task(REPO / "config" / "task-r1.yaml")).flat()
    r2 = build_model(load_task(REPO / "config" / "task-r2.yaml")).flat()
    assert r1.n_states == r2.n_states and r1.fingerprint() != r2.fingerprint()


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_non_finite_reward_in_a_task_file_is_refused(tmp_path, value, capsys):
    data = yaml.safe_load((REPO / "config" / "task-r1.yaml").read_text())
    text = yaml.safe_dump(data).replace("restricted_guarded: 30.0", f"restricted_guarded: {value}")
    path = tmp_path / "task.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="restricted_guarded.*finite"):
        load_task(path)
    assert vigil(["solve", str(path), "-o", str(tmp_path / "p.npz"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "finite" in err and "Traceback" not in err
    assert not (tmp_path / "p.npz").exists()


def test_huge_state_count_is_refused_before_allocating():
    with pytest.raises(PomdpFormatError, match="limit"):
        read_pomdp("discount: 0.9\nstates: 100000000\nactions: 2\nobservations: 2\n")
    with pytest.raises(PomdpFormatError, match="entries"):
        read_pomdp("discount: 0.9\nstates: 20000\nactions: 2\nobservations: 2\nT: * uniform\n")


def test_endless_file_is_cut_off(tmp_path):
    big = tmp_path / "big.pomdp"
    big.write_text(TIGER + "#" * 5000)
    with pytest.raises(PomdpFormatError, match="limit of 1,000 bytes"):
        read_text_capped(big, max_bytes=1000)
    if Path("/dev/zero").exists():  # refused before a byte is read (issue 23)
        with pytest.raises(PomdpFormatError, match="not a regular file"):
            read_text_capped("/dev/zero", max_bytes=1 << 20)


def test_directory_as_a_file_is_one_line_exit_2(tmp_path, capsys):
    for argv in (
        ["solve-pomdp", str(tmp_path)],
        ["evaluate", str(tmp_path / "x.pomdp"), "--policy", str(tmp_path)],
    ):
        if argv[0] == "evaluate":
            (tmp_path / "x.pomdp").write_text(
                TIGER + "T: 0\nidentity\nO: 0\n1.0\n1.0\nR: 0 : * : * : * 1.0\n"
            )
        assert vigil(argv) == 2
        err = capsys.readouterr().err
        assert "directory" in err and "Traceback" not in err and err.count("\n") == 1


def test_degenerate_solve_is_an_error(monkeypatch):
    """A solve that leaves V(b0) at the initial bound raises instead of returning."""
    import stack.planning.solve as solve_module

    real = solve_module.solve

    def no_progress(pomdp, config, starts, seeds, progress, start):
        result = real(pomdp, SolverConfig(algorithm="perseus", iterations=1), starts, seeds)
        init = float(
            (np.vstack([solve_module.blind_lower_bound(pomdp), seeds[0]]) @ pomdp.b0).max()
        )
        result.lower_bound = init
        return result

    monkeypatch.setattr(solve_module, "solve", no_progress)
    with pytest.raises(DegenerateSolveError, match="initial lower bound"):
        solve_task_model(
            load_task(REPO / "config" / "task-r1.yaml"), SolverConfig(algorithm="perseus")
        )


def test_degenerate_factored_solve_is_an_error(monkeypatch):
    """The task's default solver (the mixed-observability search) is checked the same way."""
    from stack.planning.momdp import MixedSearch
    from stack.planning.solve import TASK_CONFIG

    monkeypatch.setattr(MixedSearch, "_backup", lambda self, node: None)
    with pytest.raises(DegenerateSolveError, match="initial lower bound"):
        solve_task_model(load_task(REPO / "config" / "task-r1.yaml"), TASK_CONFIG)


def test_bad_solver_arguments_exit_2(capsys):
    assert vigil(["solve-pomdp", "x.pomdp", "--time-limit", "nan"]) == 2
    assert "time-limit" in capsys.readouterr().err
