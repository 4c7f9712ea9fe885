"""The in-process loop (dm-control environment, no ROS) against the ROS lock-step run.

    MUJOCO_GL=egl .venv/bin/python bench/bench_inprocess.py [SCENARIO] [--steps N]

Runs the scenario (default ``scenarios/guard/two-visits.yaml`` cut to 8 decision steps)
once through ROS (``vigil.run.run_scenario``: eight node processes) and once in one
process (``vigil.inprocess.run_inprocess``), then prints for each the simulated time,
the wall-clock and CPU seconds per simulated second, and whether the two made the same
decisions. Wall-clock figures depend on the machine and its load (printed); CPU
seconds (all processes, the ROS run's children included) depend less on the load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from vigil.inprocess import run_inprocess  # noqa: E402
from vigil.run import run_scenario  # noqa: E402


def _cpu_s() -> float:
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _measure(label: str, fn) -> tuple[float, float, tuple[float, ...]]:
    load0 = os.getloadavg()
    t0, c0 = time.monotonic(), _cpu_s()
    fn()
    wall, cpu = time.monotonic() - t0, _cpu_s() - c0
    load = tuple(round((a + b) / 2, 1) for a, b in zip(load0, os.getloadavg(), strict=True))
    print(f"[bench] {label}: {wall:.1f} s wall, {cpu:.1f} s CPU, load average {load[0]}")
    return wall, cpu, load


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", nargs="?", default=str(REPO / "scenarios/guard/two-visits.yaml"))
    ap.add_argument("--steps", type=int, default=8, help="decision steps (0: the file's)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        src = Path(args.scenario).resolve()
        data = yaml.safe_load(src.read_text())
        data["task"] = str((src.parent / data["task"]).resolve())
        if args.steps:
            data["steps"] = args.steps
        scenario = tmp / src.name
        scenario.write_text(yaml.safe_dump(data, sort_keys=False))
        quiet = lambda _s: None  # noqa: E731
        ros_wall, ros_cpu, _ = _measure(
            "ROS", lambda: run_scenario(scenario, out=tmp / "ros", say=quiet)
        )
        ip_wall, ip_cpu, _ = _measure(
            "in-process", lambda: run_inprocess(scenario, tmp / "ip", say=quiet)
        )
        steps = [
            [json.loads(line) for line in (tmp / d / "steps.jsonl").read_text().splitlines()]
            for d in ("ros", "ip")
        ]
        sim_s = steps[1][-1]["stamp_s"]
        ros_info = json.loads((tmp / "ros" / "run.json").read_text())
        ip_info = json.loads((tmp / "ip" / "inprocess.json").read_text())
    same = [a["action"] == b["action"] and a["observation"] == b["observation"]
            for a, b in zip(*steps, strict=False)]  # fmt: skip
    print(f"scenario {src.stem}: {len(steps[1])} steps, {sim_s:.1f} s simulated to the last")
    print(f"ROS       : {ros_wall / sim_s:5.2f} s wall and {ros_cpu / sim_s:5.2f} s CPU per "
          f"simulated s (run {ros_info['wall_s']} s incl. start-up)")  # fmt: skip
    print(f"in-process: {ip_wall / sim_s:5.2f} s wall and {ip_cpu / sim_s:5.2f} s CPU per "
          f"simulated s (loop {ip_info['wall_s']} s)")  # fmt: skip
    print(f"speed-up  : {ros_wall / ip_wall:.1f}x wall, {ros_cpu / ip_cpu:.1f}x CPU")
    print(f"same decisions: {sum(same)}/{len(same)} steps (action and observation)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
