"""The one place where vigil's domain records and ROS messages are converted (issue 14).

Every typed topic of the stack (``vigil_interfaces`` and the standard messages used in
their place) is written with a ``*_to_msg`` function here and read with a
``*_from_msg`` one, so that a field is named, defaulted and range-checked once. The
domain side is what the pure cores already speak: plain dicts of the JSON records the
nodes used to send (:meth:`stack.perception.observation.Observation.to_dict`, the
navigation executor's result, the planner's step record...), or the cores' own types.
Readers return those same dicts, so the cores did not change; readers raise
:class:`ValueError` naming the field when a message is malformed (a typed message can
still carry NaN, a negative cell or a wrong label), and nodes log and skip it.

No rclpy here (messages are plain classes; tests build them without a ROS graph), and
the cores under ``stack/planning``, ``stack/perception`` and ``stack/nav`` never import
this module or a message package: only node files do.

It is over 500 lines because it is deliberately the one codec for every typed topic
(about twenty functions in writer/reader pairs): split, the pairs would drift apart.

"Absent" in a message: a cell of -1, an empty string, a NaN number or a ``has_*`` flag
of false; readers turn those back into ``None``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose2D, Vector3
from vigil_interfaces.action import NavigateToPose
from vigil_interfaces.msg import (
    Belief,
    BeliefVariable,
    CameraPerson,
    Decision,
    LegTrack,
    LegTracks,
    LockstepAck,
    NavGoal,
    NavProgress,
    NavResult,
    PersonObservation,
    PlannerDone,
    SpeechDone,
    TwinTruth,
    Warning,
)

from stack.lockstep import stamp_parts

NONE_CELL = -1
_INT32_MAX = 2**31 - 1


# -- small parts ---------------------------------------------------------------------------
def stamp(t_s: float) -> Time:
    """builtin_interfaces/Time of ``t_s`` seconds, rounded to the nanosecond first (so
    2.9999999999 s is 3 s, not 2 s with the nanoseconds wrapped to 0)."""
    if not math.isfinite(t_s) or t_s < 0:
        t_s = 0.0
    sec, nanosec = stamp_parts(t_s)
    return Time(sec=sec, nanosec=nanosec)


def stamp_s(t: Any) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(t.sec) + 1e-9 * float(t.nanosec)


def _header(msg: Any, t_s: float, frame_id: str = "") -> Any:
    msg.header.stamp = stamp(t_s)
    msg.header.frame_id = frame_id
    return msg


def _cell_out(cell: Any) -> int:
    """A cell number or None -> int32 (-1 for None)."""
    if cell is None:
        return NONE_CELL
    c = int(cell)
    return c if 0 <= c <= _INT32_MAX else NONE_CELL


def _cell_in(value: Any, what: str) -> int | None:
    c = int(value)
    if c == NONE_CELL:
        return None
    if c < 0:
        raise ValueError(f"{what} {c} is not a cell (-1: none)")
    return c


def _finite(value: Any, what: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{what} is not finite: {v}")
    return v


def _nan_none(value: Any) -> float | None:
    v = float(value)
    return None if math.isnan(v) else v


def _none_nan(value: Any) -> float:
    return math.nan if value is None else float(value)


def _point(xy: Sequence[float] | None) -> Point:
    if xy is None:
        return Point()
    return Point(x=float(xy[0]), y=float(xy[1]), z=0.0)


def _xy(p: Any, what: str) -> list[float]:
    return [_finite(p.x, f"{what}.x"), _finite(p.y, f"{what}.y")]


def _str(value: Any) -> str:
    return "" if value is None else str(value)


def _opt_str(value: str) -> str | None:
    return value or None


# -- observations (/observations) ----------------------------------------------------------
def observation_to_msg(d: Mapping[str, Any], frame_id: str = "map") -> PersonObservation:
    """The observations node's record (:meth:`Observation.to_dict`, plus ``people``:
    one {person, velocity} per slot with several people) -> PersonObservation."""
    msg = _header(PersonObservation(), float(d.get("stamp_s") or 0.0), frame_id)
    msg.robot, msg.person, msg.velocity = str(d["robot"]), str(d["person"]), str(d["velocity"])
    pos = d.get("person_position_m")
    msg.has_person_position = pos is not None
    msg.person_position = _point(pos)
    msg.speed_mps = _none_nan(d.get("speed_mps"))
    msg.source = _str(d.get("source"))
    frame = d.get("frame_stamp_s")
    if frame is not None:
        msg.frame_stamp = stamp(float(frame))
    hidden = d.get("hidden") or {}
    msg.hidden_cells = [int(c) for c in hidden]
    msg.hidden_fractions = [float(f) for f in hidden.values()]
    people = d.get("people") or ()
    msg.people_person = [str(p["person"]) for p in people]
    msg.people_velocity = [str(p["velocity"]) for p in people]
    if any("position_m" in p for p in people):
        msg.people_has_position = [p.get("position_m") is not None for p in people]
        msg.people_position = [_point(p.get("position_m")) for p in people]
    return msg


def observation_from_msg(msg: Any) -> dict[str, Any]:
    """PersonObservation -> the record :meth:`Observation.to_dict` gives (the planner's
    :meth:`Observed.from_dict` reads it).

    Raises:
        ValueError: hidden cells and fractions, or slot labels, of different lengths.
    """
    if len(msg.hidden_cells) != len(msg.hidden_fractions):
        raise ValueError(
            f"observation has {len(msg.hidden_cells)} hidden cells but "
            f"{len(msg.hidden_fractions)} fractions"
        )
    if len(msg.people_person) != len(msg.people_velocity):
        raise ValueError(
            f"observation has {len(msg.people_person)} people labels but "
            f"{len(msg.people_velocity)} velocities"
        )
    out: dict[str, Any] = {
        "stamp_s": round(stamp_s(msg.header.stamp), 9),
        "robot": str(msg.robot),
        "person": str(msg.person),
        "velocity": str(msg.velocity),
        "person_position_m": (
            _xy(msg.person_position, "person_position") if msg.has_person_position else None
        ),
        "speed_mps": _nan_none(msg.speed_mps),
        "source": str(msg.source),
        "frame_stamp_s": (
            round(stamp_s(msg.frame_stamp), 9)
            if msg.frame_stamp.sec or msg.frame_stamp.nanosec
            else None
        ),
        # float32 on the wire: the sender rounded to 3 decimals, so this is its value
        "hidden": {
            str(int(c)): round(float(f), 3)
            for c, f in zip(msg.hidden_cells, msg.hidden_fractions, strict=True)
        },
    }
    if msg.people_person:
        out["people"] = [
            {"person": str(p), "velocity": str(v)}
            for p, v in zip(msg.people_person, msg.people_velocity, strict=True)
        ]
        if len(msg.people_has_position):
            if not len(msg.people_has_position) == len(msg.people_position) == len(out["people"]):
                raise ValueError(
                    f"observation has {len(out['people'])} people but "
                    f"{len(msg.people_has_position)} position flags and "
                    f"{len(msg.people_position)} positions"
                )
            flags, points = msg.people_has_position, msg.people_position
            for slot, has, q in zip(out["people"], flags, points, strict=True):
                slot["position_m"] = _xy(q, "people_position") if has else None
    return out


# -- the camera's person (/perception/person) ----------------------------------------------
def camera_to_msg(d: Mapping[str, Any], frame_id: str = "map") -> CameraPerson:
    """A camera record (:meth:`CameraPersonState.to_dict` or ``silent_dict``, with
    ``people_m`` for several people) -> CameraPerson."""
    msg = _header(CameraPerson(), float(d.get("stamp_s") or 0.0), frame_id)
    msg.status = str(d["status"])
    pos = d.get("position_m")
    msg.has_position = pos is not None
    msg.position = _point(pos)
    msg.cell = _cell_out(d.get("cell"))
    msg.direction = str(d.get("direction") or "Not moving")
    foot = d.get("foot_px")
    msg.has_foot_px = foot is not None
    if foot is not None:
        msg.foot_u_px, msg.foot_v_px = float(foot[0]), float(foot[1])
    msg.boxes = [float(v) for box in d.get("boxes") or () for v in box]
    msg.missed_frames = max(0, int(d.get("missed_frames") or 0))
    msg.warning = _str(d.get("warning"))
    msg.people = [_point(q) for q in d.get("people_m") or ()]
    return msg


def camera_from_msg(msg: Any) -> dict[str, Any]:
    """CameraPerson -> the camera record (:meth:`CameraPersonState.to_dict` keys, and
    ``people_m``).

    Raises:
        ValueError: boxes not in fives, a non-finite position, a bad cell.
    """
    if len(msg.boxes) % 5:
        raise ValueError(f"camera boxes must come in fives (x, y, w, h, weight): {len(msg.boxes)}")
    b = [float(v) for v in msg.boxes]
    boxes = [[*(int(v) if v.is_integer() else v for v in b[i : i + 4]), b[i + 4]]
             for i in range(0, len(b), 5)]  # fmt: skip
    return {
        "stamp_s": stamp_s(msg.header.stamp),
        "status": str(msg.status),
        "position_m": _xy(msg.position, "position") if msg.has_position else None,
        "cell": _cell_in(msg.cell, "camera cell"),
        "direction": str(msg.direction),
        "foot_px": [float(msg.foot_u_px), float(msg.foot_v_px)] if msg.has_foot_px else None,
        "boxes": boxes,
        "missed_frames": int(msg.missed_frames),
        "warning": _opt_str(msg.warning),
        "people_m": [_xy(q, "people") for q in msg.people],
    }


# -- the legs (/perception/legs) -----------------------------------------------------------
def legs_to_msg(d: Mapping[str, Any], frame_id: str = "map") -> LegTracks:
    """The legs node's record (:func:`stack.perception.messages.legs_to_dict`) -> LegTracks."""
    msg = _header(LegTracks(), float(d.get("stamp_s") or 0.0), frame_id)
    msg.valid_beams = int(d.get("valid_beams") or 0)
    msg.segments = int(d.get("segments") or 0)
    msg.on_obstacles = int(d.get("on_obstacles") or 0)
    msg.legs = [_point(q) for q in d.get("legs") or ()]
    msg.people = [_point(q) for q in d.get("people") or ()]
    tracks = []
    for t in d.get("tracks") or ():
        tr = LegTrack()
        tr.id = int(t["id"])
        tr.position = _point(t["position_m"])
        vx, vy = t["velocity_mps"]
        tr.velocity = Vector3(x=float(vx), y=float(vy), z=0.0)
        tr.speed_mps = float(t["speed_mps"])
        tr.speed_class = str(t.get("speed_class") or "")
        tr.hits = int(t["hits"])
        tr.age_s = float(t["age_s"])
        tr.confirmed = bool(t["confirmed"])
        tracks.append(tr)
    msg.tracks = tracks
    return msg


