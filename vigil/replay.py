"""Chapter 5's tables replayed through our planner, shared by ``vigil replay`` and
``vigil replay-report``: the replay (solving each needed task once), and its Markdown
and JSON forms.
"""

from __future__ import annotations

import argparse
import sys
import time

from vigil.solving import TASKS, progress_printer, solve_task_file


def run_replay(tables: list[str], args: argparse.Namespace, policies: dict | None = None):
    """Replay the named tables; solves each needed task once. Returns TableResults."""
    from stack.planning.replay import TABLES, policy_chooser, replay_table

    solved: dict[str, tuple] = dict(policies or {})
    results = []
    for name in tables:
        table = TABLES[name]
        if table.task not in solved:
            print(f"solving task {table.task} ...", file=sys.stderr, flush=True)
            # --time-limit holds for each task's solve (the first counts from the
            # command's start, the later ones from their own)
            model, pomdp, result = solve_task_file(
                TASKS[table.task], args, progress_printer(args), require_progress=True,
                start=None if not solved else time.perf_counter(),
            )  # fmt: skip
            solved[table.task] = (model, pomdp, result)
        model, pomdp, result = solved[table.task]
        results.append(replay_table(model, pomdp, table, policy_chooser(result.policy, pomdp)))
    return results, solved


def replay_markdown(results) -> str:
    lines = []
    total = sum(len(r.steps) for r in results)
    agree = sum(r.agreement for r in results)
    ties = sum(r.agreement_with_ties for r in results)
    lines.append(
        f"Agreement with the thesis's actions: **{agree}/{total}** "
        f"({ties}/{total} counting ties between equally good moves)\n"
    )
    for r in results:
        t = r.table
        lines.append(
            f"## Table {t.name}: {t.title} ({r.agreement}/{len(r.steps)}, "
            f"{r.agreement_with_ties} with ties)\n"
        )
        lines.append(
            "| step | thesis action | our action | obs robot | obs person | obs velocity | |"
        )
        lines.append("|---:|---|---|---:|---|---|---|")
        for s in r.steps:
            mark = "=" if s.agrees else ("tie" if s.tie else "**differs**")
            o = s.observation
            lines.append(
                f"| {s.step} | {s.thesis_action} | {s.chosen_action} | {o.robot} | "
                f"{o.person if o.person is not None else 'No person'} | {o.velocity} | {mark} |"
            )
        if r.quotes:
            lines.append("\n| after step | belief | thesis | ours |")
            lines.append("|---:|---|---:|---:|")
            for q in r.quotes:
                lines.append(
                    f"| {q.quote.step} | {q.quote.label} | {q.quote.thesis:.2f} | {q.ours:.2f} |"
                )
        lines.append("")
    return "\n".join(lines)


def replay_json(results) -> dict:
    out = {}
    for r in results:
        out[r.table.name] = {
            "agreement": r.agreement,
            "agreement_with_ties": r.agreement_with_ties,
            "steps": [
                {
                    "step": s.step,
                    "observation": {
                        "robot": s.observation.robot,
                        "person": s.observation.person,
                        "velocity": s.observation.velocity,
                    },
                    "thesis_action": s.thesis_action,
                    "chosen_action": s.chosen_action,
                    "agrees": s.agrees,
                    "tie": s.tie,
                }
                for s in r.steps
            ],
            "quoted_beliefs": [
                {
                    "step": q.quote.step,
                    "belief": q.quote.label,
                    "thesis": q.quote.thesis,
                    "ours": q.ours,
                }
                for q in r.quotes
            ],
        }
    return out
