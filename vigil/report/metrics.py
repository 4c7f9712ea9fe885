"""Honest guarding metrics of one run, from ground truth: pure functions.

Every definition is the one in ``docs/EXPERIMENTS.md`` ("Metrics"); nothing here
reads files or draws. Inputs are a :class:`Timeline` (the twin's ground truth as
cells over time, built from ``trace.jsonl`` by :func:`timeline_from_trace`; both in
:mod:`vigil.report.timeline`, importable from here), the utterance start times (the
speech log) and the decision steps' person labels.

In short:

- a **visit**: the person's floor position inside one restricted cell for at least
  ``MIN_VISIT_S`` (cell, entry, exit);
- **guarded**: the robot (its centre) is in that cell at some instant of the visit;
  **delay**: the robot's first instant there minus the person's entry (0 when the
  robot was there already); **abandoned**: after arriving, the robot is out of the
  cell at an instant when the person is still in it; **robot first**: the robot was in
  the cell at the person's entry (it got there first: delay 0);
- a warning is **timely** when it starts while the person is in a restricted cell,
  within ``WARNING_AFTER_S`` after they left one, or within ``WARNING_BEFORE_S`` before
  they enter one (**ahead**: a guard that anticipates warns as the person approaches),
  or, with the robot in a restricted cell, while the person is next to it (diagonals
  included; off the grid, within 0.3 m of such a cell, the observations' border margin)
  and has not left it within ``WARNING_BEFORE_S`` (an **approach**
  warning: they may turn away, which is what it is for);
  otherwise **late**;
- a visit's **warning lead time**: the person's entry minus the start of the first
  warning between ``WARNING_BEFORE_S`` before the entry (not before the previous
  visit ended) and ``WARNING_AFTER_S`` after the exit: seconds before entry, negative
  when the warning came after it; None when no warning fell in that window;
- **reachable**: whether an ideal guard could have been there: one that knows where
  the person is going from the instant they enter the room and drives at
  ``REACH_SPEED_MPS`` in a straight line from its cell's centre at that instant to the
  nearest point of the visit's cell, arriving before the person leaves. Visits no robot
  of that speed could guard (a person heading straight for the far cell and leaving
  within seconds) are counted apart, so that ``guarded`` / ``reachable`` measures the
  planner, not the base;
- a **false trip**: the robot arrives in a restricted cell while nobody was in the
  room during the ``QUIET_S`` before and after;
- a **needless trip**: the robot arrives in a restricted cell that no person is in at
  any instant during the ``NEEDLESS_S`` before and after, whether or not the room is
  empty (a false trip is a needless trip of an empty room); counted per run;
- per decision step, with the truth at the step's stamp: a **miss** is "No person"
  observed while the person is on the grid; **wrong cell**, a cell other than the
  person's; **unseen**, the label "Unseen" (the camera could not look: not a miss).

Time runs on the run's clock (simulated in the twin). An instant's cell holds from
that trace record until the next one.

The module is just over 500 lines because it is the one place every metric is defined
and computed (runs, the guarding set and studies all call it); split by metric, the
definitions above would lose the one page that states them together.
"""

from __future__ import annotations

import bisect
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from stack.cells import CellGrid
from vigil.report.timeline import Timeline as Timeline
from vigil.report.timeline import timeline_from_trace as timeline_from_trace

MIN_VISIT_S = 1.0  # shorter stays in a restricted cell are not visits
REACH_SPEED_MPS = 0.5  # the ideal guard's speed: the MBot's (and the twin's) top speed
WARNING_AFTER_S = 3.0  # a warning this long after the person left is still timely
QUIET_S = 10.0  # a trip is false when the room was empty this long before and after
WARNING_BEFORE_S = 10.0  # a warning this long before the person entered is timely (ahead)
NEEDLESS_S = 10.0  # a trip is needless when nobody was in the cell this long before and after
NO_PERSON = "No person"
UNSEEN = "Unseen"


