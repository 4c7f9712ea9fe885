"""The guarding set across three hosts (issue 25): every scenario of a folder run by
``vigil launch --host NAME --scenario S`` on three network namespaces of this machine
(the robot side with the twin at real time, the camera side, the planner side;
:mod:`vigil.hosts_rehearsal`), tabulated as ``vigil experiments`` tabulates its runs
(``OUT/experiments.md``, ``.json``, ``.png``; each run's three folders in
``OUT/<scenario>/``). Needs root and iproute2.

    sudo .venv/bin/python bench/bench_hosts.py [scenarios/guard] [--out runs/guard-hosts]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from vigil.experiments import run_set  # noqa: E402
from vigil.hosts_rehearsal import can_run, run_across_hosts, virtual_lan  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="?", default=str(REPO / "scenarios" / "guard"))
    ap.add_argument("--out", default=str(REPO / "runs" / "guard-hosts"))
    ap.add_argument("--only", nargs="*", default=(), help="these scenario file stems only")
    args = ap.parse_args()
    if not can_run():
        print("bench_hosts: needs root and iproute2", file=sys.stderr)
        return 2
    with virtual_lan() as (names, addresses):

        def runner(path, _config, run_dir, _seed, say=print, **_extra) -> dict:
            run = run_across_hosts(Path(path), Path(run_dir), names, addresses,
                                   domain=100 + os.getpid() % 100)  # fmt: skip
            say(f"exit codes {run.codes}, {run.steps} steps, robot link "
                f"{run.robot_link_bytes / 1e6:.0f} MB")  # fmt: skip
            if not run.summary:
                raise RuntimeError(f"no report: {run.out['planner'][-500:]}")
            return {**run.summary, "realtime": run.realtime}

        run_set(args.scenarios, args.out, only=args.only, runner=runner, say=print)
    return 0


if __name__ == "__main__":
    sys.exit(main())
