"""The report of one scenario run (``vigil run``): tables 5.1-5.4 and figures 5.1-5.4
from the records the nodes write into the run folder, plus the run's video.

Inputs in the run folder (formats fixed by ``vigil run``):

- ``steps.jsonl``, one object per decision step (the planner node)::

      {"step": 1, "stamp_s": 12.34, "action": "East",
       "observation": {"robot": "7", "person": "9", "velocity": "East higher"} | null,
       "belief": {"robot": {...}, "person": {"1": p, ..., "No person": p},
                  "direction": {...}} | null,
       "values": [q, ...], "nav": {...} | null, "resumed": false, "error": "..."?}

  Step n's action was chosen from the belief before; the robot executed it; the
  observation was read at sim time ``stamp_s``; ``belief`` is the belief after it.
- ``trace.jsonl``, one object per recorded instant (the recorder node, ~10 Hz)::

      {"t": 1.2, "robot": [x, y, yaw] | null, "robot_cell": 7 | null,
       "person": [x, y] | null, "person_cell": 9 | null, "person_velocity": [vx, vy] | null,
       "odom": [x, y, yaw] | null, "camera": {...} | null, "legs": [[x, y], ...],
       "speech": "text" | null}

  ``robot`` null means no ground truth (hardware mode); then the events of the
  summary fall back to the odometry's cell and the camera's person cell.
- ``speech/*.wav``: listed in the summary.

Malformed records: a line that is not a JSON object, lacks a required key or holds
an unknown label raises :class:`RunRecordError` (a ValueError) naming the file and
the line number. The one exception is a *last* line without its newline (a node
killed in the middle of a write): it is skipped and a warning is listed in
``summary.json["warnings"]``. Missing files are warnings too, unless both are missing.

Outputs: ``steps.md``, ``steps.csv``, ``positions.png``, ``belief.png`` and
``summary.json`` (:func:`write_report`); ``VideoComposer`` writes the MP4 live.
"""

from __future__ import annotations

import bisect
import csv
import io
import json
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stack.cells import CellGrid
from stack.planning.model import (
    ACTIONS,
    NO_PERSON,
    OUT_OF_MAP,
    VELOCITIES,
    FactoredModel,
)

if TYPE_CHECKING:
    from stack.planning.replay import Table

NOT_MOVING = "Not moving"
STEPS_FILE = "steps.jsonl"
TRACE_FILE = "trace.jsonl"
NOT_MOVING_BELOW_MPS = 0.05  # a true speed below this is "Not moving"
SPEED_THRESHOLDS_MPS = (0.2, 0.7)  # thesis 4.5: 0-0.2, 0.2-0.7, higher
VISIT_GRACE_S = 10.0  # a robot arriving this long after the person left still counts
VISIT_MERGE_GAP_S = 1.0  # visits to one cell closer than this are one visit (cell flicker)
UNKNOWN = "-"


class RunRecordError(ValueError):
    """A run record is malformed; the message names the file and the line number."""

    def __init__(self, path: str | Path, line: int | None, reason: str):
        self.path, self.line, self.reason = str(path), line, reason
        where = self.path if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {reason}")


# -- reading -----------------------------------------------------------------------------