# -- visits ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Visit:
    """One visit of the person to a restricted cell and what the robot did.

    ``person_left_t`` is None when the person was still there at the end (then the
    duration runs to the last instant). ``robot_late_arrival_t``: when the visit was
    not guarded, the robot's first instant in the cell within ``QUIET_S`` after the
    person left (the arrival that came too late), else None. ``robot_first``: the
    robot was in the cell at the person's entry. ``first_warning_t`` and
    ``warning_lead_s``: the visit's first warning and its lead time (see the module);
    None without a warning, or when no warning times were given.
    """

    cell: int
    person_arrival_t: float
    person_left_t: float | None
    person_duration_s: float
    guarded: bool
    robot_arrival_t: float | None
    delay_s: float | None
    abandoned: bool
    abandoned_t: float | None
    robot_late_arrival_t: float | None
    reachable: bool | None = None  # None: no grid given, or the robot's cell unknown
    robot_first: bool = False
    first_warning_t: float | None = None
    warning_lead_s: float | None = None  # > 0: before the entry, < 0: after

    def as_dict(self) -> dict[str, Any]:
        return {k: _round(v) if isinstance(v, float) else v for k, v in asdict(self).items()}


def restricted_runs(tl: Timeline, restricted: Iterable[int]) -> list[tuple[int, int, int]]:
    """Maximal runs of instants with the person in one restricted cell: (cell, i0, i1)."""
    cells = set(restricted)
    out, i, n = [], 0, len(tl)
    while i < n:
        c = tl.person[i]
        if c in cells:
            j = i
            while j + 1 < n and tl.person[j + 1] == c:
                j += 1
            out.append((c, i, j))
            i = j + 1
        else:
            i += 1
    return out


def reach_time_s(grid: CellGrid, from_cell: int, to_cell: int, speed_mps: float) -> float:
    """Straight-line time from ``from_cell``'s centre to the nearest point of ``to_cell``."""
    x, y = grid.center(from_cell)
    x0, y0, x1, y1 = grid.bounds(to_cell)
    dx = max(x0 - x, 0.0, x - x1)
    dy = max(y0 - y, 0.0, y - y1)
    return float((dx * dx + dy * dy) ** 0.5 / speed_mps)


def _reachable(
    tl: Timeline,
    i0: int,
    cell: int,
    left: float | None,
    grid: CellGrid,
    speed_mps: float,
    since: int = 0,
) -> bool | None:
    """Could an ideal guard reach ``cell`` before the person left (see the module)?
    The race starts when the person entered the room, or left the previous restricted
    cell (index ``since``), whichever is later."""
    s = i0
    while s > since and tl.present[s - 1]:
        s -= 1  # back to the instant the person entered the room
    known = [k for k in range(s, -1, -1) if tl.robot_known[k] and tl.robot[k] is not None]
    if not known:
        return None
    if left is None:
        return True  # still there at the end: the guard had until then and beyond
    return tl.t[s] + reach_time_s(grid, tl.robot[known[0]], cell, speed_mps) < left  # type: ignore[arg-type]


def find_visits(
    tl: Timeline,
    restricted: Iterable[int],
    min_visit_s: float = MIN_VISIT_S,
    grid: CellGrid | None = None,
    reach_speed_mps: float = REACH_SPEED_MPS,
    warning_starts: Sequence[float] | None = None,
) -> list[Visit]:
    """Every visit (at least ``min_visit_s`` in one restricted cell), in time order;
    with ``grid``, whether an ideal guard could have reached it (``reachable``); with
    ``warning_starts`` (utterance start times), each visit's first warning and lead."""
    visits: list[Visit] = []
    n = len(tl)
    since = 0  # the instant after the previous restricted run
    warnings = sorted(warning_starts or ())
    for cell, i0, i1 in restricted_runs(tl, restricted):
        enter = tl.t[i0]
        left = tl.t[i1 + 1] if i1 + 1 < n else None
        duration = (left if left is not None else tl.t[i1]) - enter
        start = since
        since = i1 + 1
        if duration < min_visit_s:
            continue
        inside = range(i0, i1 + 1)
        there = [k for k in inside if tl.robot[k] == cell]
        arrival = tl.t[there[0]] if there else None
        abandoned_t = None
        if there:
            for k in range(there[0] + 1, i1 + 1):
                if tl.robot_known[k] and tl.robot[k] != cell:
                    abandoned_t = tl.t[k]
                    break
        late = None
        if not there and left is not None:
            for k in range(i1 + 1, n):
                if tl.t[k] > left + QUIET_S:
                    break
                if tl.robot[k] == cell:
                    late = tl.t[k]
                    break
        lo = enter - WARNING_BEFORE_S
        if visits and visits[-1].person_left_t is not None:
            lo = max(lo, visits[-1].person_left_t)
        hi = (left if left is not None else tl.t[-1]) + WARNING_AFTER_S
        first_w = next((w for w in warnings if lo - 1e-9 <= w <= hi + 1e-9), None)
        visits.append(
            Visit(
                cell=cell,
                person_arrival_t=enter,
                person_left_t=left,
                person_duration_s=duration,
                guarded=bool(there),
                robot_arrival_t=arrival,
                delay_s=None if arrival is None else arrival - enter,
                abandoned=abandoned_t is not None,
                abandoned_t=abandoned_t,
                robot_late_arrival_t=late,
                reachable=None
                if grid is None
                else _reachable(tl, i0, cell, left, grid, reach_speed_mps, start),
                robot_first=bool(there) and there[0] == i0,
                first_warning_t=first_w,
                warning_lead_s=None if first_w is None else enter - first_w,
            )
        )
    return visits