def legs_from_msg(msg: Any) -> dict[str, Any]:
    """LegTracks -> the legs record (:func:`stack.perception.messages.tracks_from_dict`
    reads its ``tracks``).

    Raises:
        ValueError: a non-finite position, velocity, speed or age.
    """
    return {
        "stamp_s": stamp_s(msg.header.stamp),
        "valid_beams": int(msg.valid_beams),
        "segments": int(msg.segments),
        "on_obstacles": int(msg.on_obstacles),
        "legs": [_xy(q, "legs") for q in msg.legs],
        "people": [_xy(q, "people") for q in msg.people],
        "tracks": [
            {
                "id": int(t.id),
                "position_m": _xy(t.position, "track position"),
                "velocity_mps": _xy(t.velocity, "track velocity"),
                "speed_mps": _finite(t.speed_mps, "track speed"),
                "speed_class": str(t.speed_class),
                "hits": int(t.hits),
                "age_s": _finite(t.age_s, "track age"),
                "confirmed": bool(t.confirmed),
            }
            for t in msg.tracks
        ],
    }


# -- navigation (/nav/goal, /nav/result, /nav/progress) ------------------------------------
def nav_goal_to_msg(goal_id: int, action: str, t_s: float) -> NavGoal:
    msg = _header(NavGoal(), t_s, "map")
    msg.goal_id, msg.action = int(goal_id), str(action)
    return msg


