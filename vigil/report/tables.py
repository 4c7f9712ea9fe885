"""The step table (tables 5.1-5.4 with the truth beside them) and the metric tables.

Pure text: rows from the records (:mod:`vigil.report.records`), Markdown and CSV out.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from stack.planning.model import FactoredModel
from stack.vocabulary import ACTIONS, NO_PERSON, OUT_OF_MAP
from vigil.report.metrics import Timeline, set_totals, step_outcome
from vigil.report.records import (
    NOT_MOVING,
    UNKNOWN,
    cell_of_label,
    direction_of,
    hidden_cells,
    true_velocity_label,
)

if TYPE_CHECKING:
    from stack.planning.replay import Table


def truth_at(trace: list[dict], times: list[float], t: float) -> dict | None:
    """The trace record nearest at or before ``t`` (None before the first)."""
    import bisect

    i = bisect.bisect_right(times, t + 1e-9) - 1
    return trace[i] if i >= 0 else None


@dataclass
class StepRow:
    """One row of the step table: the planner's record beside the truth at stamp_s."""

    step: int
    stamp_s: float
    action: str
    obs_robot: str  # a label, or "-" when the step has no observation
    obs_person: str
    obs_velocity: str
    true_robot: str  # a label, or "-" when there is no ground truth at stamp_s
    true_person: str
    true_velocity: str
    reward: float | None
    reward_basis: str  # "true", "observed" or "-"
    discounted: float | None
    cumulative: float | None
    nav_result: str
    resumed: bool
    error: str
    belief_person: dict[int, float] | None = field(default=None, repr=False)
    belief_none: float | None = None
    source: str = ""  # what saw the person ("camera", "laser", "fused", "none"), if recorded
    hidden: str = ""  # cells the camera could not see, "3 (40%), 5"
    trigger: str = ""  # why the step ended, if recorded ("step", "person in 3")
    outcome: str = ""  # the person label against the truth (metrics.step_outcome)

    @property
    def mismatches(self) -> list[str]:
        pairs = (
            ("robot", self.obs_robot, self.true_robot),
            ("person", self.obs_person, self.true_person),
            ("velocity", self.obs_velocity, self.true_velocity),
        )
        return [n for n, o, t in pairs if UNKNOWN not in (o, t) and o != t]


def reward_of(
    model: FactoredModel, R: np.ndarray, robot: int | None, person: int | None, vel: str, a: str
) -> float:
    persons = [(person, direction_of(vel))] + [(None, NOT_MOVING)] * (model.people - 1)
    return float(R[model.state_index(robot, persons), ACTIONS.index(a)])


