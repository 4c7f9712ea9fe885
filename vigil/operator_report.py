"""What ``vigil arm``, ``vigil disarm`` and ``vigil status`` make of what they heard (pure).

:mod:`vigil.operator` listens on the deployment's ROS domain for a short window and
fills a :class:`Heard`; this module turns it into the status screen, its JSON record and
exit code, and the checks ``vigil arm`` makes before it arms.

Levels are diagnostic_msgs' (0 OK, 1 WARN, 2 ERROR, 3 STALE). The gate's own level is
WARN whenever it passes nothing (disarmed, or armed with navigation idle: ``stale``),
so ``vigil status`` exits 1 on a healthy but disarmed robot; 0 means every status heard
is OK, the gate among them, beating.

Before arming (:func:`arm_refusals`), refused unless ``--force``:

- the gate published no state on ``/diagnostics`` (its caps cannot be checked);
- the gate reported a non-finite command (navigation sends NaN or inf);
- a cap of the gate above the deployment's ``hardware.velocity_gate`` (a gate started
  from another file, or with ``-p``: caps the operator never agreed to);
- another component at ERROR or STALE (a camera that cannot stream, say);
- another node publishing the base's topic (a path around the gate).

Not refused: ``stale`` (an armed gate whose navigation is idle: normal), WARN of other
components, a camera never heard, navigation commanding motion (printed: the base moves
at once when armed).

``vigil status`` also lists the robot side's inputs the stack reads (:class:`Input`: the
lidar's scan, the base's odometry, the map, the localisation's ``map -> odom`` and, with
``pose_source: amcl``, its pose): a stream heard nothing in the window, or a latched or
sparse topic has no publisher, is a problem.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

GATE = "velocity_gate"
CAMERA = "camera_stream"
LEVELS = ("OK", "WARN", "ERROR", "STALE")
NON_FINITE = "non-finite command"  # stack.hardware.velocity_gate.NON_FINITE
CAPS = (
    "max_linear_mps",
    "max_angular_radps",
    "cmd_timeout_s",
    "max_linear_accel_mps2",
    "max_angular_accel_radps2",
)
SLOW_BEAT = 0.5  # a heartbeat below this share of the gate's rate_hz is a WARN
DEFAULT_GATE_RATE_HZ = 20.0  # the gate's rate_hz default, when its parameter is unread

Cmd = tuple[float, float, float]


def level_name(level: int) -> str:
    return LEVELS[level] if 0 <= level < len(LEVELS) else f"LEVEL{level}"


@dataclass
class Input:
    """One of the robot side's inputs the stack reads, as one listen window heard it.

    ``stream``: it must be heard within the window (a sensor, the localisation's
    transform); otherwise a publisher suffices (a latched map, a pose published only
    when the filter updates)."""

    kind: str  # scan | odom | map | map_odom (on /tf) | pose: its message type
    topic: str
    source: str  # who should provide it, for the operator
    stream: bool = True
    times: list[float] = field(default_factory=list)  # receipt times (monotonic)
    publishers: list[str] | None = None  # node names; None: not looked up


@dataclass
class Heard:
    """What one listen window heard; times are monotonic seconds, ``now`` its end."""

    domain_id: int
    base_topic: str
    nav_topic: str
    window_s: float = 0.0
    now: float = 0.0
    statuses: dict[str, dict[str, Any]] = field(default_factory=dict)  # latest per name
    status_at: dict[str, float] = field(default_factory=dict)  # its receipt time
    gate_reasons: list[str] = field(default_factory=list)  # every gate reason, in order
    beats: list[tuple[float, int]] = field(default_factory=list)  # (receipt, count)
    base_cmds: list[tuple[float, Cmd]] = field(default_factory=list)
    nav_cmds: list[tuple[float, Cmd]] = field(default_factory=list)
    base_publishers: list[str] | None = None  # node names; None: not looked up
    params: dict[str, Any] | None = None  # the gate's parameters; None: no answer
    robot: dict[str, Input] = field(default_factory=dict)  # label -> input; {}: not listened

    def gate_status(self) -> dict[str, Any] | None:
        return self.statuses.get(GATE)

    def gate_armed(self) -> bool | None:
        """The gate's state as its last status says (None: no status heard)."""
        st = self.gate_status()
        return None if st is None else bool(st.get("armed"))


def heartbeat_hz(beats: list[tuple[float, int]]) -> float | None:
    """The gate's beat rate from its counts over the window (lost messages do not
    lower it; a restarted gate, whose count starts again, is measured from its
    restart); None with fewer than two beats."""
    if len(beats) < 2:
        return None
    start = 0
    for i in range(1, len(beats)):
        if beats[i][1] <= beats[i - 1][1]:  # the count went back: a new gate
            start = i
    t0, c0 = beats[start]
    t1, c1 = beats[-1]
    if t1 - t0 <= 0 or c1 <= c0:
        return None
    return (c1 - c0) / (t1 - t0)


