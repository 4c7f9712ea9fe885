"""A property-based fuzzer over the scenario parser (issue 23), seeded (hypothesis is not
installed here): hostile values put at random places of a valid scenario.

Property: :func:`vigil.scenario.parse_scenario` either refuses with a
:class:`ConfigError` whose one-line message names a key at or above the changed place,
or returns a scenario every value of which is usable: numbers finite and in range, cells
of the task's grid, the seed one the twin takes, the name a plain folder name, and
waypoints that the twin can build. Before issue 23, ``cell: .inf`` in a fault ended in
an OverflowError traceback and NaN speeds, times and points passed.
"""

from __future__ import annotations

import copy
import functools
import math
import os
import random
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError
from vigil.scenario import FAULT_KINDS, MAX_SEED, MAX_STEPS, Scenario, parse_scenario

REPO = Path(__file__).resolve().parents[1]
TASK = REPO / "config" / "task-r2.yaml"
CASES = 800

HOSTILE: list[Any] = [
    math.nan, math.inf, -math.inf, 1e308, -1e308, 10**30, -(10**30), 2**63, 2**32, -1, 0,
    0.5, 1.5, 13, 99, True, False, None, "", "x", "../..", "a/b", ".", "..", "1", "nan",
    [], {}, [1], [1, 2, 3], [math.nan, 0.0], [1e9, 1.0], ["a", "b"], {"to": 1},
    "door", "outside", 7, 12, 1.0, 0.1, 1.4, 1.41,
]  # fmt: skip
# values that fit some places: so that many mutated scenarios are accepted and checked
PLAUSIBLE: list[Any] = [
    1, 2, 4, 5, 6, 11, 0.3, 1.2, 30.0, "door", "outside", [1.0, 2.0], "north", "5.4",
    "camera_off", "lidar_off", "obstacle", "kill", "planner", "legs", "none", "East",
]  # fmt: skip


def valid() -> dict[str, Any]:
    return {
        "name": "fuzz",
        "title": "a fuzzed scenario",
        "thesis_table": "5.4",
        "task": str(TASK),
        "seed": 3,
        "steps": 8,
        "robot_cell": 9,
        "belief": {"person": 11, "direction": "not moving"},
        "person": {
            "start": "outside",
            "walk": [
                {"to": "door", "speed_mps": 1.0},
                {"to": 1, "speed_mps": 0.6, "pause_s": 8},
                {"to": [2.3, 0.4], "speed_mps": 0.4},
            ],
        },
        "faults": [
            {"kind": "camera_off", "at_s": 20, "duration_s": 4},
            {"kind": "kill", "node": "planner", "after_step": 3},
            {"kind": "obstacle", "cell": 5},
        ],
    }


def places(data: Any, path: tuple = ()) -> list[tuple]:
    """Every place (path of keys and indices) in a nested mapping/list."""
    out = [path] if path else []
    if isinstance(data, dict):
        for k, v in data.items():
            out += places(v, (*path, k))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out += places(v, (*path, i))
    return out


def key_of(path: tuple) -> str:
    """The key a ConfigError names for a place: person.walk[1].to."""
    text = ""
    for p in path:
        text += f"[{p}]" if isinstance(p, int) else (f".{p}" if text else str(p))
    return text


def put(data: dict, path: tuple, value: Any) -> None:
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value


def mutate(rng: random.Random) -> tuple[dict, list[tuple]]:
    data = valid()
    changed = []
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        where = rng.choice(places(data))
        if rng.random() < 0.1 and isinstance(data.get(where[0]), dict | list):
            where = (*where[:-1], "unknown_key") if isinstance(where[-1], str) else where
        try:
            pool = HOSTILE if rng.random() < 0.6 else PLAUSIBLE
            put(data, where, copy.deepcopy(rng.choice(pool)))
        except (TypeError, IndexError, KeyError):  # the parent was replaced by a scalar
            continue
        changed.append(where)
    return data, changed


def check_usable(sc: Scenario) -> None:
    """What an accepted scenario promises the nodes."""
    grid = _grid()
    cells = set(grid.cells)
    assert sc.name and "/" not in sc.name and sc.name not in (".", "..")
    assert 0 <= sc.seed <= MAX_SEED and 1 <= sc.steps <= MAX_STEPS
    np.random.default_rng(sc.seed)  # the twin's generator takes it
    assert sc.robot_cell in cells
    assert sc.belief_person is None or sc.belief_person in cells
    for f in sc.faults:
        assert f.kind in FAULT_KINDS
        assert math.isfinite(f.at_s) and math.isfinite(f.duration_s)
        assert isinstance(f.cell, int) and isinstance(f.after_step, int)
        if f.kind == "obstacle":
            assert f.cell in cells
        if f.kind == "kill":
            assert 1 <= f.after_step <= sc.steps
    for w in sc.people_waypoints(grid, (7.0, 5.2)):
        for wp in w:
            assert all(math.isfinite(v) for v in wp.values()), wp