def nav_goal_from_msg(msg: Any) -> tuple[int, str]:
    """NavGoal -> (goal_id, action).

    Raises:
        ValueError: goal id 0 (ids start at 1: 0 means "none" in results).
    """
    if int(msg.goal_id) == 0:
        raise ValueError(f"navigation goal {msg.action!r} without a goal id (ids start at 1)")
    return int(msg.goal_id), str(msg.action)


def nav_result_to_msg(d: Mapping[str, Any], t_s: float = 0.0) -> NavResult:
    """Navigation's result record (:meth:`stack.nav.executor.ActionExecutor` ``result``
    output; the planner's ``nav`` of a step, e.g. {"result": "timeout"}) -> NavResult."""
    msg = _header(NavResult(), t_s, "map")
    msg.goal_id = int(d.get("goal_id") or 0)
    msg.result = _str(d.get("result"))
    msg.error_code = int(d.get("error_code") or 0)
    msg.error_name = _str(d.get("error_name"))
    msg.message = _str(d.get("message"))
    msg.action = _str(d.get("action"))
    msg.from_cell = _cell_out(d.get("from_cell"))
    msg.target_cell = _cell_out(d.get("target_cell"))
    msg.cell = _cell_out(d.get("cell"))
    return msg


def nav_result_from_msg(msg: Any) -> dict[str, Any]:
    """NavResult -> the result record (the planner's step machine reads it).

    Raises:
        ValueError: a cell below -1.
    """
    return {
        "goal_id": int(msg.goal_id),
        "result": str(msg.result),
        "error_code": int(msg.error_code),
        "error_name": str(msg.error_name),
        "message": str(msg.message),
        "action": _opt_str(msg.action),
        "from_cell": _cell_in(msg.from_cell, "from_cell"),
        "target_cell": _cell_in(msg.target_cell, "target_cell"),
        "cell": _cell_in(msg.cell, "cell"),
    }