# -- warnings ----------------------------------------------------------------------------


def restricted_intervals(tl: Timeline, restricted: Iterable[int]) -> list[tuple[int, float, float]]:
    """(cell, from, to) while the person is in a restricted cell, any duration; ``to``
    is the next instant's time (the last instant's time at the end)."""
    out = []
    for cell, i0, i1 in restricted_runs(tl, restricted):
        end = tl.t[i1 + 1] if i1 + 1 < len(tl) else tl.t[i1]
        out.append((cell, tl.t[i0], end))
    return out


def classify_warnings(
    tl: Timeline,
    restricted: Iterable[int],
    starts: Sequence[float],
    after_s: float = WARNING_AFTER_S,
    before_s: float = WARNING_BEFORE_S,
    grid: CellGrid | None = None,
) -> list[dict[str, Any]]:
    """Each warning's start, the person's and robot's cells then, and whether it was
    timely (started while the person was in a restricted cell, within ``after_s``
    after they left one, or within ``before_s`` before they entered one: ``ahead``;
    with ``grid``, also while the robot stood in a restricted cell and the person was
    next to it, diagonals included (or off the grid within ``EDGE_M`` of such a cell),
    not having left it within ``before_s``:
    ``approach``, a warning to someone who may then turn away) or late."""
    restricted = tuple(restricted)
    spans = restricted_intervals(tl, restricted)
    out = []
    for s in starts:
        cell = next((c for c, a, b in spans if a <= s <= b + after_s), None)
        ahead = None
        if cell is None:
            ahead = next((c for c, a, _ in spans if a - before_s <= s < a), None)
            cell = ahead
        i = tl.index_at(s)
        person = None if i is None else tl.person[i]
        robot = None if i is None or not tl.robot_known[i] else tl.robot[i]
        near = person if i is None or not tl.person_edge else tl.person_edge[i]
        approach = (
            cell is None
            and grid is not None
            and robot in restricted
            and near is not None
            and grid.chebyshev(near, robot) <= 1
            # not someone who just left it: that warning is late
            and not any(c == robot and s - before_s <= b <= s for c, _, b in spans)
        )
        out.append(
            {
                "t": _round(s),
                "timely": cell is not None or approach,
                "ahead": ahead is not None,
                "approach": approach,
                "visit_cell": cell,
                "person_cell": person,
                "robot_cell": robot,
            }
        )
    return out


# -- false trips -------------------------------------------------------------------------


def false_trips(
    tl: Timeline, restricted: Iterable[int], quiet_s: float = QUIET_S
) -> list[dict[str, Any]]:
    """Arrivals of the robot in a restricted cell with nobody in the room during the
    ``quiet_s`` before and after (as far as the timeline reaches)."""
    out = []
    for k, c in robot_arrivals(tl, restricted):
        t = tl.t[k]
        lo = bisect.bisect_left(tl.t, t - quiet_s - 1e-9)
        hi = bisect.bisect_right(tl.t, t + quiet_s + 1e-9)
        if not any(tl.present[lo:hi]):
            out.append({"t": _round(t), "cell": c})
    return out


