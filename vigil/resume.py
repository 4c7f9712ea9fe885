"""Whether a new ``vigil launch`` resumes the planner from an earlier launch's state
(issue 23): only when asked, only for the same deployment, task and policy, and only
when the state is young enough; :func:`resume_decision` says so in one line."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

STATE_FILE = "planner_state.json"  # the planner's belief and step (vigil.system)
IDENTITY_FILE = "launch.json"  # what a launch's planner state belongs to
DEFAULT_RESUME_MAX_AGE_S = 600.0  # --resume-max-age-s: a restart after a crash, not yesterday


MAX_HASHED_BYTES = 1 << 30  # a policy file is at most this (stack.planning.policy)


def _digest(path: str | Path | None) -> str:
    """sha256 of a file's bytes ("" for no file); read in chunks, any size."""
    if not path:
        return ""
    from stack.config import open_regular

    h = hashlib.sha256()
    with open_regular(path, MAX_HASHED_BYTES) as f:  # never /dev/zero, never a pipe
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def planner_identity(deployment: Path | None, planner: dict) -> dict[str, str]:
    """What a planner state belongs to: the deployment, task and policy files' contents
    (sha256; the policy "" for the online planner)."""
    return {
        "deployment": _digest(deployment),
        "task": _digest(planner.get("task_file")),
        "policy": _digest(planner.get("policy_file")),
    }


def previous_state(out: Path) -> Path | None:
    """The newest planner state among earlier launches into ``out`` (``out``, ``out-2``,
    ...: the folders :func:`vigil.run_folder.fresh_run_dir` numbers), None if there is none.
    Only folders vigil made (holding its run mark) count."""
    from vigil.run_folder import MAX_NUMBERED, RUN_MARK

    family = [out] + [out.with_name(f"{out.name}-{n}") for n in range(2, MAX_NUMBERED)]
    found: list[tuple[float, Path]] = []
    for folder in family:
        state = folder / STATE_FILE
        try:
            if (folder / RUN_MARK).is_file() and state.is_file():
                found.append((state.stat().st_mtime, state))
        except OSError:
            continue
    return max(found)[1] if found else None


def _age(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def resume_decision(
    state: Path | None,
    identity: dict[str, str],
    resume: bool,
    max_age_s: float,
    now_s: float,
) -> tuple[Path | None, str]:
    """Whether the planner resumes from an earlier launch's ``state``, and the one line
    that says so.

    It resumes only when asked (``resume``), only when the state's launch recorded the
    same deployment, task and policy (:data:`IDENTITY_FILE` beside it), and only when
    the state was written less than ``max_age_s`` ago. The age is on the wall clock
    (the file's modification time: the only clock that survives a restart); a state
    written in the future (a clock set back) is not resumed.

    Args:
        state: the earlier state file (:func:`previous_state`), None if none.
        identity: this launch's :func:`planner_identity`.
        resume: ``--resume`` was given.
        max_age_s: ``--resume-max-age-s``.
        now_s: the wall-clock time [s since the epoch].

    Returns:
        (the state file to resume from, or None; the line to show).
    """
    from stack.config import read_text_capped

    if not resume:
        if state is None:
            return None, "planner: initial belief"
        return None, f"planner: initial belief ({state} is not resumed without --resume)"
    if state is None:
        return None, "planner: initial belief (--resume: no earlier planner state found)"
    no = f"planner: initial belief, not resuming {state}"
    try:
        recorded = json.loads(read_text_capped(state.parent / IDENTITY_FILE))
        saved = json.loads(read_text_capped(state))
        age_s = now_s - state.stat().st_mtime
    except (OSError, ValueError) as err:
        return None, f"{no}: its launch is unreadable or records nothing ({err})"
    if not isinstance(recorded, dict) or not isinstance(saved, dict):
        return None, f"{no}: not a JSON object"
    differ = [k for k in ("task", "policy", "deployment") if recorded.get(k) != identity[k]]
    if differ:
        return None, f"{no}: another {', '.join(differ)} than this launch's"
    if age_s < 0:
        return None, f"{no}: written {_age(-age_s)} in the future (a clock set back?)"
    if age_s > max_age_s:
        return None, (f"{no}: {_age(age_s)} old, older than --resume-max-age-s {max_age_s:g}")
    step = saved.get("step")
    return state, f"planner: resuming from {state} (step {step}, {_age(age_s)} old)"