def read_jsonl(
    path: str | Path, required: Sequence[str] = (), warnings: list[str] | None = None
) -> list[dict]:
    """The JSON objects of a JSON-lines file, in order; blank lines are skipped.

    Raises:
        RunRecordError: a line is not a JSON object or lacks a ``required`` key. A last
            line without its newline that does not parse (a truncated write) is skipped
            instead, with a message appended to ``warnings`` (raised when None).
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    lines = text.split("\n")
    truncated_tail = not text.endswith("\n")
    out: list[dict] = []
    for i, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as e:
            if truncated_tail and i == len(lines) and warnings is not None:
                warnings.append(f"{path.name}:{i}: skipped a truncated last line ({e.msg})")
                continue
            raise RunRecordError(path, i, f"not valid JSON ({e.msg} at column {e.colno})") from e
        if not isinstance(rec, dict):
            raise RunRecordError(path, i, f"expected a JSON object, got {type(rec).__name__}")
        missing = [k for k in required if k not in rec]
        if missing:
            raise RunRecordError(path, i, f"missing key(s) {missing}")
        rec["_line"] = i
        out.append(rec)
    return out


def _number(path: Path, rec: dict, key: str) -> float:
    v = rec.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise RunRecordError(path, rec.get("_line"), f"{key!r} must be a finite number, got {v!r}")
    return float(v)


def _check_step(path: Path, rec: dict, n_cells: int) -> None:
    line = rec.get("_line")
    step = rec.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise RunRecordError(path, line, f"'step' must be an integer >= 1, got {step!r}")
    _number(path, rec, "stamp_s")
    if rec.get("action") not in ACTIONS:
        raise RunRecordError(path, line, f"unknown action {rec.get('action')!r}; known {ACTIONS}")
    obs = rec.get("observation")
    if obs is None:
        return
    if not isinstance(obs, dict):
        raise RunRecordError(path, line, f"'observation' must be an object or null, got {obs!r}")
    cells = {str(c) for c in range(1, n_cells + 1)}
    checks = (
        ("robot", cells | {OUT_OF_MAP}),
        ("person", cells | {NO_PERSON}),
        ("velocity", set(VELOCITIES)),
    )
    for key, allowed in checks:
        if obs.get(key) not in allowed:
            raise RunRecordError(path, line, f"observation {key} {obs.get(key)!r} is not a label")


# -- labels ------------------------------------------------------------------------------


def true_velocity_label(
    velocity: Sequence[float] | None,
    not_moving_below: float = NOT_MOVING_BELOW_MPS,
    thresholds: tuple[float, float] = SPEED_THRESHOLDS_MPS,
) -> str:
    """The velocity observation label a perfect sensor would give for (vx, vy) [m/s].

    "Not moving" below ``not_moving_below`` (or for None); otherwise the direction of
    the dominant axis (x east, y north; a tie goes to East/West) and the speed class of
    the speed |v|: "0-0.2" below thresholds[0], "0.2-0.7" below thresholds[1], else
    "higher" (as ``stack.perception.observation.speed_class``).
    """
    if velocity is None:
        return NOT_MOVING
    vx, vy = float(velocity[0]), float(velocity[1])
    speed = math.hypot(vx, vy)
    if not math.isfinite(speed) or speed < not_moving_below:
        return NOT_MOVING
    if abs(vx) >= abs(vy):
        direction = "East" if vx > 0 else "West"
    else:
        direction = "North" if vy > 0 else "South"
    if speed < thresholds[0]:
        speed_label = "0-0.2"
    elif speed < thresholds[1]:
        speed_label = "0.2-0.7"
    else:
        speed_label = "higher"
    return f"{direction} {speed_label}"


def direction_of(velocity_label: str) -> str:
    """The model's direction of a velocity label: "East higher" -> "East"."""
    return NOT_MOVING if velocity_label == NOT_MOVING else velocity_label.split()[0]


def _cell_of_label(label: str) -> int | None:
    return None if label in (OUT_OF_MAP, NO_PERSON) else int(label)


# -- the trace ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Instant:
    """One trace record reduced to what the events need.

    ``robot_known`` is False when neither ground truth nor odometry says where the
    robot is; then ``robot_cell`` is None without meaning "out of the map".
    """

    t: float
    robot_known: bool
    robot_cell: int | None
    person_cell: int | None
    speech: str | None


def _instants(trace: list[dict], grid: CellGrid) -> tuple[list[Instant], str]:
    """The event series of a trace: ground truth where the record has it, else the
    odometry's cell and the camera's person cell; and which source was used."""
    out, sources = [], set()
    for rec in trace:
        if rec.get("robot") is not None:
            sources.add("ground truth")
            robot_known, robot_cell = True, rec.get("robot_cell")
            person_cell = rec.get("person_cell") if rec.get("person") is not None else None
        else:
            sources.add("odometry and camera")
            odom = rec.get("odom")
            robot_known = odom is not None
            robot_cell = grid.cell_at(odom[0], odom[1]) if odom is not None else None
            cam = rec.get("camera") or {}
            person_cell = cam.get("cell") if cam.get("status") == "person" else None
        speech = rec.get("speech")
        out.append(Instant(float(rec["t"]), robot_known, robot_cell, person_cell, speech))
    source = " + ".join(sorted(sources)) if sources else "none"
    return out, source


def _truth_at(trace: list[dict], times: list[float], t: float) -> dict | None:
    """The trace record nearest at or before ``t`` (None before the first)."""
    i = bisect.bisect_right(times, t + 1e-9) - 1
    return trace[i] if i >= 0 else None