# nav2's error codes in the NavigateToPose result (vigil's own detail: error_msg, result)
NAV2_NONE, NAV2_UNKNOWN, NAV2_TIMEOUT = 0, 9000, 9003


def nav_action_goal_from_msg(goal: Any, map_frame: str = "map") -> dict[str, Any]:
    """A NavigateToPose goal -> {"goal_id", "action"} (an action's name, vigil's field)
    or {"goal_id", "x", "y"} (a pose in the map frame, nav2's field; orientation ignored).

    Raises:
        ValueError: an unknown frame, or a non-finite pose.
    """
    goal_id = int(goal.goal_id)
    if goal.action:
        return {"goal_id": goal_id, "action": str(goal.action)}
    frame = goal.pose.header.frame_id
    if frame and frame != map_frame:
        raise ValueError(f"goal pose in frame {frame!r}, need {map_frame!r}")
    x, y = _xy(goal.pose.pose.position, "goal pose")
    return {"goal_id": goal_id, "x": x, "y": y}


def nav_action_result_to_msg(d: Mapping[str, Any]) -> Any:
    """Navigation's result record -> NavigateToPose.Result (nav2's error code: NONE on
    success, TIMEOUT for timed_out, UNKNOWN otherwise; vigil's detail in error_msg)."""
    msg = NavigateToPose.Result()
    result = _str(d.get("result"))
    msg.error_code = (
        NAV2_NONE
        if result == "succeeded"
        else NAV2_TIMEOUT
        if result == "timed_out"
        else NAV2_UNKNOWN
    )
    msg.error_msg = "" if result == "succeeded" else f"{d.get('error_name')}: {d.get('message')}"
    msg.goal_id = int(d.get("goal_id") or 0)
    msg.result = result
    msg.cell = _cell_out(d.get("cell"))
    return msg


def nav_action_feedback_to_msg(
    d: Mapping[str, Any], pose_xy_yaw: tuple[float, float, float] | None, elapsed_s: float
) -> Any:
    """Navigation's progress record, the robot's map pose and the time since the goal
    began -> NavigateToPose.Feedback."""
    msg = NavigateToPose.Feedback()
    if pose_xy_yaw is not None:
        x, y, yaw = pose_xy_yaw
        msg.current_pose.header.frame_id = "map"
        msg.current_pose.pose.position.x, msg.current_pose.pose.position.y = float(x), float(y)
        msg.current_pose.pose.orientation.z = math.sin(yaw / 2)
        msg.current_pose.pose.orientation.w = math.cos(yaw / 2)
    elapsed_ns = max(0, int(round(elapsed_s * 1e9))) if math.isfinite(elapsed_s) else 0
    msg.navigation_time.sec, msg.navigation_time.nanosec = divmod(elapsed_ns, 1_000_000_000)
    msg.number_of_recoveries = min(int(d.get("replans") or 0), 2**15 - 1)
    msg.distance_remaining = _none_nan(d.get("distance_remaining_m"))
    msg.goal_id = int(d.get("goal_id") or 0)
    msg.state = _str(d.get("state"))
    return msg