def step_rows(
    model: FactoredModel,
    steps: list[dict],
    trace: list[dict],
    timeline: Timeline | None = None,
) -> list[StepRow]:
    """The step table: observations, the truth at each stamp, the rewards.

    ``timeline`` (ground truth as cells, :func:`metrics.timeline_from_trace`) adds
    each step's outcome (seen, miss, unseen, wrong cell...).

    The reward of step n is the model's reward table at the true state at ``stamp_s``
    and step n's action (basis "true"); with no ground truth there, at the observed
    state (basis "observed", as the thesis's figures count it). It is discounted by
    gamma^(n - 1), n the record's step number.
    """
    gamma = model.task.discount
    R = model.reward_table().reshape(model.n_states, len(ACTIONS))
    times = [float(r["t"]) for r in trace]
    rows, total = [], 0.0
    for rec in steps:
        obs = rec.get("observation")
        truth = truth_at(trace, times, float(rec["stamp_s"]))
        if truth is not None and truth.get("robot") is not None:
            tr = truth.get("robot_cell")
            tp = truth.get("person_cell") if truth.get("person") is not None else None
            tv = true_velocity_label(truth.get("person_velocity")) if tp is not None else NOT_MOVING
            true = (OUT_OF_MAP if tr is None else str(tr), NO_PERSON if tp is None else str(tp), tv)
            reward = reward_of(model, R, tr, tp, tv, rec["action"])
            basis = "true"
        else:
            true = (UNKNOWN, UNKNOWN, UNKNOWN)
            if obs is not None:
                reward = reward_of(
                    model,
                    R,
                    cell_of_label(obs["robot"]),
                    cell_of_label(obs["person"]),
                    obs["velocity"],
                    rec["action"],
                )
                basis = "observed"
            else:
                reward, basis = None, UNKNOWN
        disc = None if reward is None else reward * gamma ** (int(rec["step"]) - 1)
        total += disc or 0.0
        belief = rec.get("belief") or {}
        bp = belief.get("person")
        nav = rec.get("nav")
        outcome = ""
        if timeline is not None:
            i = timeline.index_at(float(rec["stamp_s"]))
            true_cell = None if i is None else timeline.person[i]
            present = False if i is None else timeline.present[i]
            outcome = step_outcome(obs["person"] if obs else None, true_cell, present)
        hidden = hidden_cells((obs or {}).get("hidden"))
        rows.append(
            StepRow(
                step=int(rec["step"]),
                stamp_s=float(rec["stamp_s"]),
                action=rec["action"],
                obs_robot=obs["robot"] if obs else UNKNOWN,
                obs_person=obs["person"] if obs else UNKNOWN,
                obs_velocity=obs["velocity"] if obs else UNKNOWN,
                true_robot=true[0],
                true_person=true[1],
                true_velocity=true[2],
                reward=reward,
                reward_basis=basis,
                discounted=disc,
                cumulative=total,
                nav_result=str(nav.get("result", "")) if isinstance(nav, dict) else "",
                resumed=bool(rec.get("resumed", False)),
                error=str(rec.get("error") or ("no observation" if obs is None else "")),
                belief_person=(
                    {int(k): float(v) for k, v in bp.items() if str(k).isdigit()}
                    if isinstance(bp, dict)
                    else None
                ),
                belief_none=(
                    float(bp[NO_PERSON]) if isinstance(bp, dict) and NO_PERSON in bp else None
                ),
                source=str((obs or {}).get("source") or ""),
                hidden=", ".join(
                    str(c) if f >= 1.0 else f"{c} ({100 * f:.0f}%)" for c, f in hidden.items()
                ),
                trigger=str(rec.get("trigger") or ""),
                outcome=outcome,
            )
        )
    return rows


# -- writing -----------------------------------------------------------------------------

CSV_COLUMNS = (
    "step",
    "stamp_s",
    "action",
    "obs_robot",
    "obs_person",
    "obs_velocity",
    "true_robot",
    "true_person",
    "true_velocity",
    "reward",
    "reward_basis",
    "discounted_reward",
    "cumulative_discounted_reward",
    "nav_result",
    "resumed",
    "error",
    "source",
    "hidden",
    "trigger",
    "outcome",
)


def round_or_none(x: float | None, nd: int = 6) -> float | None:
    return None if x is None else round(float(x), nd) + 0.0


def _fmt(x: float | None, nd: int = 2) -> str:
    return UNKNOWN if x is None else f"{x:.{nd}f}"


