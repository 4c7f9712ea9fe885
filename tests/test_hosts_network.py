"""The networked system across three hosts (issue 25): the robot side (the twin's bridge
as the robot, with its localisation, leg tracker, navigation and speech), the camera
side (the people detector) and the planner side (observations, planner, recorder, bag)
each in a network namespace of its own, joined by veth links over a bridge in a fourth
namespace, each running ``vigil launch FILE --host NAME`` with its own copy of the
deployment (DDS on its own address only, the other two as peers), the twin on the wall
clock. The namespaces and links are made by the test, on this machine only.

Each host runs the same scenario (``vigil launch FILE --host NAME --scenario S``): the
robot side's twin walks its person, the planner side makes its steps, then ends
("finished") and writes the run's report; the other two stop on Ctrl-C. Two lengths: a
short scenario (5.1.1 cut to 6 steps) and a whole one of the guarding set
(``scenarios/guard/fast-walker.yaml``, its visit to cell 1).

Checked: the planner decided from observations that joined the camera side's frames
and the robot side's odometry, the person was seen, the robot side's twin kept the wall
clock, the camera's images crossed the robot's link, the report was written on the
planner side, and every host stopped cleanly. No delay or loss is added on the links:
this machine's kernel has no ``netem`` queueing discipline (the test says so when it
cannot add one).

Needs root and iproute2 (CI runs as root).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from vigil.hosts_rehearsal import HOSTS, add_delay, can_run, run_across_hosts, virtual_lan

REPO = Path(__file__).resolve().parents[1]

pytestmark = [
    pytest.mark.slow,
    pytest.mark.ros,
    pytest.mark.skipif(not can_run(), reason="needs root and iproute2"),
]

SHORT_STEPS = 6


@pytest.fixture
def lan():
    with virtual_lan() as (names, addresses):
        yield names, addresses


def scenario_file(tmp_path: Path, length: str) -> Path:
    """The short scenario (5.1.1 cut to SHORT_STEPS steps) or a whole guarding one."""
    if length == "whole":
        return REPO / "scenarios" / "guard" / "fast-walker.yaml"
    source = REPO / "scenarios" / "5.1.1.yaml"
    data = yaml.safe_load(source.read_text())
    data.update(steps=SHORT_STEPS, task=str((source.parent / data["task"]).resolve()))
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize("length", ["short", "whole"])
def test_a_scenario_runs_across_three_hosts(lan, tmp_path, length):
    names, addresses = lan
    why_not = add_delay(names["robot"], 5.0)
    if why_not:
        print(f"no delay or loss on the links: {why_not}")
    scenario = scenario_file(tmp_path, length)
    steps_to_make = yaml.safe_load(scenario.read_text())["steps"]
    run = run_across_hosts(scenario, tmp_path / "run", names, addresses,
                           domain=100 + os.getpid() % 100)  # fmt: skip
    out = run.out
    assert run.codes == dict.fromkeys(HOSTS, 0), {h: out[h][-2000:] for h in out}
    for host, nodes in HOSTS.items():  # each host started its own nodes and no other
        started = {line.split()[2] for line in out[host].splitlines() if "] started " in line}
        assert started == set(nodes), (host, started)
    # the planner side decided from the camera side's frames and the robot's odometry
    planner = run.folder / "planner"
    record = json.loads((planner / "run.json").read_text())
    assert record["ending"] == "finished" and record["report"] == "written", record
    steps = [json.loads(line) for line in (planner / "steps.jsonl").open()]
    assert len(steps) == run.steps == steps_to_make, out["planner"][-2000:]
    observed = [s["observation"] for s in steps if s.get("observation")]
    assert all(o["robot"].isdigit() for o in observed), observed
    assert sum("frame_stamp_s" in o for o in observed) >= len(observed) - 1
    assert any(o["person"].isdigit() for o in observed), observed  # the person was seen
    # the robot side's twin kept the wall clock; the images crossed its link
    # (how many of the frames due were delivered depends on the machine's load: a
    # benchmark's figure, docs/BENCHMARKS.md; here only that they flowed)
    realtime = run.realtime
    assert realtime["factor"] > 0.95 and realtime["frames"] >= 50, realtime
    assert run.robot_link_bytes > 20e6, run.robot_link_bytes  # 10 frames of 768 kB a second
    metrics = run.summary["metrics"]
    if length == "whole":  # its visit to cell 1, seen from the planner side's records
        assert metrics["n_visits"] == 1, metrics
    print(f"{len(steps)} steps, person seen in {sum(o['person'].isdigit() for o in observed)}, "
          f"visits guarded {metrics['guarded']}/{metrics['n_visits']}, "
          f"robot link {run.robot_link_bytes / 1e6:.0f} MB, twin factor {realtime['factor']}, "
          f"frames {realtime['frames']}/{realtime['frames_due']}")  # fmt: skip