def person_visits(
    instants: Sequence[Instant],
    restricted: Sequence[int],
    grace_s: float = VISIT_GRACE_S,
    merge_gap_s: float = VISIT_MERGE_GAP_S,
) -> list[dict]:
    """Each visit of the person to a restricted cell and when the robot got there.

    A visit is a maximal run of instants with the person in one restricted cell
    (runs of the same cell less than ``merge_gap_s`` apart are merged). Per visit:
    ``person_arrival_t`` (first instant in the cell), ``person_left_t`` (first
    instant after, None if still there at the end), ``robot_arrival_t`` and
    ``delay_s`` = robot arrival - person arrival: negative when the robot was already
    in the cell (arrival = the start of its stay), None when it did not come before
    ``grace_s`` after the person left.
    """
    runs: list[dict] = []
    for cell in restricted:
        cur: dict | None = None
        for i, ins in enumerate(instants):
            if ins.person_cell == cell:
                if cur is not None and ins.t - instants[cur["last"]].t <= merge_gap_s:
                    cur["last"] = i
                    continue
                if cur is not None:
                    runs.append(cur)
                cur = {"cell": cell, "first": i, "last": i}
            elif cur is not None and ins.t - instants[cur["last"]].t > merge_gap_s:
                runs.append(cur)
                cur = None
        if cur is not None:
            runs.append(cur)
    runs.sort(key=lambda r: (instants[r["first"]].t, r["cell"]))
    visits = []
    for r in runs:
        cell, first, last = r["cell"], r["first"], r["last"]
        arrive = instants[first].t
        left_i = last + 1 if last + 1 < len(instants) else None
        left = instants[left_i].t if left_i is not None else None
        robot_arrival = None
        if instants[first].robot_cell == cell:
            j = first
            while j > 0 and instants[j - 1].robot_cell == cell:
                j -= 1
            robot_arrival = instants[j].t
        else:
            until = (left if left is not None else instants[last].t) + grace_s
            for ins in instants[first + 1 :]:
                if ins.t > until:
                    break
                if ins.robot_cell == cell:
                    robot_arrival = ins.t
                    break
        end = left if left is not None else instants[last].t
        warned = [
            ins.t for ins in instants if ins.speech and arrive - grace_s <= ins.t <= end + grace_s
        ]
        visits.append(
            {
                "cell": cell,
                "person_arrival_t": _round(arrive),
                "person_left_t": _round(left),
                "person_duration_s": _round(end - arrive),
                "robot_arrival_t": _round(robot_arrival),
                "delay_s": _round(None if robot_arrival is None else robot_arrival - arrive),
                "warnings_t": [_round(t) for t in warned],
            }
        )
    return visits


# -- the step table ----------------------------------------------------------------------


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

    @property
    def mismatches(self) -> list[str]:
        pairs = (
            ("robot", self.obs_robot, self.true_robot),
            ("person", self.obs_person, self.true_person),
            ("velocity", self.obs_velocity, self.true_velocity),
        )
        return [n for n, o, t in pairs if UNKNOWN not in (o, t) and o != t]


def _reward(
    model: FactoredModel, R: np.ndarray, robot: int | None, person: int | None, vel: str, a: str
) -> float:
    persons = [(person, direction_of(vel))] + [(None, NOT_MOVING)] * (model.people - 1)
    return float(R[model.state_index(robot, persons), ACTIONS.index(a)])


