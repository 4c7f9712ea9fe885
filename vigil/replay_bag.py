"""``vigil replay-bag RUN``: re-enact a recorded run's decisions from its bag.

A twin run with lock-step records its bag as a lock-step participant
(:mod:`vigil.node_bag`), so the bag holds every ``/lockstep/tick`` followed by the
messages of that tick, in the order the bag received them. The replay starts the run's
own ``observations`` and ``planner`` nodes (their parameters from the run's
``params.yaml``; the planner's state and step files go to the replay folder), and a
player (:mod:`vigil.node_bag_player`) takes the twin bridge's place as the lock-step
coordinator: per recorded tick it publishes ``/clock``, waits until both nodes have
processed it, ``/lockstep/tick`` (their timers run), waits, then every recorded message
of that tick on a topic the two nodes read and do not write themselves (camera people,
legs, odometry or TF, navigation results...), each followed by a wait until everything
it caused has been processed. What is fed is read from the nodes' own acknowledgements
(the topics they subscribe to), and messages go out as the recorded CDR bytes with the
recorded type, so the replay does not depend on the message types.

The replayed planner writes its ``steps.jsonl``; :func:`compare_steps` sets it beside
the run's, step by step.

This module reads and compares (no rclpy); the node and the processes are started by
:func:`replay_run`.
"""

from __future__ import annotations

import json
import math
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from stack.config import dump_yaml, load_yaml, read_text_capped, write_text
from vigil.bag import BAG_DIR, ReplayError, fresh_path, read_recording
from vigil.bag_salvage import RECOVERED_SUFFIX, closed_cleanly, recovered_path

REPLAYED = ("observations", "planner")  # the nodes re-run from the bag
REPLAY_DIR = "replay"  # inside the run folder (replay_1, ... when taken)
STALL_S = 120.0  # wall seconds without any acknowledgement: the replay gives up
MAX_STEPS_BYTES = 256 * 2**20  # steps.jsonl: a record per decision step, far below this


def find_bag(run_dir: Path) -> Path:
    """The run's bag folder (``bag_recovered`` when ``bag`` was not closed and
    ``vigil bag-reindex`` salvaged it), or :class:`ReplayError` saying what is missing."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ReplayError(f"{run_dir}: no such run folder")
    bag = run_dir / BAG_DIR
    if not bag.is_dir():
        raise ReplayError(
            f"{run_dir} has no bag ({bag} is missing): only runs recorded with the bag node "
            "(vigil run) can be replayed"
        )
    if not closed_cleanly(bag):
        salvaged = recovered_path(bag)
        if closed_cleanly(salvaged):  # what vigil bag-reindex recovered from it
            return salvaged
        raise ReplayError(
            f"{bag} has no metadata.yaml: the bag was not closed (the recorder was killed?); "
            f"salvage its complete messages with `vigil bag-reindex {bag}` (it writes "
            f"{salvaged}, which replay-bag then replays)"
        )
    return bag


# -- the step table --------------------------------------------------------------------
def read_steps(path: Path) -> list[dict]:
    """The planner's step records (JSON lines); a last line being written is dropped."""
    if not path.is_file():
        return []
    out = []
    try:
        lines = read_text_capped(path, MAX_STEPS_BYTES).splitlines()
    except ValueError as err:
        raise ReplayError(str(err)) from None
    last = max((n for n, line in enumerate(lines, 1) if line.strip()), default=0)
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except ValueError as err:
            if n == last:  # cut off mid-write (the run was killed): the steps before it
                break
            raise ReplayError(f"{path} line {n}: not JSON ({err})") from err
        if not isinstance(rec, dict):
            raise ReplayError(f"{path} line {n}: not a step record")
        out.append(rec)
    return out


def _labels(rec: dict) -> str:
    o = rec.get("observation") or {}
    if o.get("people"):
        people = "; ".join(f"{p.get('person')}, {p.get('velocity')}" for p in o["people"])
        return f"robot {o.get('robot', '-')}, people {people}"
    return f"robot {o.get('robot', '-')}, person {o.get('person', '-')}, {o.get('velocity', '-')}"


