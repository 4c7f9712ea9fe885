"""Reading a run folder's records: the planner's steps, the recorder's trace, the
speech log. Everything here checks its input and names the file and line it rejects.

Inputs in the run folder (formats fixed by ``vigil run``):

- ``steps.jsonl``, one object per decision step (the planner node)::

      {"step": 1, "stamp_s": 12.34, "action": "East",
       "observation": {"robot": "7", "person": "9" | "No person" | "Unseen",
                       "velocity": "East higher",
                       "source": "camera" | "laser" | "fused" | "none",   (optional)
                       "hidden": {"3": 0.4, ...} | [[3, 0.4], ...]}      (optional)
                      | null,
       "belief": {"robot": {...}, "person": {"1": p, ..., "No person": p},
                  "direction": {...}} | null,
       "values": [q, ...], "nav": {...} | null, "resumed": false, "error": "..."?}

  Step n's action was chosen from the belief before; the robot executed it; the
  observation was read at sim time ``stamp_s``; ``belief`` is the belief after it.
  Keys not named here (``trigger``, ...) are kept and never rejected.
- ``trace.jsonl``, one object per recorded instant (the recorder node, ~10 Hz)::

      {"t": 1.2, "robot": [x, y, yaw] | null, "robot_cell": 7 | null,
       "person": [x, y] | null, "person_cell": 9 | null, "person_velocity": [vx, vy] | null,
       "odom": [x, y, yaw] | null, "camera": {...} | null, "legs": [[x, y], ...],
       "speech": "text" | ["text", ...] | null}

  ``robot`` null means no ground truth (hardware mode). ``speech``: the warnings the
  speech node decided since the previous record (a string in older runs).
- ``speech/speech_log.tsv``: one line per utterance started (``time_s``, ``voice``,
  ``duration_s``, ``wav``, ``text``; time on the run's clock, simulated in the twin).

Times: every stamp above is on the run's clock. In lock-step (and in-process) runs that
is the twin's simulated time, which starts at 0 with the run. In real time (``vigil run
--realtime``) and on the robot it is the ROS system clock, epoch seconds: the bridge
stamps the system time of the run's start plus the simulated time. :func:`load_run`
gives the report run-relative times in both: when the earliest stamp is epoch-scaled
(at least :data:`WALL_CLOCK_FROM_S`) it subtracts it from every time it returns
(:func:`time_origin`, :func:`rebase`); simulated stamps are returned as they are. The
files themselves are never changed.

Malformed records: a line that is not a JSON object, lacks a required key or holds
an unknown label raises :class:`RunRecordError` (a ValueError) naming the file and the
line number. The one exception is a *last* line without its newline (a node killed in
the middle of a write): it is skipped and a warning is returned.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from stack.files import MAX_RECORD_BYTES, read_text_capped
from stack.vocabulary import ACTIONS, NO_PERSON, OUT_OF_MAP, VELOCITIES
from twin.realtime import REALTIME_FILE

NOT_MOVING = "Not moving"
UNSEEN = "Unseen"  # the camera could not look: not "No person"
UNKNOWN = "-"
STEPS_FILE = "steps.jsonl"
TRACE_FILE = "trace.jsonl"
SPEECH_LOG = "speech/speech_log.tsv"
NOT_MOVING_BELOW_MPS = 0.05  # a true speed below this is "Not moving"
SPEED_THRESHOLDS_MPS = (0.2, 0.7)  # thesis 4.5: 0-0.2, 0.2-0.7, higher
# a run whose earliest stamp is at least this [s] is on the system clock (epoch seconds,
# 1973 on): no simulated run lasts three years, and a simulated clock starts at 0
WALL_CLOCK_FROM_S = 1e8


class RunRecordError(ValueError):
    """A run record is malformed; the message names the file and the line number."""

    def __init__(self, path: str | Path, line: int | None, reason: str):
        self.path, self.line, self.reason = str(path), line, reason
        where = self.path if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {reason}")


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
    text = read_text_capped(path, MAX_RECORD_BYTES)  # a regular file, bounded
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


def number(path: Path, rec: dict, key: str) -> float:
    """``rec[key]`` as a finite float, or :class:`RunRecordError`."""
    v = rec.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise RunRecordError(path, rec.get("_line"), f"{key!r} must be a finite number, got {v!r}")
    return float(v)


def person_labels(n_cells: int) -> set[str]:
    """Every person label a step may carry: a cell, "No person", "Unseen"."""
    return {str(c) for c in range(1, n_cells + 1)} | {NO_PERSON, UNSEEN}


def check_step(path: Path, rec: dict, n_cells: int) -> None:
    """Reject a step record with a bad step number, stamp, action or label.

    Extra keys (in the record or its observation) are accepted as they are.
    """
    line = rec.get("_line")
    step = rec.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or step < 1:
        raise RunRecordError(path, line, f"'step' must be an integer >= 1, got {step!r}")
    number(path, rec, "stamp_s")
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
        ("person", person_labels(n_cells)),
        ("velocity", set(VELOCITIES)),
    )
    for key, allowed in checks:
        if obs.get(key) not in allowed:
            raise RunRecordError(path, line, f"observation {key} {obs.get(key)!r} is not a label")


def hidden_cells(value: Any) -> dict[int, float]:
    """An observation's ``hidden`` field as {cell: fraction}; anything unreadable -> {}.

    Accepts {"3": 0.4} and [[3, 0.4], ...] (and a bare list of cells: fraction 1).
    """
    out: dict[int, float] = {}
    try:
        if isinstance(value, dict):
            items = value.items()
        elif isinstance(value, list | tuple):
            items = [(v, 1.0) if not isinstance(v, list | tuple) else v[:2] for v in value]
        else:
            return {}
        for c, f in items:
            out[int(c)] = float(f)
    except (TypeError, ValueError):
        return {}
    return dict(sorted(out.items()))


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


def cell_of_label(label: str) -> int | None:
    """A cell label's number; None for "No person", "Unseen", "Out of the map"."""
    return int(label) if label.isdigit() else None