def step_rows(model: FactoredModel, steps: list[dict], trace: list[dict]) -> list[StepRow]:
    """The step table: observations, the truth at each stamp, the rewards.

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
        truth = _truth_at(trace, times, float(rec["stamp_s"]))
        if truth is not None and truth.get("robot") is not None:
            tr = truth.get("robot_cell")
            tp = truth.get("person_cell") if truth.get("person") is not None else None
            tv = true_velocity_label(truth.get("person_velocity")) if tp is not None else NOT_MOVING
            true = (OUT_OF_MAP if tr is None else str(tr), NO_PERSON if tp is None else str(tp), tv)
            reward = _reward(model, R, tr, tp, tv, rec["action"])
            basis = "true"
        else:
            true = (UNKNOWN, UNKNOWN, UNKNOWN)
            if obs is not None:
                reward = _reward(
                    model,
                    R,
                    _cell_of_label(obs["robot"]),
                    _cell_of_label(obs["person"]),
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
)


def _round(x: float | None, nd: int = 6) -> float | None:
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
            ]
        )
    return buf.getvalue()


def _md_cell(s: Any) -> str:
    return str(s).replace("|", "\\|").replace("\n", " ")


def _md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
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
                note,
            )
        )
    out.append(_md_table(header, body))
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
            _md_table(
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


def _plot(
    run_dir: Path,
    model: FactoredModel,
    rows: Sequence[StepRow],
    thesis_table: Table | None,
    title: str,
) -> list[str]:
    from vigil.report import plot_belief_grids, plot_positions

    def cells(labels: Sequence[str]) -> list:
        return [float("nan") if x == UNKNOWN else _cell_of_label(x) for x in labels]

    task = model.task
    steps = [r.step for r in rows]
    series = [
        ("robot (observed)", cells([r.obs_robot for r in rows]), "step:b-"),
        ("robot (true)", cells([r.true_robot for r in rows]), "c--"),
        ("person (observed)", cells([r.obs_person for r in rows]), "o"),
        ("person (true)", cells([r.true_person for r in rows]), "x:"),
    ]
    if thesis_table is not None:
        th = list(thesis_table.steps[: len(rows)])
        pad = [float("nan")] * (len(rows) - len(th))
        series.append(("robot (thesis)", [st.robot for st in th] + pad, "s-"))
        series.append(("person (thesis)", [st.person for st in th] + pad, "d:"))
        title += f" - thesis table {thesis_table.name}"
    rewards = {"cumulative discounted reward": [r.cumulative for r in rows]}
    files = []
    plot_positions(
        run_dir / "positions.png",
        steps,
        [s for s in series if not all(isinstance(v, float) and np.isnan(v) for v in s[1])],
        n_cells=model.n_cells,
        restricted=task.restricted_cells,
        rest_cell=task.rest_cell,
        rewards=rewards,
        title=title,
    )
    files.append("positions.png")
    panels = []
    for r in rows:
        true_p = r.true_person if r.true_person not in (UNKNOWN, NO_PERSON) else None
        robot = r.obs_robot if r.obs_robot not in (UNKNOWN, OUT_OF_MAP) else None
        if robot is None and r.true_robot not in (UNKNOWN, OUT_OF_MAP):
            robot = r.true_robot
        panels.append(
            {
                "title": f"{r.step}: {r.action}",
                "probs": r.belief_person,
                "robot": None if robot is None else int(robot),
                "person": None if true_p is None else int(true_p),
                "note": "" if r.belief_none is None else f"P(none) {r.belief_none:.2f}",
            }
        )
    plot_belief_grids(
        run_dir / "belief.png",
        task.grid,
        panels,
        restricted=task.restricted_cells,
        title=f"{title}: P(person in cell) after each step",
    )
    files.append("belief.png")
    return files


def summarise(
    model: FactoredModel,
    rows: Sequence[StepRow],
    trace: list[dict],
    wavs: Sequence[str],
    warnings: Sequence[str],
    thesis_table: Table | None = None,
) -> dict:
    """The run's summary (JSON-ready, deterministic)."""
    task = model.task
    instants, source = _instants(trace, task.grid)
    restricted = tuple(task.restricted_cells)
    visits = person_visits(instants, restricted)

    left_trace = [i.t for i in instants if i.robot_known and i.robot_cell is None]
    left_steps = [r.step for r in rows if r.obs_robot == OUT_OF_MAP]

    in_region = [i.t for i in instants if i.person_cell is not None]
    person_last = in_region[-1] if in_region else None
    returned, returned_t, still_there = None, None, False
    if person_last is not None:
        still_there = instants[-1].person_cell is not None
        later = [i.t for i in instants if i.t > person_last and i.robot_cell == task.rest_cell]
        returned_t = later[0] if later else None
        returned = None if still_there else returned_t is not None

    spoken = [
        {
            "t": _round(i.t),
            "text": i.speech,
            "robot_cell": i.robot_cell if i.robot_known else None,
            "robot_in_restricted": i.robot_cell in restricted,
        }
        for i in instants
        if i.speech
    ]

    camera = Counter()
    nav = Counter()
    for rec in trace:
        cam = rec.get("camera")
        camera["missing" if not isinstance(cam, dict) else str(cam.get("status"))] += 1
    for r in rows:
        if r.nav_result:
            nav[r.nav_result] += 1

    def agreement(pairs: list[tuple[str, str]]) -> dict:
        known = [(o, t) for o, t in pairs if UNKNOWN not in (o, t)]
        return {"same": sum(o == t for o, t in known), "compared": len(known)}

    rewarded = [r for r in rows if r.reward is not None]
    bases = sorted({r.reward_basis for r in rewarded})
    observed_total = 0.0
    R = model.reward_table().reshape(model.n_states, len(ACTIONS))
    n_observed = 0
    for r in rows:
        if r.obs_robot != UNKNOWN:
            rw = _reward(
                model,
                R,
                _cell_of_label(r.obs_robot),
                _cell_of_label(r.obs_person),
                r.obs_velocity,
                r.action,
            )
            observed_total += rw * task.discount ** (r.step - 1)
            n_observed += 1
    times = [i.t for i in instants]
    summary: dict[str, Any] = {
        "task": task.name,
        "restricted_cells": list(restricted),
        "rest_cell": task.rest_cell,
        "discount": task.discount,
        "ground_truth": source == "ground truth",
        "events_source": source,
        "steps": len(rows),
        "step_errors": sum(1 for r in rows if r.error),
        "resumed_steps": sum(1 for r in rows if r.resumed),
        "actions": dict(sorted(Counter(r.action for r in rows).items())),
        "total_discounted_reward": _round(sum(r.discounted for r in rewarded)) if rows else 0.0,
        "total_reward": _round(sum(r.reward for r in rewarded)) if rows else 0.0,
        "reward_basis": "+".join(bases) if bases else None,
        "steps_without_reward": len(rows) - len(rewarded),
        "total_discounted_reward_observed": _round(observed_total) if n_observed else None,
        "visits": visits,
        "robot_reached_every_visit": bool(visits)
        and all(v["robot_arrival_t"] is not None for v in visits),
        "left_map": bool(left_trace or left_steps),
        "left_map_first_t": _round(left_trace[0]) if left_trace else None,
        "left_map_observed_steps": left_steps,
        "person_last_in_region_t": _round(person_last),
        "person_in_region_at_end": still_there,
        "returned_to_rest": returned,
        "returned_to_rest_t": _round(returned_t),
        "warning_in_restricted": any(s["robot_in_restricted"] for s in spoken),
        "warnings_spoken": spoken,
        "wav_files": list(wavs),
        "trace": {
            "records": len(trace),
            "start_t": _round(times[0]) if times else None,
            "end_t": _round(times[-1]) if times else None,
            "camera_status": dict(sorted(camera.items())),
            "camera_person_frames": camera.get("person", 0),
            "frames_with_legs": sum(1 for rec in trace if rec.get("legs")),
            "speech_utterances": len(spoken),
        },
        "nav_results": dict(sorted(nav.items())),
        "observation_agreement": {
            "robot": agreement([(r.obs_robot, r.true_robot) for r in rows]),
            "person": agreement([(r.obs_person, r.true_person) for r in rows]),
            "velocity": agreement([(r.obs_velocity, r.true_velocity) for r in rows]),
            "direction": agreement(
                [
                    (direction_of(r.obs_velocity), direction_of(r.true_velocity))
                    if UNKNOWN not in (r.obs_velocity, r.true_velocity)
                    else (UNKNOWN, UNKNOWN)
                    for r in rows
                ]
            ),
        },
        "warnings": list(warnings),
    }
    if thesis_table is not None:
        common = min(len(thesis_table.steps), len(rows))
        summary["thesis"] = {
            "table": thesis_table.name,
            "thesis_steps": len(thesis_table.steps),
            "same_action": sum(
                rows[k].action == thesis_table.steps[k].action for k in range(common)
            ),
            "compared": common,
        }
    return summary


