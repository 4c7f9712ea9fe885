"""The whole system's speed: a scenario through ROS in the lock-step twin.

    MUJOCO_GL=egl .venv/bin/python bench/bench_system.py [scenarios/5.2.2.yaml]

Prints the simulated time, the wall-clock time, their ratio, the time per decision
step and the camera frames the stack processed. Lock-step makes the result the same
on any machine; only the wall-clock figures depend on it.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from vigil.run import run_scenario  # noqa: E402


def main() -> int:
    scenario = sys.argv[1] if len(sys.argv) > 1 else str(REPO / "scenarios" / "5.2.2.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        summary = run_scenario(scenario, out=out, say=lambda s: None)
        run = json.loads((out / "run.json").read_text())
    sim_s = summary["trace"]["end_t"]
    wall_s = run["wall_s"]
    frames = summary["trace"]["records"]
    print(f"scenario {Path(scenario).stem}: {summary['steps']} steps, {frames} camera frames")
    print(f"simulated {sim_s:.1f} s in {wall_s:.1f} s wall: {sim_s / wall_s:.2f}x real time")
    per_step, per_frame_ms = wall_s / summary["steps"], wall_s / frames * 1000
    print(f"wall per decision step {per_step:.1f} s, per frame {per_frame_ms:.0f} ms")
    print(f"total discounted reward {summary['total_discounted_reward']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