# -- the speech log ----------------------------------------------------------------------


@dataclass(frozen=True)
class Utterance:
    """One utterance the speech node started: at ``t`` [s] for ``duration_s``."""

    t: float
    duration_s: float | None
    text: str
    wav: str = ""
    frame_stamp_s: float | None = None  # the camera frame that caused it (a warning)


def read_speech_log(path: str | Path, warnings: list[str] | None = None) -> list[Utterance]:
    """The utterances of ``speech_log.tsv`` (header ``time_s voice duration_s wav
    frame_stamp_s text``; logs without ``frame_stamp_s`` are read too).

    Raises:
        RunRecordError: a line without five tab-separated fields or with a time that is
            not a number (a truncated last line is skipped with a warning instead when
            ``warnings`` is given).
    """
    path = Path(path)
    text = read_text_capped(path, MAX_RECORD_BYTES)
    lines = text.split("\n")
    out: list[Utterance] = []
    # the text is the last column (it may hold tabs); the frame stamp's column is newer
    framed = lines[0].split("\t")[4:5] == ["frame_stamp_s"]
    fields = 6 if framed else 5
    for i, line in enumerate(lines, start=1):
        if not line.strip() or (i == 1 and line.startswith("time_s")):
            continue
        parts = line.split("\t")
        frame: float | None = None
        try:
            if len(parts) < fields:
                raise ValueError(f"expected {fields} tab-separated fields, got {len(parts)}")
            t = float(parts[0])
            if not math.isfinite(t):
                raise ValueError(f"time {parts[0]!r} is not finite")
            dur = float(parts[2]) if parts[2] not in ("", "nan") else None
            if framed and parts[4]:
                frame = float(parts[4])
                if not math.isfinite(frame):
                    raise ValueError(f"frame stamp {parts[4]!r} is not finite")
        except ValueError as e:
            if i == len(lines) and not text.endswith("\n") and warnings is not None:
                warnings.append(f"{path.name}:{i}: skipped a truncated last line")
                continue
            raise RunRecordError(path, i, str(e)) from e
        out.append(Utterance(t, dur, "\t".join(parts[fields - 1 :]), parts[3], frame))
    return out


def trace_speech(rec: dict) -> list[str]:
    """The warnings a trace record holds (a string in older runs, a list now)."""
    s = rec.get("speech")
    if not s:
        return []
    if isinstance(s, str):
        return [s]
    if isinstance(s, list):
        return [str(x) for x in s if x]
    return [str(s)]


# -- the whole folder --------------------------------------------------------------------


@dataclass
class RunRecords:
    """What the nodes recorded, checked: steps, trace (sorted by t), utterances.

    ``speech_source`` says where ``utterances`` came from: "speech log" (what was
    spoken), "trace" (what the speech node decided, older runs) or "none".
    """

    steps: list[dict]
    trace: list[dict]
    utterances: list[Utterance]
    speech_source: str
    warnings: list[str]
    # the run's clock at its start [s], subtracted from every time above: 0.0 for a
    # simulated clock, the earliest stamp for the system clock (:func:`time_origin`)
    origin_s: float = 0.0