@functools.cache
def _grid() -> CellGrid:
    from stack.planning.task import load_task

    return load_task(TASK).grid


def test_parse_scenario_refuses_with_the_key_or_returns_a_usable_scenario():
    rng = random.Random(23)
    accepted = refused = 0
    for case in range(CASES):
        data, changed = mutate(rng)
        try:
            sc = parse_scenario(data)
        except ConfigError as err:
            refused += 1
            assert "\n" not in str(err), (case, str(err))
            named = [key_of(p) for p in changed]
            # a change may break a rule between siblings (kind camera_off needs a duration)
            named += [key_of(p[:-1]) for p in changed if len(p) >= 2]
            # the key named lies at, above or beside a changed place; a smaller steps may
            # refuse a fault's after_step
            k = err.key.removeprefix("scenario.")  # top-level unknown keys
            ok = any(n.startswith(k) or k.startswith(n) for n in named) or (
                any(n == "steps" for n in named) and k.startswith("faults")
            )
            assert ok, (case, changed, err.key, str(err))
            continue
        except Exception as exc:  # noqa: BLE001 - anything else is a finding
            pytest.fail(f"case {case}: {changed}: {type(exc).__name__}: {exc}")
        accepted += 1
        check_usable(sc)
    assert accepted > 50 and refused > 300, (accepted, refused)  # both sides exercised


@pytest.mark.parametrize(
    "fault, key",
    [
        ({"kind": "obstacle", "cell": math.inf}, "faults[0].cell"),  # OverflowError before
        ({"kind": "obstacle", "cell": 2.5}, "faults[0].cell"),  # silently cell 2 before
        ({"kind": "obstacle", "cell": 99}, "faults[0].cell"),  # no such cell
        ({"kind": "camera_off", "at_s": math.nan, "duration_s": 1}, "faults[0].at_s"),
        ({"kind": "lidar_off", "at_s": 1, "duration_s": math.inf}, "faults[0].duration_s"),
        ({"kind": "kill", "node": "planner", "after_step": "x"}, "faults[0].after_step"),
        ({"kind": "kill", "node": "planner", "after_step": 99}, "faults[0].after_step"),
        ({"kind": "kill", "node": ["planner"], "after_step": 1}, "faults[0].node"),
    ],
)
def test_hostile_fault_values_are_refused_naming_the_key(fault, key):
    data = valid()
    data["faults"] = [fault]
    with pytest.raises(ConfigError) as err:
        parse_scenario(data)
    assert err.value.key == key


@pytest.mark.parametrize(
    "change, key",
    [
        ({"seed": 2**64}, "seed"),
        ({"seed": 1.5}, "seed"),
        ({"steps": 10**12}, "steps"),
        ({"robot_cell": 40}, "robot_cell"),
        ({"belief": {"person": 0}}, "belief.person"),
        ({"belief": {"direction": 3}}, "belief.direction"),
        ({"name": "../../home"}, "name"),
        ({"title": ["x"]}, "title"),
        ({"thesis_table": "9.9"}, "thesis_table"),
        ({"person": {"start": [math.nan, 1.0]}}, "person.start"),
        ({"person": {"walk": [{"to": 1, "speed_mps": math.nan}]}}, "person.walk[0].speed_mps"),
        ({"person": {"walk": [{"to": 1, "pause_s": math.inf}]}}, "person.walk[0].pause_s"),
        ({"task": str(REPO / "config" / "twin.yaml")}, "task"),
    ],
)
def test_hostile_values_are_refused_naming_the_key(change, key):
    data = valid()
    data.update(change)
    with pytest.raises(ConfigError) as err:
        parse_scenario(data)
    assert err.value.key == key


def test_vigil_run_refuses_an_infinite_fault_cell_in_one_line(tmp_path):
    text = (REPO / "scenarios" / "5.1.1.yaml").read_text()
    text = text.replace("task: ../config/task-r1.yaml", f"task: {REPO / 'config' / 'task-r1.yaml'}")
    bad = tmp_path / "bad.yaml"
    bad.write_text(text + "faults:\n  - {kind: obstacle, cell: .inf}\n")
    proc = subprocess.run(
        [sys.executable, "-m", "vigil.cli", "run", str(bad), "--out", str(tmp_path / "run")],
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "faults[0].cell" in lines[0], proc.stderr
    assert not (tmp_path / "run").exists()