def steps_csv(rows: Sequence[StepRow]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in rows:
        w.writerow(
            [
                r.step,
                f"{r.stamp_s:.3f}",
                r.action,
                r.obs_robot,
                r.obs_person,
                r.obs_velocity,
                r.true_robot,
                r.true_person,
                r.true_velocity,
                _fmt(r.reward, 4),
                r.reward_basis,
                _fmt(r.discounted, 4),
                _fmt(r.cumulative, 4),
                r.nav_result,
                int(r.resumed),
                r.error,
                r.source,
                r.hidden,
                r.trigger,
                r.outcome,
            ]
        )
    return buf.getvalue()


def _md_cell(s: Any) -> str:
    return str(s).replace("|", "\\|").replace("\n", " ")


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def steps_markdown(
    rows: Sequence[StepRow], title: str, thesis_table: Table | None = None, gamma: float = 0.99
) -> str:
    """The step table (tables 5.1-5.4's columns, the truth beside them), then the
    thesis's table beside ours when one is given."""
    out = [f"# {title}\n"]
    out.append(
        "Step n: the action chosen from the belief after step n-1, then the observation "
        f"read at sim time t. True values: the trace at or before t. Reward: the model's "
        f"reward at the true state (or the observed one where there is no truth, basis "
        f"'observed') and the action, discounted by {gamma}^(n-1).\n"
    )
    header = (
        "step",
        "t [s]",
        "action",
        "obs robot",
        "obs person",
        "obs velocity",
        "true robot",
        "true person",
        "true velocity",
        "reward",
        "cum. disc. reward",
        "nav",
        "seen by",
        "camera blind in",
        "outcome",
        "differs / note",
    )
    body = []
    for r in rows:
        note = ", ".join(r.mismatches)
        extra = [x for x in (r.error, "resumed" if r.resumed else "") if x]
        if r.reward_basis == "observed":
            extra.append("reward from observation")
        note = "; ".join([x for x in [note] + extra if x])
        body.append(
            (
                r.step,
                f"{r.stamp_s:.2f}",
                r.action,
                r.obs_robot,
                r.obs_person,
                r.obs_velocity,
                r.true_robot,
                r.true_person,
                r.true_velocity,
                _fmt(r.reward),
                _fmt(r.cumulative),
                r.nav_result,
                r.source or UNKNOWN,
                r.hidden or UNKNOWN,
                r.outcome or UNKNOWN,
                note,
            )
        )
    out.append(md_table(header, body))
    if not rows:
        out.append("No decision steps were recorded.\n")
    if thesis_table is not None:
        t = thesis_table
        ours_by_step = {r.step: r for r in rows}
        n = max([len(t.steps)] + [r.step for r in rows])
        comp, same = [], 0
        for k in range(1, n + 1):
            th = t.steps[k - 1] if k <= len(t.steps) else None
            o = ours_by_step.get(k)
            th_cells = (
                (th.action, str(th.robot), NO_PERSON if th.person is None else str(th.person))
                if th
                else ("", "", "")
            )
            agree = th is not None and o is not None and o.action == th.action
            same += agree
            comp.append(
                (
                    k,
                    o.action if o else "",
                    th_cells[0],
                    "yes" if agree else ("" if th is None or o is None else "no"),
                    o.obs_robot if o else "",
                    th_cells[1],
                    o.obs_person if o else "",
                    th_cells[2],
                    o.obs_velocity if o else "",
                    th.velocity if th else "",
                )
            )
        out.append(f"\n## Thesis table {t.name} ({t.title}) beside ours\n")
        out.append(
            f"Same action at {same} of {min(len(t.steps), len(rows))} common steps "
            f"(thesis: {len(t.steps)} steps, ours: {len(rows)}).\n"
        )
        out.append(
            md_table(
                (
                    "step",
                    "action",
                    "thesis action",
                    "same",
                    "robot",
                    "thesis robot",
                    "person",
                    "thesis person",
                    "velocity",
                    "thesis velocity",
                ),
                comp,
            )
        )
    return "\n".join(out)


# -- the metric tables -------------------------------------------------------------------


def _t(x: Any) -> str:
    return UNKNOWN if x is None else f"{x:.1f}"


def metrics_markdown(metrics: Mapping[str, Any]) -> str:
    """A run's guarding metrics (:func:`metrics.guard_metrics`) as Markdown."""
    m = metrics
    rate = m.get("miss_rate")
    out = [
        '## Guarding metrics (docs/EXPERIMENTS.md, "Metrics")\n',
        f"Basis: {m.get('basis')}. Visits {m['n_visits']}, guarded {m['guarded']}, "
        f"abandoned {m['abandoned']}, max delay {_t(m.get('max_delay_s'))} s; warnings "
        f"timely {m['timely_warnings']}, late {m['late_warnings']}; false trips "
        f"{m['n_false_trips']}, needless trips {m.get('n_needless_trips', '-')}; robot "
        f"first on {m.get('robot_first', '-')} visits; steps with the person on the grid "
        f"{m['steps_with_person']}, "
        f"'No person' misses {m['misses']}"
        + (f" ({100 * rate:.0f} %)" if rate is not None else "")
        + f", wrong cell {m['wrong_cell_steps']}, unseen steps {m['unseen_steps']}.\n",
    ]
    if m["visits"]:
        out.append(
            md_table(
                (
                    "cell",
                    "person in [s]",
                    "out [s]",
                    "stay [s]",
                    "guarded",
                    "robot in [s]",
                    "delay [s]",
                    "abandoned [s]",
                    "robot came after [s]",
                    "warning lead [s]",
                ),
                [
                    (
                        v["cell"],
                        _t(v["person_arrival_t"]),
                        _t(v["person_left_t"]) if v["person_left_t"] is not None else "still in",
                        _t(v["person_duration_s"]),
                        "yes" if v["guarded"] else "no",
                        _t(v["robot_arrival_t"]),
                        _t(v["delay_s"]),
                        _t(v["abandoned_t"]) if v["abandoned"] else "no",
                        _t(v["robot_late_arrival_t"]),
                        _t(v.get("warning_lead_s")),
                    )
                    for v in m["visits"]
                ],
            )
        )
    else:
        out.append("No visit to a restricted cell.\n")
    if m["warnings"]:
        out.append("\nWarnings spoken:\n")
        out.append(
            md_table(
                ("start [s]", "timely", "person cell", "robot cell"),
                [
                    (
                        _t(w["t"]),
                        "yes" if w["timely"] else "late",
                        w["person_cell"] if w["person_cell"] is not None else UNKNOWN,
                        w["robot_cell"] if w["robot_cell"] is not None else UNKNOWN,
                    )
                    for w in m["warnings"]
                ],
            )
        )
    if m["false_trips"]:
        trips = ", ".join(f"cell {f['cell']} at {_t(f['t'])} s" for f in m["false_trips"])
        out.append(f"\nFalse trips: {trips}.\n")
    return "\n".join(out)


SET_COLUMNS = (
    "scenario",
    "visits",
    "guarded",
    "reachable (guarded)",
    "abandoned",
    "max delay [s]",
    "timely warnings",
    "late warnings",
    "false trips",
    "No-person misses",
    "unseen steps",
    "wrong-cell steps",
)


def set_row(name: str, m: Mapping[str, Any] | None, error: str = "") -> tuple:
    """One scenario's row of the set table (``m`` None: the run failed)."""
    if m is None:
        return (name, f"failed: {error}") + ("",) * (len(SET_COLUMNS) - 2)
    rate = m.get("miss_rate")
    miss = f"{m['misses']}/{m['steps_with_person']}"
    if rate is not None:
        miss += f" ({100 * rate:.0f} %)"
    return (
        name,
        m["n_visits"],
        m["guarded"],
        f"{m.get('reachable', '-')} ({m.get('guarded_reachable', '-')})",
        m["abandoned"],
        _t(m.get("max_delay_s")),
        m["timely_warnings"],
        m["late_warnings"],
        m["n_false_trips"],
        miss,
        m["unseen_steps"],
        m["wrong_cell_steps"],
    )


def set_markdown(rows: Sequence[tuple[str, Mapping[str, Any] | None, str]]) -> str:
    """The set's table: one row per (name, metrics or None, error) and the totals."""
    body = [set_row(name, m, err) for name, m, err in rows]
    ok = [m for _, m, _ in rows if m is not None]
    totals = set_totals(ok)
    body.append(set_row(f"**total ({len(ok)} runs)**", totals))
    return md_table(SET_COLUMNS, body)