def robot_arrivals(tl: Timeline, restricted: Iterable[int]) -> list[tuple[int, int]]:
    """(instant, cell) of every arrival of the robot in a restricted cell (its cell
    changes to it, the robot's position known)."""
    cells = set(restricted)
    return [
        (k, tl.robot[k])
        for k in range(1, len(tl))
        if tl.robot[k] in cells and tl.robot[k - 1] != tl.robot[k] and tl.robot_known[k]
    ]


def needless_trips(
    tl: Timeline,
    restricted: Iterable[int],
    window_s: float = NEEDLESS_S,
    others: Sequence[Timeline] = (),
) -> list[dict[str, Any]]:
    """Arrivals of the robot in a restricted cell that no person was in at any instant
    during the ``window_s`` before and after (the room empty or not).

    Args:
        tl: the robot's and the (first) person's timeline.
        others: the other walkers' timelines on the same instants (issue 16).
    """
    people = [tl.person, *(o.person for o in others)]
    out = []
    for k, c in robot_arrivals(tl, restricted):
        t = tl.t[k]
        # the instant holding at t - window_s (it lasts into the window) to t + window_s
        lo = max(bisect.bisect_right(tl.t, t - window_s + 1e-9) - 1, 0)
        hi = bisect.bisect_right(tl.t, t + window_s + 1e-9)
        if not any(c in p[lo:hi] for p in people):
            out.append({"t": _round(t), "cell": c})
    return out


# -- decision steps ----------------------------------------------------------------------


def step_outcome(observed: str | None, true_cell: int | None, present: bool) -> str:
    """One step's person observation against the truth at its stamp.

    Returns one of "seen" (the right cell), "wrong cell", "miss" ("No person" with
    the person on the grid), "unseen" ("Unseen"), "absent" ("No person", nobody on
    the grid), "phantom" (a cell, nobody on the grid), "no observation".
    """
    if observed is None:
        return "no observation"
    if observed == UNSEEN:
        return "unseen"
    if observed == NO_PERSON:
        return "miss" if true_cell is not None else "absent"
    if not observed.isdigit():
        return "no observation"
    if true_cell is None:
        return "phantom"
    return "seen" if int(observed) == true_cell else "wrong cell"


def step_counts(
    tl: Timeline, steps: Sequence[tuple[float, str | None, str | None]]
) -> dict[str, Any]:
    """Counts over the decision steps: (stamp, observed person label, source) each.

    ``miss_rate`` = misses / steps with the person on the grid (None without such
    steps); ``unseen_steps`` counts every "Unseen" step, ``unseen_with_person`` those
    with the person on the grid.
    """
    outcomes: Counter[str] = Counter()
    sources: Counter[str] = Counter()
    with_person = unseen_with_person = 0
    per_step = []
    for stamp, label, source in steps:
        i = tl.index_at(stamp)
        true_cell = None if i is None else tl.person[i]
        present = False if i is None else tl.present[i]
        o = step_outcome(label, true_cell, present)
        outcomes[o] += 1
        per_step.append(o)
        if source:
            sources[str(source)] += 1
        if true_cell is not None and label is not None:
            with_person += 1
            unseen_with_person += o == "unseen"
    misses = outcomes["miss"]
    return {
        "steps": len(steps),
        "steps_with_person": with_person,
        "misses": misses,
        "miss_rate": _round(misses / with_person, 4) if with_person else None,
        "wrong_cell_steps": outcomes["wrong cell"],
        "unseen_steps": outcomes["unseen"],
        "unseen_with_person": unseen_with_person,
        "phantom_steps": outcomes["phantom"],
        "outcomes": dict(sorted(outcomes.items())),
        "sources": dict(sorted(sources.items())),
        "per_step": per_step,
    }


# -- all of it ---------------------------------------------------------------------------


