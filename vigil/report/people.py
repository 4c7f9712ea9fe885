"""Guarding metrics per person when the twin has several walkers (issue 16): pure.

The trace's records list every walker (``people``); :func:`walkers_in_trace` counts
them, :func:`~vigil.report.metrics.timeline_from_trace` with ``walker=i`` gives walker
i's timeline, and :func:`people_metrics` finds each walker's visits (the definitions
of :mod:`vigil.report.metrics`), the false trips with nobody at all in the room and
the needless trips with nobody in the cell.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

from stack.cells import CellGrid
from vigil.report.metrics import (
    MIN_VISIT_S,
    NEEDLESS_S,
    QUIET_S,
    REACH_SPEED_MPS,
    Timeline,
    classify_warnings,
    false_trips,
    find_visits,
    needless_trips,
    reach_time_s,
    visit_summary,
)


def walkers_in_trace(trace: Iterable[dict]) -> int:
    """How many walkers the trace's records list (``people``; 0: one-person records)."""
    return max((len(rec.get("people") or ()) for rec in trace), default=0)


def people_metrics(
    timelines: Sequence[Timeline],
    restricted: Sequence[int],
    min_visit_s: float = MIN_VISIT_S,
    grid: CellGrid | None = None,
    warning_starts: Sequence[float] | None = None,
) -> dict[str, Any]:
    """Visits per person, and false trips with anybody in the room (issue 16).

    Args:
        timelines: one timeline per walker (:func:`timeline_from_trace` with ``walker``),
            on the same instants.
        warning_starts: the utterances' start times (each visit's warning lead time).

    Returns:
        ``per_person``: each walker's visits, guarded, reachable, max delay; the totals;
        ``false_trips``: arrivals in a restricted cell with nobody in the room during
        ``QUIET_S`` before and after; ``needless_trips``: arrivals in a restricted cell
        no walker was in during ``NEEDLESS_S`` before and after.
    """
    per = []
    for i, tl in enumerate(timelines):
        visits = find_visits(tl, restricted, min_visit_s, grid, warning_starts=warning_starts)
        per.append({"person": i + 1, **visit_summary(visits)})
    every = [v for p in per for v in p["visits"]]
    trips: list[dict[str, Any]] = []
    needless: list[dict[str, Any]] = []
    if timelines:
        first = timelines[0]
        anyone = tuple(any(tl.present[k] for tl in timelines) for k in range(len(first)))
        trips = false_trips(
            Timeline(first.t, first.robot, first.robot_known, first.person, anyone, first.source),
            restricted,
        )
        needless = needless_trips(first, restricted, others=timelines[1:])
    delays = [p["max_delay_s"] for p in per if p["max_delay_s"] is not None]
    # a warning is timely when it is timely for some walker (it warned that one), an
    # approach warning when it is timely only as one
    each = [classify_warnings(tl, restricted, warning_starts or (), grid=grid) for tl in timelines]
    timely = [any(w[k]["timely"] for w in each) for k in range(len(warning_starts or ()))]
    direct = [
        any(w[k]["timely"] and not w[k]["approach"] for w in each)
        for k in range(len(warning_starts or ()))
    ]
    return {
        "per_person": per,
        "n_visits": sum(p["n_visits"] for p in per),
        "guarded": sum(p["guarded"] for p in per),
        "reachable": sum(p["reachable"] for p in per),
        "guarded_reachable": sum(p["guarded_reachable"] for p in per),
        "one_guard": None if grid is None else one_guard_reachable(every, grid),
        "max_delay_s": max(delays) if delays else None,
        "false_trips": trips,
        "n_false_trips": len(trips),
        "robot_first": sum(p["robot_first"] for p in per),
        "needless_trips": needless,
        "n_needless_trips": len(needless),
        "timely_warnings": sum(timely),
        "late_warnings": sum(not t for t in timely),
        "approach_warnings": sum(t and not d for t, d in zip(timely, direct, strict=True)),
    }


ONE_GUARD_EXACT_MAX = 12  # reachable visits counted exactly (2^12 x 12 states at most)


def one_guard_reachable(
    visits: Sequence[dict[str, Any]], grid: CellGrid, speed_mps: float = REACH_SPEED_MPS
) -> int:
    """How many of ``visits`` (every walker's, as :func:`visit_summary` lists them) one
    ideal guard could guard: the most reachable visits (``reachable``: the ideal guard
    of :mod:`vigil.report.metrics`, one person at a time) that one robot could be in,
    one after the other, while the person is inside. Optimistic, so the count is an
    upper bound: the guard is in the first visit's cell as the person enters, and
    leaves each cell the moment it is there for the next, straight at ``speed_mps``
    from the cell's centre to the next cell's nearest point. Two people in the two
    cells of task r2 at once are one visit for one guard, not two. Exact up to
    ``ONE_GUARD_EXACT_MAX`` reachable visits; beyond, every reachable visit.
    """
    vs = [
        (float(v["person_arrival_t"]), math.inf if v["person_left_t"] is None
         else float(v["person_left_t"]), int(v["cell"]))
        for v in visits
        if v.get("reachable")
    ]  # fmt: skip
    n = len(vs)
    if n > ONE_GUARD_EXACT_MAX:  # 2^n states: count every reachable visit (still an
        return n  # upper bound) rather than stall or fail a run's report
    # best[mask][last]: the earliest instant the guard can have been in the cells of
    # the visits in ``mask``, ending with ``last``
    best: dict[tuple[int, int], float] = {(1 << i, i): vs[i][0] for i in range(n)}
    most = 1 if n else 0
    for mask in range(1, 1 << n):
        for last in range(n):
            t = best.get((mask, last))
            if t is None:
                continue
            most = max(most, bin(mask).count("1"))
            for j in range(n):
                if mask >> j & 1:
                    continue
                arrive, left, cell = vs[j]
                there = max(arrive, t + reach_time_s(grid, vs[last][2], cell, speed_mps))
                if there < left and there < best.get((mask | 1 << j, j), math.inf):
                    best[(mask | 1 << j, j)] = there
    return most


def people_markdown(m: dict[str, Any]) -> str:
    """:func:`people_metrics` as Markdown (the run's steps.md)."""
    lines = [
        "## Visits per person (issue 16)",
        "",
        "| person | cell | in [s] | out [s] | guarded | delay [s] | reachable |",
        "|---:|---:|---:|---:|---|---:|---|",
    ]
    for p in m["per_person"]:
        for v in p["visits"]:
            left = v["person_left_t"]
            lines.append(
                f"| {p['person']} | {v['cell']} | {v['person_arrival_t']:.1f} | "
                f"{'still in' if left is None else f'{left:.1f}'} | "
                f"{'yes' if v['guarded'] else 'no'} | "
                f"{_delay(v['delay_s'])} | "
                f"{v['reachable']} |"
            )
        if not p["visits"]:
            lines.append(f"| {p['person']} | no visit | | | | | |")
    lines += [
        "",
        f"Guarded {m['guarded']} of {m['n_visits']} visits; false trips (nobody in the room "
        f"{QUIET_S:g} s before and after): {m['n_false_trips']}; needless trips (nobody in "
        f"the cell {NEEDLESS_S:g} s before and after): {m['n_needless_trips']}.",
        "",
    ]
    return "\n".join(lines)


def _delay(d: float | None) -> str:
    return "" if d is None else f"{d:.1f}"