def _close(a: Any, b: Any, tol: float = 1e-9) -> bool:
    """Equal, numbers within ``tol`` (nested dicts and lists compared item by item)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, tol) for x, y in zip(a, b, strict=True))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=tol, abs_tol=tol)
    return a == b


def step_difference(recorded: dict | None, replayed: dict | None) -> str:
    """What differs between two step records ("" when they match)."""
    if recorded is None:
        return "not in the run"
    if replayed is None:
        return "not replayed"
    out = []
    for key in ("stamp_s", "action", "observation", "belief"):
        if not _close(recorded.get(key), replayed.get(key)):
            out.append("time" if key == "stamp_s" else key)
    return ", ".join(out)


@dataclass
class Comparison:
    rows: list[tuple[int, dict | None, dict | None, str]]  # step, recorded, replayed, diff

    @property
    def matches(self) -> bool:
        return bool(self.rows) and all(diff == "" for *_, diff in self.rows)

    @property
    def mismatched(self) -> int:
        return sum(diff != "" for *_, diff in self.rows)


def compare_steps(recorded: list[dict], replayed: list[dict]) -> Comparison:
    """The two step tables side by side, step by step."""
    n = max(len(recorded), len(replayed))
    rows = []
    for i in range(n):
        a = recorded[i] if i < len(recorded) else None
        b = replayed[i] if i < len(replayed) else None
        rows.append((i + 1, a, b, step_difference(a, b)))
    return Comparison(rows)


def comparison_markdown(cmp: Comparison) -> str:
    """The side-by-side step table (Markdown)."""

    def cells(rec: dict | None) -> list[str]:
        if rec is None:
            return ["-", "-", "-"]
        return [f"{float(rec.get('stamp_s', 0.0)):.2f}", str(rec.get("action")), _labels(rec)]

    lines = [
        "| step | run t (s) | run action | run observation "
        "| replay t (s) | replay action | replay observation | |",
        "|---:|---:|---|---|---:|---|---|---|",
    ]
    for step, a, b, diff in cmp.rows:
        mark = "match" if not diff else f"**mismatch** ({diff})"
        lines.append("| " + " | ".join([str(step), *cells(a), *cells(b), mark]) + " |")
    verdict = (
        f"all {len(cmp.rows)} steps match"
        if cmp.matches
        else f"{cmp.mismatched} of {len(cmp.rows)} steps differ"
    )
    return "\n".join(lines) + f"\n\n{verdict}\n"


def restart_note(recorded: list[dict]) -> str:
    """Why the replay may differ from the run: its planner was restarted ("" if not)."""
    first = next((r for r in recorded if r.get("resumed")), None)
    if first is None:
        return ""
    return (
        f"the run's planner was restarted and resumed at step {first.get('step')}; the "
        "replay runs it straight through (its timers keep their first phase), so steps "
        "from there may differ"
    )


# -- the nodes' parameters ---------------------------------------------------------------
def replay_params(run_dir: Path, out_dir: Path) -> dict[str, dict[str, Any]]:
    """The replayed nodes' parameters: the run's, with lock-step on, the planner's files
    in ``out_dir``, and paths into the run folder moved with it (a copied run replays).

    Raises:
        ReplayError: no ``params.yaml``, or it lacks a replayed node.
    """
    path = run_dir / "params.yaml"
    if not path.is_file():
        raise ReplayError(f"{run_dir} has no params.yaml (the nodes' parameters of the run)")
    try:
        doc = load_yaml(read_text_capped(path)) or {}
    except (ValueError, yaml.YAMLError) as err:
        raise ReplayError(f"{path}: not YAML ({err})") from err
    out: dict[str, dict[str, Any]] = {}
    for name in REPLAYED:
        section = doc.get(name) if isinstance(doc, dict) else None
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ReplayError(f"{path} has no parameters for the {name} node")
        out[name] = dict(params)
    old = str(Path(out["planner"].get("steps_file") or run_dir / "steps.jsonl").parent)
    new = str(run_dir.resolve())
    for params in out.values():
        for key, value in params.items():
            if isinstance(value, str) and old != new and value.startswith(old + os.sep):
                params[key] = new + value[len(old) :]
        params["lockstep"] = True
    out["planner"]["state_file"] = str(out_dir / "planner_state.json")
    out["planner"]["steps_file"] = str(out_dir / "steps.jsonl")
    return out


# -- the whole replay --------------------------------------------------------------------
@dataclass
class ReplayResult:
    out_dir: Path
    comparison: Comparison
    fed: dict[str, int]  # topic -> messages published into the nodes
    wall_s: float
    note: str = ""  # why steps may differ (a restarted planner), or ""


def replay_run(
    run_dir: str | Path,
    out: str | Path | None = None,
    say: Callable[[str], None] = print,
    stall_s: float = STALL_S,
) -> ReplayResult:
    """Replay ``run_dir``'s bag into its observations and planner nodes; compare steps.

    Raises:
        ReplayError: no run folder, bag, parameters or step records; a node died; the
            replay stalled.
    """
    from stack.lockstep import RUN_ID_ENV
    from vigil.dds import dds_env, write_profile
    from vigil.launch import Launcher
    from vigil.processes import ProcessSpec
    from vigil.ros_domain import claim_domain
    from vigil.system import MODULES

    run_dir = Path(run_dir).resolve()
    bag = find_bag(run_dir)
    recorded = read_steps(run_dir / "steps.jsonl")
    if not recorded:
        raise ReplayError(f"{run_dir} has no step records (steps.jsonl): nothing to compare")
    note = restart_note(recorded)
    if bag.name.endswith(RECOVERED_SUFFIX):
        salvaged = (
            f"the bag is {bag.name}, salvaged from a bag that was not closed: "
            "steps after its last message cannot be replayed"
        )
        note = f"{note}; {salvaged}" if note else salvaged
    if note:
        say(f"[replay-bag] note: {note}")
    t0 = time.monotonic()
    recording = read_recording(bag)
    n_msgs = sum(len(t.messages) for t in recording.ticks)
    say(
        f"[replay-bag] {bag}: {len(recording.ticks)} ticks "
        f"({recording.ticks[0].t_ns / 1e9:.2f}-{recording.ticks[-1].t_ns / 1e9:.2f} s), "
        f"{n_msgs} messages, {len(recorded)} recorded steps"
    )
    out_dir = fresh_path(run_dir, REPLAY_DIR) if out is None else Path(out).resolve()
    if out_dir.exists() and any(out_dir.iterdir()):
        raise ReplayError(f"{out_dir} exists and is not empty: not writing into it")
    params = replay_params(run_dir, out_dir)  # checks the run before anything is written
    out_dir.mkdir(parents=True, exist_ok=True)
    params_file = out_dir / "params.yaml"
    write_text(
        params_file,
        dump_yaml({n: {"ros__parameters": p} for n, p in params.items()}, sort_keys=True),
    )
    run_id = "replay-" + uuid.uuid4().hex[:8]
    claim = claim_domain()
    try:
        env = dds_env(write_profile(out_dir), True)
        env.update({RUN_ID_ENV: run_id, "ROS_DOMAIN_ID": str(claim.domain_id)})
        env.update(PYTHONUNBUFFERED="1", RCUTILS_COLORIZED_OUTPUT="0")
        say(f"[replay-bag] folder {out_dir}, ROS domain {claim.domain_id}")
        specs = [ProcessSpec(n, MODULES[n], params_file, restart=False) for n in REPLAYED]
        launcher = Launcher(specs, out_dir / "logs", env, max_restarts=0, say=say)
    except BaseException:
        claim.release()  # (the finally below owns it once the launcher exists)
        raise
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # this process's DDS participant joins the same domain
    try:
        from vigil.node_bag_player import play

        launcher.start()
        fed = play(
            recording,
            expected=REPLAYED,
            run_id=run_id,
            domain_id=claim.domain_id,
            steps=len(recorded),
            alive=launcher.poll,
            stall_s=stall_s,
            say=say,
        )
    except ReplayError as err:
        launcher.poll()
        if launcher.failures:
            raise ReplayError(f"{err}: {'; '.join(launcher.failures)}") from err
        raise
    finally:
        launcher.stop(5.0)
        claim.release()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    if launcher.failures:
        raise ReplayError("a replayed node failed: " + "; ".join(launcher.failures))
    cmp = compare_steps(recorded, read_steps(out_dir / "steps.jsonl"))
    write_text(
        out_dir / "replay.md",
        f"# Replay of {run_dir.name} from its bag\n\n"
        + (f"Note: {note}\n\n" if note else "")
        + comparison_markdown(cmp),
    )
    return ReplayResult(out_dir, cmp, fed, time.monotonic() - t0, note)