def nav_progress_to_msg(d: Mapping[str, Any], t_s: float = 0.0) -> NavProgress:
    msg = _header(NavProgress(), t_s, "map")
    msg.goal_id = int(d.get("goal_id") or 0)
    msg.state = _str(d.get("state"))
    msg.distance_remaining_m = _none_nan(d.get("distance_remaining_m"))
    msg.replans = int(d.get("replans") or 0)
    msg.message = _str(d.get("message"))
    msg.cell = _cell_out(d.get("cell"))
    return msg


def nav_progress_from_msg(msg: Any) -> dict[str, Any]:
    return {
        "goal_id": int(msg.goal_id),
        "state": str(msg.state),
        "distance_remaining_m": _nan_none(msg.distance_remaining_m),
        "replans": int(msg.replans),
        "message": str(msg.message),
        "cell": _cell_in(msg.cell, "cell"),
    }


# -- the planner (/planner/belief, /planner/step, /planner/done) ----------------------------
def belief_to_msg(marginals: Mapping[str, Mapping[str, float]], step: int, t_s: float) -> Belief:
    """The planner's marginals {variable: {label: p}} -> Belief."""
    msg = _header(Belief(), t_s, "map")
    msg.step = max(0, int(step))
    msg.variables = [
        BeliefVariable(
            name=str(name),
            labels=[str(k) for k in dist],
            probabilities=[float(p) for p in dist.values()],
        )
        for name, dist in marginals.items()
    ]
    return msg


def belief_from_msg(msg: Any) -> dict[str, dict[str, float]]:
    """Belief -> {variable: {label: p}}.

    Raises:
        ValueError: labels and probabilities of different lengths, or a probability
            that is not a number in [0, 1].
    """
    out: dict[str, dict[str, float]] = {}
    for var in msg.variables:
        if len(var.labels) != len(var.probabilities):
            raise ValueError(
                f"belief variable {var.name!r}: {len(var.labels)} labels but "
                f"{len(var.probabilities)} probabilities"
            )
        dist = {}
        for label, p in zip(var.labels, var.probabilities, strict=True):
            p = float(p)
            if not 0.0 <= p <= 1.0:  # NaN fails too
                raise ValueError(f"belief variable {var.name!r}: P({label}) = {p}")
            dist[str(label)] = p
        out[str(var.name)] = dist
    return out


def decision_to_msg(record: Mapping[str, Any]) -> Decision:
    """The planner's step record (:meth:`PlannerAgent.record` completed by the step
    machine: stamp_s, nav, resumed, trigger, goal_id) -> Decision."""
    t_s = float(record.get("stamp_s") or 0.0)
    msg = _header(Decision(), t_s, "map")
    msg.step = max(0, int(record.get("step") or 0))
    msg.action = _str(record.get("action"))
    obs = record.get("observation")
    msg.has_observation = obs is not None
    if obs is not None:
        msg.observation = observation_to_msg({"stamp_s": t_s, **obs})
    msg.belief = belief_to_msg(record.get("belief") or {}, msg.step, t_s)
    msg.values = [float(v) for v in record.get("values") or ()]
    msg.note = _str(record.get("note"))
    msg.goal_id = int(record.get("goal_id") or 0)
    msg.trigger = _str(record.get("trigger"))
    msg.resumed = bool(record.get("resumed"))
    nav = record.get("nav")
    msg.has_nav = isinstance(nav, Mapping)
    if isinstance(nav, Mapping):
        msg.nav = nav_result_to_msg(nav, t_s)
    depth = record.get("depth")
    msg.depth = -1 if depth is None else int(depth)
    return msg


