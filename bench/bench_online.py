"""Two people: the online planner against the baselines, and its decision time (issue 16).

    nice -n 5 .venv/bin/python bench/bench_online.py run --planner online --episodes 1000
    nice -n 5 .venv/bin/python bench/bench_online.py run --planner single --episodes 1000
    nice -n 5 .venv/bin/python bench/bench_online.py run --planner greedy --episodes 1000
    nice -n 5 .venv/bin/python bench/bench_online.py three   # n = 3, anytime at 0.3 s
    .venv/bin/python bench/bench_online.py report           # the Markdown tables

``run`` simulates seeded episodes of config/task-r2-n2.yaml (the same function and
figures as ``vigil evaluate config/task-r2-n2.yaml --planner NAME --episodes N``)
and keeps every return in runs/bench-online/NAME.json, so that ``report`` can add the
paired differences (every planner meets the same people and observations for a
seed). Planners can run as separate processes, one per core.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from stack.planning.evaluate_people import PLANNERS, make_planner, run_episodes
from stack.planning.factored import PeopleBelief, PeopleModel
from stack.planning.online import OnlineConfig, OnlinePlanner
from stack.planning.task import load_task

REPO = Path(__file__).resolve().parents[1]
TASK = REPO / "config" / "task-r2-n2.yaml"
OUT = REPO / "runs" / "bench-online"


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def cmd_run(args: argparse.Namespace) -> None:
    pm = PeopleModel.of(load_task(TASK))
    config, name = OnlineConfig(), args.planner
    if args.depth is not None:  # an ablation of the online planner: saved as online-dN
        config, name = OnlineConfig(depth=args.depth), f"online-d{args.depth}"
    planner = make_planner(args.planner, pm, config)
    before = load()
    t0 = time.perf_counter()
    ev = run_episodes(pm, planner, args.episodes, args.seed)
    out = ev.summary() | {
        "returns": list(ev.returns),
        "seconds": time.perf_counter() - t0,
        "load_before": before,
        "load_after": load(),
        "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"{name}.json").write_text(json.dumps(out))
    print(name, ev.line(), f"({out['seconds']:.0f} s, {before} -> {out['load_after']})")


def cmd_three(args: argparse.Namespace) -> None:
    """n = 3: decision time and depth reached with a 0.3 s limit, along episodes."""
    pm = PeopleModel.of(load_task(TASK).replace(people=3))
    rows = []
    for limit in (None, 0.3):
        cfg = OnlineConfig(time_limit_s=limit, depth=3 if limit else 2)
        planner = OnlinePlanner(pm, cfg)
        rng = np.random.default_rng(args.seed)
        times, depths = [], []
        b = PeopleBelief.initial(pm)
        s = [int(np.argmax(row)) for row in b.persons]
        for _ in range(args.steps):
            d = planner.decide(b)
            times.append(d.seconds * 1e3)
            depths.append(d.depth)
            r = int(rng.choice(pm.n_robot, p=pm.robot_T[d.action, b.robot]))
            obs = [r]
            for i in range(len(s)):
                s[i] = int(rng.choice(pm.n_person, p=pm.transition[s[i]]))
                p = pm.observation_table[s[i]]
                z = int(rng.choice(len(p), p=p / p.sum()))
                obs += [z // 13, z % 13]
            b = b.update(pm, d.action, tuple(obs))
        t = np.asarray(times)
        rows.append(
            f"| 3 | {'none, depth 2' if limit is None else f'{limit} s, depth <= 3'} | "
            f"{len(t)} | {np.median(t):.1f} | {np.percentile(t, 99):.1f} | {t.max():.1f} | "
            + ", ".join(f"{k}: {depths.count(k)}" for k in sorted(set(depths)))
            + " |"
        )
    print("| people | time limit | decisions | median ms | p99 ms | max ms | depth reached |")
    print("|---:|---|---:|---:|---:|---:|---|")
    print("\n".join(rows))
    print(f"\n({load()})")


def ci(x: np.ndarray) -> float:
    return 1.96 * float(x.std(ddof=1)) / math.sqrt(len(x))


def cmd_report(args: argparse.Namespace) -> None:
    names = [*PLANNERS, *sorted(p.stem for p in OUT.glob("online-d*.json"))]
    res = {
        n: json.loads((OUT / f"{n}.json").read_text())
        for n in names
        if (OUT / f"{n}.json").exists()
    }
    print(
        "| planner | episodes | mean discounted return | 95 % interval "
        "| decision median ms | p99 ms | run |"
    )
    print("|---|---:|---:|---|---:|---:|---|")
    for n, r in res.items():
        lo, hi = r["mean"] - r["ci95"], r["mean"] + r["ci95"]
        print(
            f"| {n} | {r['episodes']} | {r['mean']:.1f} +- {r['ci95']:.1f} "
            f"| [{lo:.1f}, {hi:.1f}] | "
            f"{r['decision_ms_median']:.2f} | {r['decision_ms_p99']:.2f} | "
            f"{r['when']}, {r['seconds']:.0f} s, {r['load_before']} |"
        )
    if "online" in res:
        print("\n| paired difference (same people, same observations) | mean | 95 % interval |")
        print("|---|---:|---|")
        x = np.asarray(res["online"]["returns"])
        for n in res:
            if n == "online":
                continue
            y = np.asarray(res[n]["returns"])
            m = min(len(x), len(y))  # episode e is the same for any episode count
            d = x[:m] - y[:m]
            print(f"| online - {n} ({m} episodes) | {d.mean():.1f} | +- {ci(d):.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("run")
    p.add_argument("--planner", choices=PLANNERS, required=True)
    p.add_argument("--episodes", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--depth", type=int, default=None, help="online: another depth (ablation)")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("three")
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_three)
    p = sub.add_parser("report")
    p.set_defaults(func=cmd_report)
    args = ap.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
