"""The scenario-set runner (vigil.experiments) with a stand-in for the ROS run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stack.cells import ConfigError
from vigil.experiments import run_set, scenario_files, update_marked_section, write_docs
from vigil.report import write_report

ROOT = Path(__file__).resolve().parents[1]
GUARD = ROOT / "scenarios" / "guard"


def test_the_guard_set_covers_the_issue():
    from vigil.scenario import load_scenario

    files = scenario_files(GUARD)
    stems = {f.stem for f in files}
    for kind in ("border", "two-visits", "far-side", "fast-walker", "empty-room"):
        assert any(s.startswith(kind) for s in stems), kind
    for kind in ("pass-through", "camera-outage", "lidar-outage", "occlusion", "long-stay"):
        assert kind in stems, kind
    scenarios = [load_scenario(f) for f in files]
    assert all(s.steps <= 25 for s in scenarios)
    assert len({s.seed for s in scenarios}) == len(scenarios)
    assert len({s.robot_cell for s in scenarios}) >= 4
    fast = next(s for f, s in zip(files, scenarios, strict=True) if f.stem == "fast-walker")
    assert max(leg.speed_mps for leg in fast.walk) >= 1.3
    faults = {f.stem: {x.kind for x in s.faults} for f, s in zip(files, scenarios, strict=True)}
    assert faults["camera-outage"] == {"camera_off"} and faults["lidar-outage"] == {"lidar_off"}


def fake_run(scenario_path, config, out, seed, say=print):
    """Writes a tiny run folder: the person in cell 1 from 2 s to 8 s; the robot there
    from 5 s unless the scenario is the empty room, where nobody comes in."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "params.yaml").write_text("{}\n")
    empty = "empty" in Path(scenario_path).stem
    trace = []
    for k in range(0, 121):
        t = k / 10
        p = None if empty or not 2 <= t < 8 else [5.5, 0.75]
        trace.append({"t": t, "robot": [5.5 if t >= 5 else 4.5, 0.75, 0.0], "person": p})
    (out / "trace.jsonl").write_text("".join(json.dumps(r) + "\n" for r in trace))
    steps = [
        {
            "step": n,
            "stamp_s": 2.0 * n,
            "action": "Do nothing",
            "observation": {"robot": "1", "person": "No person", "velocity": "Not moving"},
        }
        for n in range(1, 6)
    ]
    (out / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    say("[run] step 1/5 ...")
    if "border" in Path(scenario_path).stem:
        raise RuntimeError("the system stopped")
    from vigil.scenario import load_scenario

    return write_report(out, load_scenario(scenario_path).task, plots=False, video=False)


def test_run_set_table_totals_and_docs(tmp_path):
    lines: list[str] = []
    only = ["empty-room", "occlusion", "border-1"]
    record = run_set(GUARD, tmp_path / "set", only=only, runner=fake_run, say=lines.append)
    names = [e["scenario"] for e in record["scenarios"]]
    assert names == sorted(only)
    by = {e["scenario"]: e for e in record["scenarios"]}
    assert "RuntimeError" in by["border-1"]["error"]
    # a failed run still counts with what it recorded (its report was not written here)
    assert by["border-1"]["metrics"] is None
    assert by["occlusion"]["metrics"]["n_visits"] == 1
    assert by["occlusion"]["metrics"]["guarded"] == 1
    assert by["empty-room"]["metrics"]["n_visits"] == 0
    # the robot "arrives" in cell 1 at 5 s in an empty room: a false trip
    assert by["empty-room"]["metrics"]["n_false_trips"] == 1
    t = record["totals"]
    assert (t["scenarios"], t["n_visits"], t["guarded"], t["n_false_trips"]) == (2, 1, 1, 1)
    assert t["misses"] == 3 and t["steps_with_person"] == 3  # steps at 2, 4, 6 s
    assert any(x.startswith("[occlusion] [run] step 1/5") for x in lines)
    md = (tmp_path / "set" / "experiments.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| occlusion |"))
    assert row.startswith("| occlusion | 1 | 1 | ") and "failed: RuntimeError" in md
    reachable = by["occlusion"]["metrics"]["reachable"]
    assert f"| {reachable} ({by['occlusion']['metrics']['guarded_reachable']}) |" in row
    assert "**total (2 runs)**" in md and "seed 21" in md
    assert (tmp_path / "set" / "experiments.png").stat().st_size > 0
    # the section in a docs file, twice: replaced, not repeated
    doc = tmp_path / "docs" / "EXPERIMENTS.md"
    doc.parent.mkdir()
    doc.write_text("# Experiments\n\nText.\n")
    write_docs(doc, tmp_path / "set", "guard-before", "## Before")
    once = doc.read_text()
    write_docs(doc, tmp_path / "set", "guard-before", "## Before")
    assert doc.read_text() == once and once.count("<!-- experiments:guard-before -->") == 1
    assert "![the scenario set](experiments/guard-before.png)" in once
    assert (doc.parent / "experiments" / "guard-before.png").exists()
    # report only: the run folders are read again, nothing runs
    again = run_set(GUARD, tmp_path / "set", only=["occlusion"], report_only=True, say=print)
    assert again["scenarios"][0]["metrics"]["guarded"] == 1


def test_marked_sections():
    text = "# T\n\nintro\n"
    a = update_marked_section(text, "x", "table 1", "## X")
    assert a.endswith("## X\n\n<!-- experiments:x -->\ntable 1\n<!-- /experiments:x -->\n")
    b = update_marked_section(a + "\nafter\n", "x", "table 2")
    assert "table 2" in b and "table 1" not in b and b.endswith("after\n")
    assert update_marked_section(b, "y", "other").count("<!-- experiments:") == 2
    with pytest.raises(ValueError, match="broken"):
        update_marked_section("<!-- /experiments:x --> <!-- experiments:x -->", "x", "t")


def test_bad_inputs_are_named(tmp_path):
    with pytest.raises(ConfigError, match="no such file or folder"):
        scenario_files(tmp_path / "nope")
    with pytest.raises(ConfigError, match=r"holds no \*\.yaml"):
        scenario_files(tmp_path)
    with pytest.raises(ConfigError, match="--only"):
        run_set(GUARD, tmp_path / "o", only=["nope"], runner=fake_run)
    with pytest.raises(ConfigError, match="holds no experiments.json"):
        (tmp_path / "d.md").write_text("x")
        write_docs(tmp_path / "d.md", tmp_path, "x")