def visit_summary(visits: Sequence[Visit]) -> dict[str, Any]:
    """The visit counts of a run or of one person (JSON-ready)."""
    delays = [v.delay_s for v in visits if v.delay_s is not None]
    leads = [v.warning_lead_s for v in visits if v.warning_lead_s is not None]
    return {
        "visits": [v.as_dict() for v in visits],
        "n_visits": len(visits),
        "guarded": sum(v.guarded for v in visits),
        "reachable": sum(bool(v.reachable) for v in visits),
        "guarded_reachable": sum(v.guarded and bool(v.reachable) for v in visits),
        "abandoned": sum(v.abandoned for v in visits),
        "max_delay_s": _round(max(delays)) if delays else None,
        "robot_first": sum(v.robot_first for v in visits),
        "warned_visits": len(leads),
        "warned_before_entry": sum(x >= 0 for x in leads),
        "min_warning_lead_s": _round(min(leads)) if leads else None,
        "mean_warning_lead_s": _round(sum(leads) / len(leads)) if leads else None,
    }


def guard_metrics(
    tl: Timeline,
    restricted: Sequence[int],
    warning_starts: Sequence[float],
    steps: Sequence[tuple[float, str | None, str | None]],
    min_visit_s: float = MIN_VISIT_S,
    grid: CellGrid | None = None,
) -> dict[str, Any]:
    """Every metric of the run (JSON-ready): visits (with the robot first and the
    warnings' lead), warnings, false and needless trips, steps (with ``grid``: the
    visits an ideal guard could reach, and how many of those were guarded)."""
    visits = find_visits(tl, restricted, min_visit_s, grid, warning_starts=warning_starts)
    warnings = classify_warnings(tl, restricted, warning_starts, grid=grid)
    trips = false_trips(tl, restricted)
    needless = needless_trips(tl, restricted)
    counts = step_counts(tl, steps)
    return {
        "basis": tl.source,
        **visit_summary(visits),
        "every_visit_guarded": all(v.guarded for v in visits),
        "warnings": warnings,
        "timely_warnings": sum(w["timely"] for w in warnings),
        "late_warnings": sum(not w["timely"] for w in warnings),
        "approach_warnings": sum(w["approach"] for w in warnings),
        "ahead_warnings": sum(w["ahead"] for w in warnings),
        "false_trips": trips,
        "n_false_trips": len(trips),
        "needless_trips": needless,
        "n_needless_trips": len(needless),
        **{k: v for k, v in counts.items() if k != "per_step"},
    }


def set_totals(metrics: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Totals over several runs' :func:`guard_metrics` (max delay: the largest; the
    warnings' lead over every visit with one). Runs recorded before a key existed
    count 0 for it."""

    def total(key: str) -> int:
        return sum(int(m[key]) for m in metrics)

    def newer(key: str) -> int:
        return sum(int(m.get(key) or 0) for m in metrics)

    delays = [m["max_delay_s"] for m in metrics if m.get("max_delay_s") is not None]
    leads = [
        float(v["warning_lead_s"])
        for m in metrics
        for v in m.get("visits") or ()
        if v.get("warning_lead_s") is not None
    ]
    with_person = total("steps_with_person") if metrics else 0
    misses = total("misses") if metrics else 0
    return {
        "scenarios": len(metrics),
        "n_visits": total("n_visits") if metrics else 0,
        "guarded": total("guarded") if metrics else 0,
        "reachable": sum(int(m.get("reachable", 0)) for m in metrics),
        "guarded_reachable": sum(int(m.get("guarded_reachable", 0)) for m in metrics),
        "abandoned": total("abandoned") if metrics else 0,
        "max_delay_s": max(delays) if delays else None,
        "timely_warnings": total("timely_warnings") if metrics else 0,
        "late_warnings": total("late_warnings") if metrics else 0,
        "approach_warnings": total("approach_warnings") if metrics else 0,
        "n_false_trips": total("n_false_trips") if metrics else 0,
        "n_needless_trips": newer("n_needless_trips"),
        "robot_first": newer("robot_first"),
        "ahead_warnings": newer("ahead_warnings"),
        "warned_visits": len(leads),
        "warned_before_entry": sum(x >= 0 for x in leads),
        "min_warning_lead_s": _round(min(leads)) if leads else None,
        "mean_warning_lead_s": _round(sum(leads) / len(leads)) if leads else None,
        "misses": misses,
        "steps_with_person": with_person,
        "miss_rate": round(misses / with_person, 4) if with_person else None,
        "unseen_steps": total("unseen_steps") if metrics else 0,
        "wrong_cell_steps": total("wrong_cell_steps") if metrics else 0,
    }


def _round(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(float(x), nd) + 0.0
