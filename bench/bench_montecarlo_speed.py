"""How fast one Monte-Carlo worker runs episodes, with the perception model and rendered.

    MUJOCO_GL=egl .venv/bin/python bench/bench_montecarlo_speed.py [--episodes 20] \
        [--rendered 2] [--task config/task-r1.yaml] [--walks config/walks.yaml]

Runs the study's first episodes (seed 0) one after the other in this process (one
warm-up episode first: imports and the task's policy), each once with
``perception="model"`` and the first ``--rendered`` also rendered, and prints per mode
the CPU and wall seconds per simulated second, the real-time factor of one worker
(simulated / CPU seconds), and the wall time 1,000 episodes would take on the
machine's cores at that rate. CPU seconds depend less on the load than wall seconds;
both are printed with the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
# one BLAS thread, as a study's workers have (vigil.montecarlo): a worker's CPU time
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from vigil.inprocess import run_inprocess  # noqa: E402
from vigil.montecarlo import episode_scenarios  # noqa: E402
from vigil.walks import DEFAULT_WALKS, load_walks  # noqa: E402


def run(scenarios, mode: str, study, tmp: Path) -> tuple[float, float, float]:
    sim = cpu = wall = 0.0
    for k, sc in enumerate(scenarios):
        c0, w0 = time.process_time(), time.monotonic()
        s = run_inprocess(sc, tmp / f"{mode}-{k}", max_steps=0, max_sim_s=study.max_sim_s,
                          tail_s=study.tail_s, say=lambda _s: None, perception=mode)  # fmt: skip
        cpu += time.process_time() - c0
        wall += time.monotonic() - w0
        sim += s["inprocess"]["sim_s"]
        print(f"[speed] {mode} {sc.name} ({sc.title.split(': ', 1)[1]}): "
              f"{s['inprocess']['sim_s']:.1f} s simulated, {time.process_time() - c0:.2f} CPU s",
              flush=True)  # fmt: skip
    return sim, cpu, wall


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", type=Path, default=REPO / "config" / "task-r1.yaml")
    p.add_argument("--walks", type=Path, default=DEFAULT_WALKS)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--rendered", type=int, default=2)
    args = p.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    study = load_walks(args.walks)
    scs = episode_scenarios(args.task.resolve(), max(args.episodes, args.rendered) + 1, 0, study)
    load0 = os.getloadavg()
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        run(scs[-1:], "model", study, tmp)  # warm-up
        rows = [("model", *run(scs[: args.episodes], "model", study, tmp), args.episodes)]
        if args.rendered:
            rows.append(("rendered", *run(scs[: args.rendered], "rendered", study, tmp),
                         args.rendered))  # fmt: skip
    print(f"[speed] load average before {load0[0]:.1f}, after {os.getloadavg()[0]:.1f}; "
          f"{cores} cores")  # fmt: skip
    print("| perception | episodes | simulated | CPU s / simulated s | wall s / simulated s | "
          "real-time factor (one worker, CPU) | 1,000 episodes on all cores |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|")
    for mode, sim, cpu, wall, n in rows:
        per_ep = cpu / n
        print(f"| {mode} | {n} | {sim:.0f} s | {cpu / sim:.3f} | {wall / sim:.3f} | "
              f"{sim / cpu:.1f}x | {1000 * per_ep / cores / 60:.1f} min |")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