def rate_hz(times: list[float]) -> float | None:
    """Messages per second over the receipt times; None with fewer than three."""
    if len(times) < 3 or times[-1] <= times[0]:
        return None
    return (len(times) - 1) / (times[-1] - times[0])


def caps_text(values: dict[str, Any]) -> str:
    """``0.3 m/s, 0.6 rad/s`` (+ ``, timeout 0.5 s`` when known) from a status or parameters."""
    parts = []
    if _number(values.get("max_linear_mps")) is not None:
        parts.append(f"{values['max_linear_mps']:g} m/s")
    if _number(values.get("max_angular_radps")) is not None:
        parts.append(f"{values['max_angular_radps']:g} rad/s")
    if _number(values.get("cmd_timeout_s")) is not None:
        parts.append(f"command timeout {values['cmd_timeout_s']:g} s")
    return ", ".join(parts) or "caps unknown"


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        return None
    return float(v)


def _cmd_text(cmd: Cmd) -> str:
    return "(" + ", ".join(f"{v:.2f}" for v in cmd) + ")"


def _moving(cmd: Cmd) -> bool:
    return any(v != 0.0 for v in cmd)


def gate_caps(heard: Heard) -> dict[str, Any]:
    """The gate's caps: its parameters where read, else its last status's two caps."""
    out: dict[str, Any] = {}
    st = heard.gate_status() or {}
    for key in ("max_linear_mps", "max_angular_radps"):
        if _number(st.get(key)) is not None:
            out[key] = st[key]
    for key in CAPS:
        if heard.params is not None and _number(heard.params.get(key)) is not None:
            out[key] = heard.params[key]
    return out


def other_publishers(heard: Heard) -> list[str]:
    """Nodes other than the gate that publish the base's topic."""
    return sorted(n for n in heard.base_publishers or () if n.rsplit("/", 1)[-1] != GATE)


def arm_refusals(heard: Heard, expected: dict[str, float]) -> list[str]:
    """Why arming should wait (module docstring); [] when nothing stands against it.
    ``expected``: the deployment's caps (:data:`CAPS` keys)."""
    out = []
    if heard.gate_status() is None:
        out.append(
            f"the gate published no state on /diagnostics within {heard.window_s:g} s "
            "(its caps and state cannot be checked)"
        )
    if NON_FINITE in heard.gate_reasons:
        out.append("the gate saw a non-finite command from navigation (NaN or inf)")
    caps = gate_caps(heard)
    for key in CAPS:
        have, want = _number(caps.get(key)), _number(expected.get(key))
        if have is not None and want is not None and have > want + 1e-9:
            out.append(f"the gate's {key} {have:g} exceeds the deployment's {want:g}")
    for name, st in sorted(heard.statuses.items()):
        if name != GATE and st.get("level", 0) >= 2:
            out.append(f"{name} {level_name(st['level'])} ({st.get('message', '')})")
    for name in other_publishers(heard):
        out.append(f"{name} also publishes {heard.base_topic} (a path around the gate)")
    return out


def arm_notes(heard: Heard) -> list[str]:
    """What the operator should know before arming but that does not stop it."""
    out = []
    for name, st in sorted(heard.statuses.items()):
        if name != GATE and st.get("level", 0) == 1:
            out.append(f"{name} WARN ({st.get('message', '')})")
    if CAMERA not in heard.statuses:
        out.append(
            f"{CAMERA}: no status heard within {heard.window_s:g} s, so not checked (is it "
            "running?)"
        )
    if heard.nav_cmds and _moving(heard.nav_cmds[-1][1]):
        out.append(
            f"navigation is commanding {_cmd_text(heard.nav_cmds[-1][1])} on "
            f"{heard.nav_topic}: the base moves as soon as the gate is armed"
        )
    return out