def time_origin(
    steps: Sequence[dict], trace: Sequence[dict], utterances: Sequence[Utterance]
) -> float:
    """The run's start on its clock [s]: what the report subtracts from every time.

    0.0 for a simulated clock (lock-step, in-process: the twin's time starts at 0 with
    the run, so its stamps are run-relative already and stay exactly as recorded). For
    the system clock (real time, hardware: epoch seconds, told apart by an earliest
    stamp of at least :data:`WALL_CLOCK_FROM_S`) the earliest stamp of the steps, the
    trace and the utterances: in real time the twin's first ground truth, one control
    period after the bridge started its clock.
    """
    firsts = [float(r["stamp_s"]) for r in steps] + [float(r["t"]) for r in trace]
    firsts += [u.t for u in utterances]
    start = min(firsts, default=0.0)
    return start if start >= WALL_CLOCK_FROM_S else 0.0


def since(t: float, origin_s: float) -> float:
    """``t`` as seconds since ``origin_s`` (microseconds, as the records are stamped)."""
    return round(t - origin_s, 6) + 0.0


def rebase(records: RunRecords, origin_s: float) -> None:
    """Make every time in ``records`` relative to ``origin_s`` (in place; 0.0: nothing
    changes): the steps' ``stamp_s`` and observation ``frame_stamp_s``, the trace's
    ``t``, the utterances' ``t`` and ``frame_stamp_s``. Differences between times keep."""
    records.origin_s = origin_s
    if origin_s == 0.0:
        return
    for rec in records.steps:
        rec["stamp_s"] = since(float(rec["stamp_s"]), origin_s)
        obs = rec.get("observation")
        if isinstance(obs, dict) and isinstance(obs.get("frame_stamp_s"), int | float):
            obs["frame_stamp_s"] = since(float(obs["frame_stamp_s"]), origin_s)
    for rec in records.trace:
        rec["t"] = since(float(rec["t"]), origin_s)
    records.utterances = [
        replace(
            u,
            t=since(u.t, origin_s),
            frame_stamp_s=None if u.frame_stamp_s is None else since(u.frame_stamp_s, origin_s),
        )
        for u in records.utterances
    ]


def read_realtime(run_dir: str | Path, warnings: list[str]) -> dict | None:
    """The real-time twin's stats (:data:`twin.realtime.REALTIME_FILE`, written by the
    bridge), or None for a lock-step run; a malformed file is a warning, not an error."""
    path = Path(run_dir) / REALTIME_FILE
    if not path.exists():
        return None
    try:
        data = json.loads(read_text_capped(path, 1 << 20))
    except (OSError, ValueError) as err:
        warnings.append(f"{REALTIME_FILE}: unreadable: {err}")
        return None
    if not isinstance(data, dict) or not isinstance(data.get("factor"), int | float):
        warnings.append(f"{REALTIME_FILE}: not the real-time stats (no factor)")
        return None
    return data


def load_run(run_dir: str | Path, n_cells: int) -> RunRecords:
    """Read and check ``steps.jsonl``, ``trace.jsonl`` and the speech log; every time
    in what it returns is seconds since the run's start (:func:`time_origin`, which
    ``origin_s`` holds; the module's docstring).

    Raises:
        RunRecordError: a malformed record, or neither steps.jsonl nor trace.jsonl.
    """
    run_dir = Path(run_dir)
    warnings: list[str] = []
    steps_path, trace_path = run_dir / STEPS_FILE, run_dir / TRACE_FILE
    if not steps_path.exists() and not trace_path.exists():
        raise RunRecordError(run_dir, None, f"neither {STEPS_FILE} nor {TRACE_FILE} is here")
    steps: list[dict] = []
    if steps_path.exists():
        steps = read_jsonl(steps_path, ("step", "stamp_s", "action"), warnings)
        for rec in steps:
            check_step(steps_path, rec, n_cells)
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
            number(trace_path, rec, "t")
        ts = [float(r["t"]) for r in trace]
        if ts != sorted(ts):
            warnings.append(f"{TRACE_FILE}: times are not in order; sorted them")
            trace.sort(key=lambda r: float(r["t"]))
    else:
        warnings.append(f"{TRACE_FILE} is missing: no ground truth or events")
    if steps and trace and float(steps[0]["stamp_s"]) < float(trace[0]["t"]):
        warnings.append(f"step {steps[0]['step']} is stamped before the first trace record")
    log = run_dir / SPEECH_LOG
    if log.exists():
        utterances, source = read_speech_log(log, warnings), "speech log"
    else:
        utterances = [
            Utterance(float(r["t"]), None, text) for r in trace for text in trace_speech(r)
        ]
        source = "trace" if utterances else "none"
    records = RunRecords(steps, trace, utterances, source, warnings)
    rebase(records, time_origin(steps, trace, utterances))
    return records