def decision_from_msg(msg: Any) -> dict[str, Any]:
    """Decision -> the step record (the planner's ``steps_file`` line, with ``goal_id``).

    Raises:
        ValueError: a malformed observation, belief or result inside.
    """
    obs = observation_from_msg(msg.observation) if msg.has_observation else None
    if obs is not None:  # the labels Observed.to_dict writes, nothing of the sensors
        obs = {
            k: v
            for k, v in obs.items()
            if k in ("robot", "person", "velocity", "people", "source", "hidden")
            and (v or k in ("robot", "person", "velocity"))
        }
    out: dict[str, Any] = {
        "step": int(msg.step),
        "action": _opt_str(msg.action),
        "observation": obs,
        "belief": belief_from_msg(msg.belief),
        "values": [float(v) for v in msg.values],
        "note": _opt_str(msg.note),
        "stamp_s": round(stamp_s(msg.header.stamp), 6),
        "trigger": str(msg.trigger),
        "resumed": bool(msg.resumed),
        "nav": nav_result_from_msg(msg.nav) if msg.has_nav else None,
        "goal_id": int(msg.goal_id),
    }
    if msg.depth >= 0:
        out["depth"] = int(msg.depth)
    return out


def planner_done_to_msg(steps: int, t_s: float) -> PlannerDone:
    msg = _header(PlannerDone(), t_s)
    msg.steps = max(0, int(steps))
    return msg


# -- speech (/speech/warning, /speech/done) ------------------------------------------------
def warning_to_msg(text: str, request_id: int, person_cell: int | None, t_s: float) -> Warning:
    msg = _header(Warning(), t_s)
    msg.text, msg.request_id, msg.person_cell = (
        str(text),
        max(0, int(request_id)),
        _cell_out(person_cell),
    )
    return msg


def speech_done_to_msg(d: Mapping[str, Any], t_s: float) -> SpeechDone:
    """The speech node's event record {request_id, kind, text, voice, wav, duration_s,
    error} -> SpeechDone."""
    msg = _header(SpeechDone(), t_s)
    msg.request_id = int(d["request_id"])
    msg.kind, msg.text = str(d["kind"]), _str(d.get("text"))
    msg.voice, msg.wav, msg.error = _str(d.get("voice")), _str(d.get("wav")), _str(d.get("error"))
    msg.duration_s = _none_nan(d.get("duration_s"))
    return msg


def speech_done_from_msg(msg: Any) -> dict[str, Any]:
    return {
        "request_id": int(msg.request_id),
        "kind": str(msg.kind),
        "text": str(msg.text),
        "voice": _opt_str(msg.voice),
        "wav": _opt_str(msg.wav),
        "duration_s": _nan_none(msg.duration_s),
        "error": _opt_str(msg.error),
    }


# -- the twin's ground truth (/twin/truth) -------------------------------------------------
def truth_to_msg(d: Mapping[str, Any]) -> TwinTruth:
    """The twin's truth record (:func:`twin.twin.truth_record`) -> TwinTruth."""
    msg = _header(TwinTruth(), float(d["t"]), "map")
    x, y, yaw = d["robot"]
    msg.robot = Pose2D(x=float(x), y=float(y), theta=float(yaw))
    msg.robot_cell = _cell_out(d.get("robot_cell"))
    person = d.get("person")
    msg.has_person = person is not None
    msg.person = _point(person)
    msg.person_cell = _cell_out(d.get("person_cell"))
    vel = d.get("person_velocity") or (0.0, 0.0)
    msg.person_velocity = Vector3(x=float(vel[0]), y=float(vel[1]), z=0.0)
    people = d.get("people") or ()
    msg.people = [_point(q["position"]) for q in people]
    msg.people_cells = [_cell_out(q.get("cell")) for q in people]
    msg.people_velocities = [
        Vector3(x=float(q["velocity"][0]), y=float(q["velocity"][1]), z=0.0) for q in people
    ]
    return msg


def truth_from_msg(msg: Any) -> dict[str, Any]:
    """TwinTruth -> the truth record (the recorder's trace reads it).

    Raises:
        ValueError: the people's arrays of different lengths, non-finite values.
    """
    n = len(msg.people)
    if len(msg.people_cells) != n or len(msg.people_velocities) != n:
        raise ValueError(
            f"truth has {n} people, {len(msg.people_cells)} cells and "
            f"{len(msg.people_velocities)} velocities"
        )
    r = msg.robot
    out: dict[str, Any] = {
        "t": round(stamp_s(msg.header.stamp), 6),
        "robot": [_finite(r.x, "robot.x"), _finite(r.y, "robot.y"), _finite(r.theta, "robot.yaw")],
        "robot_cell": _cell_in(msg.robot_cell, "robot_cell"),
        "person": _xy(msg.person, "person") if msg.has_person else None,
        "person_cell": _cell_in(msg.person_cell, "person_cell") if msg.has_person else None,
        "person_velocity": _xy(msg.person_velocity, "person_velocity") if msg.has_person else None,
    }
    if n:
        out["people"] = [
            {
                "position": _xy(p, "people"),
                "cell": _cell_in(c, "people cell"),
                "velocity": _xy(v, "people velocity"),
            }
            for p, c, v in zip(msg.people, msg.people_cells, msg.people_velocities, strict=True)
        ]
    return out


