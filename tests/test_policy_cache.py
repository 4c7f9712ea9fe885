"""The policy cache's key: what determines a task's policy, nothing else."""

from dataclasses import replace
from pathlib import Path

import yaml

from stack.planning.policy_cache import cache_key
from stack.planning.solve import TASK_CONFIG
from stack.planning.task import load_task

CONFIG = Path(__file__).resolve().parents[1] / "config"


def _task(tmp_path: Path, name: str, edit) -> object:
    data = yaml.safe_load((CONFIG / "task-r1-goal.yaml").read_text())
    edit(data)
    path = tmp_path / name
    path.write_text("# another file, another comment\n" + yaml.safe_dump(data))
    return load_task(path)


def test_the_key_follows_the_model_not_the_file(tmp_path):
    base = load_task(CONFIG / "task-r1-goal.yaml")
    key = cache_key(base, TASK_CONFIG)

    def lead(d):  # a run-time setting the policy never sees
        d["anticipation"]["go_probability"] = 0.8

    assert cache_key(_task(tmp_path, "lead.yaml", lead), TASK_CONFIG) == key

    def reward(d):
        d["rewards"]["restricted_guarded"] = 25.0

    assert cache_key(_task(tmp_path, "reward.yaml", reward), TASK_CONFIG) != key

    def rest(d):  # the initial belief (b0) changes with the rest cell
        d["rest_cell"] = 5

    assert cache_key(_task(tmp_path, "rest.yaml", rest), TASK_CONFIG) != key
    assert cache_key(base, replace(TASK_CONFIG, iterations=7)) != key


def test_a_cached_policy_is_found_with_one_model_build_per_file_version(tmp_path, monkeypatch):
    import stack.planning.policy_cache as pc

    task_file = tmp_path / "task.yaml"
    task_file.write_text((CONFIG / "task-r1-goal.yaml").read_text())
    name = f"{load_task(task_file).name}-{cache_key(load_task(task_file), TASK_CONFIG)}.npz"
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / name).write_bytes(b"a policy")  # found: nothing is solved
    calls = []
    monkeypatch.setattr(pc, "cache_key", lambda *a: calls.append(1) or cache_key(*a))
    for _ in range(3):
        assert pc.cached_task_policy(task_file, tmp_path / "cache") == tmp_path / "cache" / name
    assert len(calls) == 1
    task_file.write_text(task_file.read_text() + "# edited\n")  # a new version: keyed again
    assert pc.cached_task_policy(task_file, tmp_path / "cache") == tmp_path / "cache" / name
    assert len(calls) == 2
