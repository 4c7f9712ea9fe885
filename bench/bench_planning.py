"""Planning benchmarks: solve time and bound gap, belief-update latency, public .pomdp files.

    .venv/bin/python bench/bench_planning.py [--iterations 200] [--pomdp-time 20]

Prints three tables (Markdown): the task models' lower/upper bound over Perseus
iterations, the latency of one belief update plus action selection, and
`solve-pomdp` on ../shared/pomdp/ beside SARSOP's figures.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from stack.planning import belief as B
from stack.planning.pomdp_format import read_pomdp
from stack.planning.replay import policy_chooser
from stack.planning.solve import SolverConfig, solve
from stack.vocabulary import ACTIONS
from vigil.solving import TASKS, solve_task_file

SHARED = Path(__file__).resolve().parents[2] / "shared" / "pomdp"
SARSOP = {  # ../shared/pomdp/README.md, 60 s
    "Tiger.pomdp": "19.371 / 19.372",
    "4x3.95.POMDP": "1.8899 / 1.8909",
    "cheese.95.POMDP": "3.4853 / 3.4862",
    "RockSample_4_4.pomdp": "17.924 exact",
    "Hallway.pomdp": "0.995 / 1.206",
    "Hallway2.pomdp": "0.364 / 0.904",
    "TagAvoid.pomdp": "-6.200 / -1.998",
    "RockSample_5_7.pomdp": "24.475 / 27.107",
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--pomdp-time", type=float, default=20.0)
    args = ap.parse_args()
    ns = argparse.Namespace(
        beliefs=300, iterations=args.iterations, time_limit=None, fib_time=0.0, seed=0, quiet=True
    )

    print("## Task models: Perseus (300 beliefs), value at b0 vs the QMDP bound\n")
    print("| task | iteration | lower | upper | gap | alphas | seconds |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    solved = {}
    for name, path in TASKS.items():
        model, pomdp, result = solve_task_file(path, ns)
        solved[name] = (model, pomdp, result)
        marks = {1, 10, 25, 50, 100, 150, 200, 300, 400, len(result.history)}
        for s in result.history:
            if s.iteration in marks:
                print(
                    f"| {name} | {s.iteration} | {s.value_b0:.2f} | {s.upper_b0:.2f} | "
                    f"{s.gap:.2f} ({100 * s.gap / abs(s.upper_b0):.0f}%) | {s.n_alphas} | "
                    f"{s.elapsed_s:.1f} |"
                )

    print("\n## Belief update + action selection (task r1, one-step lookahead)\n")
    model, pomdp, result = solved["r1"]
    choose = policy_chooser(result.policy, pomdp)
    b = model.initial_belief(7, [(11, "not moving")])
    z = model.observation_index(7, [(9, "East higher")])
    a = ACTIONS.index("Do nothing")
    n = 300
    t = time.perf_counter()
    for _ in range(n):
        b1 = B.update(pomdp, b, a, z)
    t_upd = (time.perf_counter() - t) / n * 1e3
    t = time.perf_counter()
    for _ in range(n):
        choose(b1)
    t_look = (time.perf_counter() - t) / n * 1e3
    t = time.perf_counter()
    for _ in range(n):
        result.policy.action(b1)
    t_alpha = (time.perf_counter() - t) / n * 1e3
    print(
        f"| belief update | {t_upd:.3f} ms |\n| action, one-step lookahead | {t_look:.3f} ms |\n"
        f"| action, best alpha vector | {t_alpha:.3f} ms |"
    )

    limit = f"{args.pomdp_time:.0f} s limit"
    print(f"\n## solve-pomdp on ../shared/pomdp ({limit}) beside SARSOP (60 s)\n")
    print("| file | states | ours LB / UB (QMDP) | seconds | SARSOP LB / UB |")
    print("|---|---:|---|---:|---|")
    for name, ref in SARSOP.items():
        pomdp = read_pomdp(SHARED / name)
        r = solve(pomdp, SolverConfig(beliefs=500, iterations=100000, time_limit_s=args.pomdp_time))
        print(
            f"| {name} | {pomdp.n_states} | {r.lower_bound:.4f} / {r.upper_bound:.4f} | "
            f"{r.seconds:.1f} | {ref} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