# -- the lock-step acknowledgement (/lockstep/ack) -----------------------------------------
def _counts(topics: Iterable[str], counts: Iterable[int], what: str) -> dict[str, int]:
    t, c = list(topics), [int(v) for v in counts]
    if len(t) != len(c):
        raise ValueError(f"ack {what}: {len(t)} topics but {len(c)} counts")
    return {str(k): v for k, v in zip(t, c, strict=True)}


def ack_to_msg(
    node: str,
    incarnation: str,
    run: str,
    recv: Mapping[str, int],
    sent: Mapping[str, int],
    matched: Mapping[str, int],
) -> LockstepAck:
    """A participant's counts (:class:`stack.lockstep.Ack` fields) -> LockstepAck."""
    msg = LockstepAck(node=str(node), incarnation=str(incarnation), run=str(run))
    msg.recv_topics, msg.recv_counts = list(recv), [max(0, int(v)) for v in recv.values()]
    msg.sent_topics, msg.sent_counts = list(sent), [max(0, int(v)) for v in sent.values()]
    msg.matched_topics, msg.matched_counts = list(matched), [int(v) for v in matched.values()]
    return msg


def ack_from_msg(msg: Any) -> dict[str, Any]:
    """LockstepAck -> {node, incarnation, run, recv, sent, matched} (:class:`Ack`'s fields).

    Raises:
        ValueError: topics and counts of different lengths, or no node name.
    """
    if not msg.node:
        raise ValueError("ack without a node name")
    return {
        "node": str(msg.node),
        "incarnation": str(msg.incarnation),
        "run": str(msg.run),
        "recv": _counts(msg.recv_topics, msg.recv_counts, "recv"),
        "sent": _counts(msg.sent_topics, msg.sent_counts, "sent"),
        "matched": _counts(msg.matched_topics, msg.matched_counts, "matched"),
    }


# -- health (/diagnostics) -----------------------------------------------------------------
DIAGNOSTIC_LEVELS = {"ok": 0, "warn": 1, "error": 2, "stale": 3}


def _diag_value(v: Any) -> str:
    """A value as diagnostics text: strings as they are, the rest as JSON (true, 0.3)."""
    return v if isinstance(v, str) else json.dumps(v)


def diagnostics_to_msg(
    name: str,
    hardware_id: str,
    level: str,
    message: str,
    values: Mapping[str, Any],
    stamp_msg: Any,
) -> DiagnosticArray:
    """One component's health as a diagnostic_msgs/DiagnosticArray with one status
    (``level``: ok, warn, error or stale; ``values`` shown as key/value text)."""
    status = DiagnosticStatus(
        level=DIAGNOSTIC_LEVELS[level].to_bytes(1, "little"),
        name=str(name),
        message=str(message),
        hardware_id=str(hardware_id),
        values=[KeyValue(key=str(k), value=_diag_value(v)) for k, v in values.items()],
    )
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = stamp_msg
    return msg


def diagnostics_from_msg(msg: Any) -> dict[str, dict[str, Any]]:
    """DiagnosticArray -> {status name: {"level": 0-3, "message": ..., key: value}}, values
    read back as JSON where they are JSON (true, 0.3) and as text otherwise."""
    out: dict[str, dict[str, Any]] = {}
    for st in msg.status:
        level = st.level
        entry: dict[str, Any] = {
            "level": int.from_bytes(level, "little") if isinstance(level, bytes) else int(level),
            "message": str(st.message),
        }
        for kv in st.values:
            try:
                entry[kv.key] = json.loads(kv.value)
            except (ValueError, RecursionError):  # text, or JSON nested too deep to read
                entry[kv.key] = kv.value
        out[str(st.name)] = entry
    return out