def write_report(
    run_dir: str | Path,
    task_path: str | Path,
    thesis_table: Table | None = None,
    *,
    plots: bool = True,
) -> dict:
    """Write steps.md, steps.csv, positions.png, belief.png and summary.json into
    ``run_dir`` from its steps.jsonl and trace.jsonl; return the summary.

    Deterministic: the same inputs give byte-identical steps.md, steps.csv and
    summary.json (and PNGs, with the same matplotlib). Prints nothing.

    Raises:
        RunRecordError: a malformed record (file and line named), or neither
            steps.jsonl nor trace.jsonl exists.
    """
    from stack.planning.model import build_model
    from stack.planning.task import load_task

    run_dir = Path(run_dir)
    task = load_task(task_path)
    model = build_model(task)
    warnings: list[str] = []

    steps_path, trace_path = run_dir / STEPS_FILE, run_dir / TRACE_FILE
    if not steps_path.exists() and not trace_path.exists():
        raise RunRecordError(run_dir, None, f"neither {STEPS_FILE} nor {TRACE_FILE} is here")
    steps: list[dict] = []
    if steps_path.exists():
        steps = read_jsonl(steps_path, ("step", "stamp_s", "action"), warnings)
        for rec in steps:
            _check_step(steps_path, rec, model.n_cells)
            if rec.get("observation") is None:
                why = rec.get("error") or "no observation and no error given"
                warnings.append(f"{STEPS_FILE}:{rec['_line']}: step {rec['step']}: {why}")
        numbers = [rec["step"] for rec in steps]
        if numbers != sorted(set(numbers)):
            warnings.append(f"{STEPS_FILE}: step numbers are not strictly increasing: {numbers}")
    else:
        warnings.append(f"{STEPS_FILE} is missing: no decision steps")
    trace: list[dict] = []
    if trace_path.exists():
        trace = read_jsonl(trace_path, ("t",), warnings)
        for rec in trace:
            _number(trace_path, rec, "t")
        ts = [float(r["t"]) for r in trace]
        if ts != sorted(ts):
            warnings.append(f"{TRACE_FILE}: times are not in order; sorted them")
            trace.sort(key=lambda r: float(r["t"]))
    else:
        warnings.append(f"{TRACE_FILE} is missing: no ground truth or events")
    if steps and trace and float(steps[0]["stamp_s"]) < float(trace[0]["t"]):
        warnings.append(f"step {steps[0]['step']} is stamped before the first trace record")

    rows = step_rows(model, steps, trace)
    wavs = sorted(p.relative_to(run_dir).as_posix() for p in (run_dir / "speech").glob("*.wav"))
    title = f"{run_dir.name} ({task.name})"
    (run_dir / "steps.md").write_text(
        steps_markdown(rows, title, thesis_table, task.discount), encoding="utf-8"
    )
    (run_dir / "steps.csv").write_text(steps_csv(rows), encoding="utf-8")
    files = ["steps.md", "steps.csv"]
    if plots:
        files += _plot(run_dir, model, rows, thesis_table, title)
    summary = summarise(model, rows, trace, wavs, warnings, thesis_table)
    summary["files"] = sorted(files + ["summary.json"])
    (run_dir / "summary.json").write_text(
        json.dumps(summary, indent=2, sort_keys=True) + "\n", encoding="utf-8"
    )
    return summary