# -- vigil status --------------------------------------------------------------------------
def status_record(heard: Heard) -> dict[str, Any]:
    """Everything ``vigil status`` shows, as JSON-ready data, with ``ok`` and ``problems``."""
    problems: list[str] = []
    st = heard.gate_status()
    hz = heartbeat_hz(heard.beats)
    params = heard.params or {}
    rate = _number(params.get("rate_hz")) or DEFAULT_GATE_RATE_HZ
    present = st is not None or bool(heard.beats) or heard.params is not None
    gate: dict[str, Any] = {
        "present": present,
        "heartbeat_hz": None if hz is None else round(hz, 1),
    }
    if st is not None:
        gate.update(
            level=level_name(st["level"]),
            armed=bool(st.get("armed")),
            reason=st.get("reason", st.get("message", "")),
            age_s=round(heard.now - heard.status_at[GATE], 2),
        )
    gate["caps"] = gate_caps(heard)
    if heard.params is not None:
        gate["armed_parameter"] = params.get("armed")
    if not present:
        problems.append(
            f"no velocity gate heard (no status, heartbeat or parameter service) within "
            f"{heard.window_s:g} s"
        )
    else:
        if st is None:
            problems.append("the gate published no status on /diagnostics")
        elif st["level"] != 0:
            problems.append(f"{GATE} {level_name(st['level'])} ({gate['reason']})")
        if hz is None:
            problems.append("no heartbeat from the gate (dead, or its timer stuck)")
        elif hz < SLOW_BEAT * rate:
            problems.append(f"the gate's heartbeat is slow: {hz:.1f} Hz of {rate:g} Hz")
    base: dict[str, Any] = {"topic": heard.base_topic, "commands": len(heard.base_cmds)}
    if heard.base_cmds:
        t, cmd = heard.base_cmds[-1]
        base.update(last=list(cmd), age_s=round(heard.now - t, 2))
    if heard.base_publishers is not None:
        base["publishers"] = sorted(heard.base_publishers)
        for name in other_publishers(heard):
            problems.append(f"{name} also publishes {heard.base_topic} (a path around the gate)")
    robot: dict[str, Any] = {}
    for label, i in heard.robot.items():
        entry: dict[str, Any] = {"topic": i.topic, "from": i.source, "heard": len(i.times)}
        if i.times:
            entry["age_s"] = round(heard.now - i.times[-1], 2)
        hz = rate_hz(i.times)
        if hz is not None:
            entry["hz"] = round(hz, 1)
        if i.publishers is not None:
            entry["publishers"] = sorted(i.publishers)
        entry["ok"] = bool(i.times) or (not i.stream and bool(i.publishers))
        if not entry["ok"]:
            problems.append(f"{label} MISSING ({i.source})")
        robot[label] = entry
    statuses = {}
    for name, s in sorted(heard.statuses.items()):
        entry = {k: v for k, v in s.items() if k not in ("level", "message")}
        statuses[name] = {
            "level": level_name(s["level"]),
            "message": s.get("message", ""),
            "age_s": round(heard.now - heard.status_at[name], 2),
            **entry,
        }
        if name != GATE and s["level"] != 0:
            problems.append(f"{name} {level_name(s['level'])} ({s.get('message', '')})")
    record = {
        "ok": not problems,
        "domain_id": heard.domain_id,
        "window_s": heard.window_s,
        "problems": problems,
        "gate": gate,
        "base": base,
        "statuses": statuses,
    }
    if robot:
        record["robot"] = robot
    return record


def _input_text(r: dict[str, Any]) -> str:
    """``9.9 Hz, last 0.1 s ago; publishers: /lidar`` or what is missing and from whom."""
    if r["heard"]:
        what = f"{r['hz']:g} Hz" if "hz" in r else f"{r['heard']} heard"
        what += f", last {r['age_s']:.1f} s ago"
    else:
        what = "nothing heard"
    if "publishers" in r:
        what += f"; publishers: {', '.join(r['publishers']) or 'none'}"
    if not r["ok"]:
        what += f" ({r['from']})"
    return what


def status_exit_code(record: dict[str, Any]) -> int:
    """0: everything heard is OK (the gate present); 1 otherwise."""
    return 0 if record["ok"] else 1


def status_lines(record: dict[str, Any]) -> list[str]:
    """The status screen: the gate, the base, the camera, every other status."""
    g, b = record["gate"], record["base"]
    lines = [f"ROS domain {record['domain_id']}, listened {record['window_s']:g} s"]
    if not g["present"]:
        lines.append(f"{GATE:<16} ABSENT  no status, heartbeat or parameter service")
    else:
        armed = {True: "ARMED", False: "disarmed", None: "state unknown"}[g.get("armed")]
        beat = "no heartbeat" if g["heartbeat_hz"] is None else f"heartbeat {g['heartbeat_hz']} Hz"
        lines.append(
            f"{GATE:<16} {g.get('level', '?'):<7} {armed}: {g.get('reason', 'no status')}; "
            f"caps {caps_text(g['caps'])}; {beat}"
        )
    if "last" in b:
        what = f"last {_cmd_text(tuple(b['last']))} {b['age_s']:.1f} s ago, {b['commands']} heard"
    else:
        what = "no command heard"
    if "publishers" in b:
        what += f"; publishers: {', '.join(b['publishers']) or 'none'}"
    lines.append(f"{'base ' + b['topic']:<16} {'':<7} {what}")
    others = sorted(record["statuses"], key=lambda n: (n != CAMERA, n))
    for name in others:
        if name == GATE:
            continue
        s = record["statuses"][name]
        lines.append(f"{name:<16} {s['level']:<7} {s['message']} ({s['age_s']:.1f} s ago)")
    if CAMERA not in record["statuses"]:
        lines.append(f"{CAMERA:<16} {'':<7} no status heard")
    for label, r in record.get("robot", {}).items():
        lines.append(f"{label:<16} {'OK' if r['ok'] else 'MISSING':<7} {_input_text(r)}")
    if record["problems"]:
        lines.append("not OK: " + "; ".join(record["problems"]))
    else:
        lines.append("OK")
    return lines