# -- the video ---------------------------------------------------------------------------

_WHITE = (255, 255, 255)
_BLACK = (0, 0, 0)
_BELIEF_RGB = np.array((40, 90, 230), float)


class VideoComposer:
    """The run's video, written live: the camera frame beside a top view of the grid.

    Each :meth:`add` writes one output frame (``size`` pixels, fixed): on the left the
    camera frame letterboxed into the panel (a grey "no frame" panel when None) with
    the HOG boxes, the foot point and the camera's status; on the right the grid seen
    from above (north up, east right): cell numbers, restricted cells red, the rest
    cell green, the person belief as blue shading, the robot with its heading and its
    path so far, the true person (green), the camera's person position (magenta ring)
    and the leg tracks (orange crosses). Colours in RGB; frames are RGB uint8.

    Raises:
        RuntimeError: the MP4 writer cannot be opened.
    """

    def __init__(
        self,
        path: str | Path,
        grid: CellGrid,
        restricted: tuple[int, ...],
        room_bounds_m: tuple[float, float, float, float] | None = None,
        fps: float = 10.0,
        *,
        rest_cell: int | None = 7,
        size: tuple[int, int] = (960, 360),
        camera_width: int = 576,
    ):
        import cv2

        self._cv2 = cv2
        self.path = Path(path)
        self.grid = grid
        self.restricted = tuple(restricted)
        self.width, self.height = (int(size[0]) // 2 * 2, int(size[1]) // 2 * 2)
        self.cam_w = int(camera_width)
        self.map_w = self.width - self.cam_w
        if self.map_w < 64:
            raise ValueError(f"size {size} leaves no room for the map beside the camera")
        self.frames = 0
        self._path_px: list[tuple[int, int]] = []
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fourcc = cv2.VideoWriter_fourcc(*"mp4v")
        self._writer = cv2.VideoWriter(
            str(self.path), fourcc, float(fps), (self.width, self.height)
        )
        if not self._writer.isOpened():
            raise RuntimeError(f"cannot open an mp4v video writer for {self.path}")
        self._setup_map(room_bounds_m, rest_cell)
        self._no_frame = np.full((self.height, self.cam_w, 3), 90, np.uint8)
        cv2.putText(
            self._no_frame,
            "no frame",
            (self.cam_w // 2 - 50, self.height // 2),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.7,
            (200, 200, 200),
            2,
            cv2.LINE_AA,
        )

    # -- geometry ----------------------------------------------------------------------
    def _setup_map(self, room: tuple[float, float, float, float] | None, rest: int | None):
        cv2 = self._cv2
        g = self.grid
        gx0, gy0 = g.origin_m
        gw, gh = g.size_m
        x0, y0, x1, y1 = (gx0, gy0, gx0 + gw, gy0 + gh)
        if room is not None:
            x0, y0, x1, y1 = (
                min(x0, room[0]),
                min(y0, room[1]),
                max(x1, room[2]),
                max(y1, room[3]),
            )
        margin, top = 10, 24
        scale = min(
            (self.map_w - 2 * margin) / max(x1 - x0, 1e-6),
            (self.height - top - 2 * margin) / max(y1 - y0, 1e-6),
        )
        self._scale = scale
        used_w, used_h = (x1 - x0) * scale, (y1 - y0) * scale
        self._ox = margin + (self.map_w - 2 * margin - used_w) / 2
        self._oy = top + margin + (self.height - top - 2 * margin - used_h) / 2
        self._x0, self._y1 = x0, y1
        bg = np.full((self.height, self.map_w, 3), 245, np.uint8)
        fg = bg.copy()
        mask = np.zeros((self.height, self.map_w), np.uint8)
        if room is not None:
            cv2.rectangle(bg, self.px(room[0], room[3]), self.px(room[2], room[1]), _WHITE, -1)
        self._cell_px: dict[int, tuple[int, int, int, int]] = {}
        self._cell_colour: dict[int, np.ndarray] = {}
        for cell in g.cells:
            bx0, by0, bx1, by1 = g.bounds(cell)
            u0, v0 = self.px(bx0, by1)
            u1, v1 = self.px(bx1, by0)
            self._cell_px[cell] = (u0, v0, u1, v1)
            colour = _WHITE
            if cell in self.restricted:
                colour = (255, 200, 200)
            elif cell == rest:
                colour = (210, 245, 210)
            self._cell_colour[cell] = np.asarray(colour, float)
            cv2.rectangle(bg, (u0, v0), (u1, v1), colour, -1)
        for cell, (u0, v0, u1, v1) in self._cell_px.items():
            for img, val in ((fg, (120, 120, 120)), (mask, 255)):
                cv2.rectangle(img, (u0, v0), (u1, v1), val, 1)
            edge = (200, 0, 0) if cell in self.restricted else (60, 60, 60)
            for img, val in ((fg, edge), (mask, 255)):
                cv2.putText(
                    img, str(cell), (u0 + 3, v0 + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, val, 1
                )
            if cell in self.restricted:
                for img, val in ((fg, (220, 0, 0)), (mask, 255)):
                    cv2.rectangle(img, (u0 + 1, v0 + 1), (u1 - 1, v1 - 1), val, 2)
        if room is not None:
            for img, val in ((fg, (80, 80, 80)), (mask, 255)):
                cv2.rectangle(img, self.px(room[0], room[3]), self.px(room[2], room[1]), val, 1)
        self._bg = bg
        self._fg_idx = np.nonzero(mask)
        self._fg_val = fg[self._fg_idx]

    def px(self, x: float, y: float) -> tuple[int, int]:
        """Pixel (u, v) in the map panel of map point (x, y) [m]."""
        return (
            int(round(self._ox + (x - self._x0) * self._scale)),
            int(round(self._oy + (self._y1 - y) * self._scale)),
        )

    # -- drawing -----------------------------------------------------------------------
    def _camera_panel(self, frame: np.ndarray | None, camera: Mapping | None) -> np.ndarray:
        cv2 = self._cv2
        if frame is None:
            panel = self._no_frame.copy()
            sx = sy = 1.0
            du = dv = 0
        else:
            frame = np.asarray(frame)
            if frame.dtype != np.uint8:
                frame = np.clip(frame, 0, 255).astype(np.uint8)
            if frame.ndim == 2:
                frame = np.repeat(frame[:, :, None], 3, axis=2)
            frame = frame[:, :, :3]
            fh, fw = frame.shape[:2]
            s = min(self.cam_w / fw, self.height / fh)
            nw, nh = max(1, int(round(fw * s))), max(1, int(round(fh * s)))
            panel = np.zeros((self.height, self.cam_w, 3), np.uint8)
            du, dv = (self.cam_w - nw) // 2, (self.height - nh) // 2
            interp = cv2.INTER_AREA if s < 0.5 else cv2.INTER_LINEAR  # AREA: slow, for big cuts
            panel[dv : dv + nh, du : du + nw] = cv2.resize(frame, (nw, nh), interpolation=interp)
            sx, sy = nw / fw, nh / fh
        status = "camera: -"
        if camera:
            for box in camera.get("boxes") or []:
                x, y, w, h = box[:4]
                p0 = (int(du + x * sx), int(dv + y * sy))
                p1 = (int(du + (x + w) * sx), int(dv + (y + h) * sy))
                cv2.rectangle(panel, p0, p1, (0, 255, 0), 2)
                if len(box) > 4:
                    cv2.putText(
                        panel,
                        f"{box[4]:.2f}",
                        (p0[0], max(p0[1] - 3, 10)),
                        cv2.FONT_HERSHEY_SIMPLEX,
                        0.4,
                        (0, 255, 0),
                        1,
                    )
            foot = camera.get("foot_px")
            if foot is not None:
                cv2.circle(
                    panel, (int(du + foot[0] * sx), int(dv + foot[1] * sy)), 5, (255, 0, 255), -1
                )
            status = f"camera: {camera.get('status', '?')}"
            if camera.get("cell") is not None:
                status += f"  cell {camera['cell']}"
            if camera.get("direction"):
                status += f"  {camera['direction']}"
        cv2.rectangle(panel, (0, 0), (self.cam_w, 20), _BLACK, -1)
        cv2.putText(panel, status, (5, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _WHITE, 1, cv2.LINE_AA)
        return panel

    def _map_panel(
        self,
        t_s: float,
        camera: Mapping | None,
        legs: Sequence,
        robot: Sequence[float] | None,
        person: Sequence[float] | None,
        belief: Mapping | None,
    ) -> np.ndarray:
        cv2 = self._cv2
        img = self._bg.copy()
        if belief:
            for cell, (u0, v0, u1, v1) in self._cell_px.items():
                p = belief.get(str(cell), belief.get(cell))
                if p is None:
                    continue
                a = 0.75 * min(max(float(p), 0.0), 1.0)
                # cells are flat colours: blend the colour, fill (lines come back below)
                c = self._cell_colour[cell] * (1.0 - a) + _BELIEF_RGB * a
                cv2.rectangle(img, (u0, v0), (u1, v1), tuple(int(x) for x in c), -1)
        img[self._fg_idx] = self._fg_val
        if robot is not None:
            u, v = self.px(robot[0], robot[1])
            if (
                not self._path_px
                or abs(self._path_px[-1][0] - u) + abs(self._path_px[-1][1] - v) > 1
            ):
                self._path_px.append((u, v))
        if len(self._path_px) > 1:
            pts = np.asarray(self._path_px, np.int32).reshape(-1, 1, 2)
            cv2.polylines(img, [pts], False, (80, 80, 255), 1, cv2.LINE_AA)
        r_px = max(3, int(0.2 * self._scale))
        for leg in legs or []:
            u, v = self.px(leg[0], leg[1])
            cv2.drawMarker(img, (u, v), (255, 140, 0), cv2.MARKER_TILTED_CROSS, 8, 2)
        if camera and camera.get("position_m") is not None:
            u, v = self.px(*camera["position_m"][:2])
            cv2.circle(img, (u, v), r_px + 3, (220, 0, 220), 2, cv2.LINE_AA)
        if person is not None:
            u, v = self.px(person[0], person[1])
            cv2.circle(img, (u, v), r_px, (0, 170, 0), -1, cv2.LINE_AA)
        if robot is not None:
            u, v = self.px(robot[0], robot[1])
            cv2.circle(img, (u, v), r_px, (0, 0, 200), -1, cv2.LINE_AA)
            if len(robot) > 2 and robot[2] is not None:
                yaw = float(robot[2])
                tip = (int(u + 2 * r_px * math.cos(yaw)), int(v - 2 * r_px * math.sin(yaw)))
                cv2.line(img, (u, v), tip, (0, 0, 120), 2, cv2.LINE_AA)
        text = f"t = {t_s:7.1f} s"
        if belief and NO_PERSON in belief:
            text += f"   P(no person) {float(belief[NO_PERSON]):.2f}"
        cv2.putText(img, text, (8, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _BLACK, 1, cv2.LINE_AA)
        return img

    def render(
        self,
        t_s: float,
        frame_rgb: np.ndarray | None,
        camera: Mapping | None,
        legs: Sequence,
        robot_xy_yaw: Sequence[float] | None,
        person_xy: Sequence[float] | None,
        belief_person: Mapping | None = None,
    ) -> np.ndarray:
        """One output frame (RGB, height x width x 3) without writing it."""
        out = np.empty((self.height, self.width, 3), np.uint8)
        out[:, : self.cam_w] = self._camera_panel(frame_rgb, camera)
        out[:, self.cam_w :] = self._map_panel(
            t_s, camera, legs, robot_xy_yaw, person_xy, belief_person
        )
        return out

    def add(
        self,
        t_s: float,
        frame_rgb: np.ndarray | None,
        camera: Mapping | None,
        legs: Sequence,
        robot_xy_yaw: Sequence[float] | None,
        person_xy: Sequence[float] | None,
        belief_person: Mapping | None = None,
    ) -> None:
        """Compose and write one frame (``belief_person``: {"1": p, ..., "No person": p})."""
        if self._writer is None:
            raise RuntimeError(f"{self.path} is closed")
        img = self.render(t_s, frame_rgb, camera, legs, robot_xy_yaw, person_xy, belief_person)
        self._writer.write(self._cv2.cvtColor(img, self._cv2.COLOR_RGB2BGR))
        self.frames += 1

    def close(self) -> None:
        """Finish the file (safe to call twice)."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def __enter__(self) -> VideoComposer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
