"""One validated YAML file per deployment: ``config/twin.yaml``, ``config/hardware.yaml``.

The file says where the stack runs (``mode: twin`` or ``mode: hardware``), which task
and policy it plans with, and how each node is set up. Paths are relative to the
file. Every key is checked; an unknown key, a wrong type or a twin-only setting in
hardware mode is a :class:`stack.cells.ConfigError` naming the key.

Sections (all optional except ``mode`` and ``task``)::

    mode: twin | hardware
    task: task-r2.yaml            # the POMDP (grid, rewards, initial state)
    policy: ""                    # alpha vectors (.npz); "": solved on first use, cached
    lockstep: true                # twin only: advance only when the stack has caught up
    ros: {domain_id: null, localhost_only: true, interfaces: [], peers: []}
    hosts: {robot: [twin_bridge, ...], planner: [...]}  # the system over several hosts:
                                  # vigil launch FILE --host NAME starts that host's nodes
    twin: {scene: twin-scene.yaml, seed: 0, realtime: false, odom_rate_hz: 25.0,
           velocity_gate: false}  # true: navigation -> velocity gate -> the twin's
                                  # base, as on a robot (real time only)
    perception: {config: "", calibration: ""}   # twin: calibrated from the twin if ""
    navigation: {config: "", pose_source: odom, pose_topic: "", control_rate_hz: 20.0,
                 drive: holonomic}        # or diff: the follower (and the twin's base)
                 # pose_source: odom (twin) | amcl | tf (hardware default; odom refused)
    speech: {voice: en}
    planner: {max_steps: 0, start_delay_s: 1.0, nav_timeout_s: 60.0, obs_timeout_s: 5.0}
    nodes: {restart: true, max_restarts: 3, stop_timeout_s: 5.0,
            processes: auto}      # vigil run: one process for the lock-step twin's
                                  # nodes (vigil.container) | one (or refused) | separate
    topics: {scan: /scan, odom: /odom, cmd_vel: /cmd_vel}
    hardware: {camera_stream: {...}, velocity_gate: {...}, armed: false,
               camera_info: axis-intrinsics.yaml}   # optional: /camera/camera_info
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import stack.topics as topic
from stack.cells import ConfigError
from stack.config import Config, read_yaml

MODES = ("twin", "hardware")
PROCESSES = ("auto", "one", "separate")  # nodes.processes
# bounds of the values (issue 23: a value a node cannot use is refused here, naming the
# key, before any process starts; types and finiteness: stack.config.check_fields)
MAX_SEED = 2**32 - 1  # numpy's legacy seeds and every ROS integer parameter take it
MAX_STEPS = 10_000  # as a scenario's (vigil.scenario)
MAX_RATE_HZ = 1000.0
MAX_WAIT_S = 3600.0  # a timeout or delay longer than an hour is no timeout
MAX_RESTARTS = 1000
TOPIC_NAME = re.compile(r"/[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")
VOICE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_+-]{0,39}")  # espeak-ng: en, en-us, en+f3


def _within(low: float, high: float, low_open: bool = True):
    """A rule: ``low < v <= high`` (``low <= v`` with ``low_open`` False)."""
    text = f"must be in {'(' if low_open else '['}{low:g}, {high:.16g}]"
    if low_open:
        return (lambda v: low < v <= high, text)
    return (lambda v: low <= v <= high, text)


NAV_CMD_VEL = topic.NAV_CMD_VEL  # hardware mode: navigation -> gate; only the gate drives the base
TWIN_ONLY = ("twin", "lockstep")


@dataclass(frozen=True)
class RosSection(Config):
    """Who can hear the system.

    Attributes:
        domain_id: -1: a private domain per run in the twin (:mod:`vigil.ros_domain`);
            hardware mode needs an explicit id other than 0 (the default domain every
            other ROS 2 system on the network shares).
        localhost_only: DDS on the loopback interface only (Fast DDS profile
            :data:`vigil.dds.PROFILE`): no other host can reach the nodes.
        interfaces: with ``localhost_only: false``, the only addresses DDS may use
            (e.g. the robot's wired address); empty: refused in hardware mode.
        keystore: an SROS2 keystore (``vigil security keystore``); hardware mode runs
            with security enforced when set.
        peers: the other hosts' addresses, asked directly at discovery (unicast: for a
            network that drops multicast, e.g. Wi-Fi), beside multicast on
            ``interfaces``.
    """

    domain_id: int = -1
    localhost_only: bool = True
    interfaces: tuple[str, ...] = ()
    keystore: str = ""
    peers: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not -1 <= self.domain_id <= 232:
            raise ConfigError("domain_id", self.domain_id, "must be in [0, 232] (or -1)")
        for ip in self.interfaces:
            if not _is_ipv4(ip):
                raise ConfigError("interfaces", ip, "must be IPv4 addresses like 10.0.0.2")
        for ip in self.peers:
            if not _is_ipv4(ip):
                raise ConfigError("peers", ip, "must be IPv4 addresses like 10.0.0.3")
        if self.peers and self.localhost_only:
            raise ConfigError("peers", list(self.peers), "needs localhost_only: false")


def _is_ipv4(text: str) -> bool:
    parts = text.split(".")
    return len(parts) == 4 and all(p.isdigit() and 0 <= int(p) <= 255 for p in parts)


@dataclass(frozen=True)
class TwinSection(Config):
    scene: str = "twin-scene.yaml"
    seed: int = 0
    realtime: bool = False
    odom_rate_hz: float = 25.0
    stall_timeout_s: float = 30.0
    stall_abort_s: float = 0.0  # 0: three stall timeouts (the bridge's default)
    # the hardware chain: navigation -> velocity gate -> the twin's base (which then also
    # watches the gate's heartbeat); only at real time, the gate's timing being on the
    # monotonic clock (vigil.system.prepare refuses it in lock-step)
    velocity_gate: bool = False

    _rules = {
        "seed": _within(0, MAX_SEED, low_open=False),
        "odom_rate_hz": _within(0, MAX_RATE_HZ),
        "stall_timeout_s": _within(0, MAX_WAIT_S),
        "stall_abort_s": (
            lambda v: v == 0 or 1 <= v <= 24 * MAX_WAIT_S,
            f"must be 0 (3 x stall_timeout_s) or in [1, {24 * MAX_WAIT_S:g}]",
        ),
    }


@dataclass(frozen=True)
class PerceptionSection(Config):
    config: str = ""
    calibration: str = ""


@dataclass(frozen=True)
class NavigationSection(Config):
    config: str = ""
    pose_source: str = "odom"
    pose_topic: str = ""
    control_rate_hz: float = 20.0
    drive: str = "holonomic"  # the base: holonomic (mecanum) or diff (differential drive)

    _rules = {
        "control_rate_hz": _within(0, MAX_RATE_HZ),
        "pose_topic": (
            lambda v: v == "" or TOPIC_NAME.fullmatch(v) is not None,
            "must be empty or an absolute ROS topic name",
        ),
    }

    def __post_init__(self) -> None:
        if self.pose_source not in ("odom", "amcl", "tf"):
            raise ConfigError("pose_source", self.pose_source, "must be odom, amcl or tf")
        if self.drive not in ("holonomic", "diff"):
            raise ConfigError("drive", self.drive, "must be holonomic or diff")


@dataclass(frozen=True)
class SpeechSection(Config):
    voice: str = "en"

    _rules = {
        "voice": (
            lambda v: VOICE_NAME.fullmatch(v) is not None,
            "must be an espeak-ng voice name (letters, digits, _ + -; not starting with -)",
        )
    }


@dataclass(frozen=True)
class PlannerSection(Config):
    max_steps: int = 0
    start_delay_s: float = 1.0
    nav_timeout_s: float = 60.0
    obs_timeout_s: float = 5.0

    _rules = {
        "max_steps": _within(0, MAX_STEPS, low_open=False),  # 0: no end
        "start_delay_s": _within(0, MAX_WAIT_S, low_open=False),
        "nav_timeout_s": _within(0, MAX_WAIT_S),
        "obs_timeout_s": _within(0, MAX_WAIT_S),
    }


@dataclass(frozen=True)
class NodesSection(Config):
    restart: bool = True
    max_restarts: int = 3
    stop_timeout_s: float = 5.0
    restart_delay_s: float = 0.0
    # vigil run: "one" process for every node of the lock-step twin run
    # (vigil.container), "separate" (one a node), "auto": one where it applies
    # (vigil.system.one_process says where not)
    processes: str = "auto"

    _rules = {
        "max_restarts": _within(0, MAX_RESTARTS, low_open=False),
        "stop_timeout_s": _within(0, 600.0),
        "restart_delay_s": _within(0, 600.0, low_open=False),
        "processes": (lambda v: v in PROCESSES, f"must be one of {', '.join(PROCESSES)}"),
    }


@dataclass(frozen=True)
class TopicsSection(Config):
    scan: str = topic.SCAN
    odom: str = topic.ODOM
    cmd_vel: str = topic.CMD_VEL

    _rules = {
        name: (
            lambda v: TOPIC_NAME.fullmatch(v) is not None,
            "must be an absolute ROS topic name (/name or /ns/name: letters, digits, _)",
        )
        for name in ("scan", "odom", "cmd_vel")
    }


@dataclass(frozen=True)
class Deployment:
    """A validated deployment file (paths resolved to absolute)."""

    mode: str
    task: Path
    policy: Path | None
    lockstep: bool
    ros: RosSection
    twin: TwinSection
    perception: PerceptionSection
    navigation: NavigationSection
    speech: SpeechSection
    planner: PlannerSection
    nodes: NodesSection
    topics: TopicsSection
    hardware: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None
    hosts: dict[str, tuple[str, ...]] = field(default_factory=dict)  # host -> its nodes

    def resolve(self, path: str) -> Path | None:
        """A path of the file, relative to the file's folder ("" -> None)."""
        if not path:
            return None
        p = Path(path)
        return p if p.is_absolute() or self.source is None else self.source.parent / p


_SECTIONS = {
    "ros": RosSection,
    "twin": TwinSection,
    "perception": PerceptionSection,
    "navigation": NavigationSection,
    "speech": SpeechSection,
    "planner": PlannerSection,
    "nodes": NodesSection,
    "topics": TopicsSection,
}
_KEYS = {"mode", "task", "policy", "lockstep", "hardware", "hosts", *_SECTIONS}


def _hosts(data: Any) -> dict[str, tuple[str, ...]]:
    """The ``hosts`` section: host name -> the names of the nodes it runs, each node on
    one host at most (which nodes exist is checked by :func:`vigil.system.host_specs`).

    Raises:
        ConfigError: not such a mapping, or a node listed twice.
    """
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise ConfigError("hosts", data, "must map host names to lists of node names")
    out: dict[str, tuple[str, ...]] = {}
    seen: dict[str, str] = {}
    for host, nodes in data.items():
        if not isinstance(host, str) or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]*", host):
            raise ConfigError("hosts", host, "host names are words like robot or camera-pc")
        if not isinstance(nodes, list) or not all(isinstance(n, str) for n in nodes):
            raise ConfigError(f"hosts.{host}", nodes, "must be a list of node names")
        for n in nodes:
            if n in seen:
                raise ConfigError(f"hosts.{host}", n, f"already runs on host {seen[n]!r}")
            seen[n] = host
        out[host] = tuple(nodes)
    return out


def parse_deployment(data: Any, source: Path | None = None) -> Deployment:
    """Validate a deployment mapping.

    Raises:
        ConfigError: naming the key, the value and the rule.
    """
    if not isinstance(data, Mapping):
        raise ConfigError("<file>", type(data).__name__, "must hold a mapping")
    for k in data:
        if k not in _KEYS:
            raise ConfigError(str(k), data[k], f"unknown key (known: {sorted(_KEYS)})")
    mode = data.get("mode")
    if mode not in MODES:
        raise ConfigError("mode", mode, f"must be one of {MODES}")
    if mode == "hardware":
        for k in TWIN_ONLY:
            if k in data and data[k]:
                raise ConfigError(k, data[k], "a twin-only setting: hardware mode refuses it")
    if mode == "twin" and data.get("hardware"):
        raise ConfigError("hardware", "...", "a hardware-only section: twin mode refuses it")
    task = data.get("task")
    if not isinstance(task, str) or not task:
        raise ConfigError("task", task, "must name the task file")
    policy = data.get("policy", "") or ""
    if not isinstance(policy, str):
        raise ConfigError("policy", policy, "must be a path or empty")
    lockstep = data.get("lockstep", mode == "twin")
    if not isinstance(lockstep, bool):
        raise ConfigError("lockstep", lockstep, "must be true or false")
    hardware = data.get("hardware") or {}
    if not isinstance(hardware, Mapping):
        raise ConfigError("hardware", hardware, "must be a mapping")
    if mode == "hardware" and isinstance(data.get("navigation") or {}, Mapping):
        # a robot's map pose: through TF unless the file names another source
        data = {**data, "navigation": {"pose_source": "tf", **(data.get("navigation") or {})}}
    sections = {name: cls.from_dict(data.get(name), name) for name, cls in _SECTIONS.items()}
    if mode == "hardware" and sections["navigation"].pose_source == "odom":
        raise ConfigError(
            "navigation.pose_source",
            "odom",
            "on a robot odometry drifts from the map: use amcl or tf (REP-105 map -> odom)",
        )
    if sections["nodes"].processes == "one" and (mode != "twin" or not lockstep):
        raise ConfigError(
            "nodes.processes", "one", "one process holds the nodes of a lock-step twin run "
            "only (a robot's, a real-time twin's or several hosts' nodes run apart): use "
            "auto or separate",
        )  # fmt: skip
    hosts = _hosts(data.get("hosts"))
    if hosts and lockstep:
        raise ConfigError(
            "hosts", sorted(hosts), "a system over several hosts cannot run in lock-step: "
            "set lockstep: false (and, in the twin, twin.realtime: true)",
        )  # fmt: skip
    dep = Deployment(
        mode=mode,
        task=Path(task),
        policy=Path(policy) if policy else None,
        lockstep=lockstep,
        hardware=dict(hardware),
        source=source,
        hosts=hosts,
        **sections,
    )
    resolved = replace(dep, task=dep.resolve(task), policy=dep.resolve(policy) if policy else None)
    if not resolved.task.exists():
        raise ConfigError("task", str(resolved.task), "file not found")
    if mode == "hardware":
        _check_hardware(resolved)
    return resolved


def _check_hardware(dep: Deployment) -> None:
    from stack.hardware.camera_stream import StreamConfig
    from stack.hardware.velocity_gate import GateConfig

    known = {"camera_stream", "velocity_gate", "armed", "camera_info"}
    for k in dep.hardware:
        if k not in known:
            raise ConfigError(
                f"hardware.{k}", dep.hardware[k], f"unknown key (known: {sorted(known)})"
            )
    StreamConfig.from_dict(dep.hardware.get("camera_stream"), "hardware.camera_stream")
    GateConfig.from_dict(dep.hardware.get("velocity_gate"), "hardware.velocity_gate")
    if not isinstance(dep.hardware.get("armed", False), bool):
        raise ConfigError("hardware.armed", dep.hardware["armed"], "must be true or false")
    info = dep.hardware.get("camera_info", "")
    if not isinstance(info, str):
        raise ConfigError("hardware.camera_info", info, "must be a path (or empty: no CameraInfo)")
    if info:
        from stack.hardware.camera_stream import load_calibration

        try:  # read now: a bad intrinsics file stops the deployment, not the camera node
            load_calibration(dep.resolve(info))
        except ConfigError as err:
            raise ConfigError("hardware.camera_info", info, str(err)) from None
    if not dep.perception.calibration:
        raise ConfigError(
            "perception.calibration", "", "hardware mode needs the camera's calibration file"
        )
    ros = dep.ros
    if ros.domain_id <= 0:
        raise ConfigError(
            "ros.domain_id",
            ros.domain_id,
            "hardware mode needs its own domain (1..232), not the shared default",
        )
    if not ros.localhost_only and not ros.interfaces:
        raise ConfigError(
            "ros.interfaces", [], "hardware mode off localhost must list the addresses DDS may use"
        )
    if dep.topics.cmd_vel in (NAV_CMD_VEL, topic.ARM, topic.DIAGNOSTICS):
        raise ConfigError(
            "topics.cmd_vel",
            dep.topics.cmd_vel,
            f"is the gate's own input or state: the base's topic must differ from {NAV_CMD_VEL}",
        )
    if ros.keystore:
        if not Path(dep.resolve(ros.keystore)).is_dir():
            raise ConfigError("ros.keystore", ros.keystore, "no such keystore folder")
        from vigil.security import require_support

        require_support()  # a keystore DDS would not enforce is refused, not ignored


def gate_topics(dep: Deployment) -> dict[str, str]:
    """The velocity gate's topics under ``dep``, as its ``*_topic`` parameters: what
    ``vigil launch`` gives the gate and what ``vigil arm``, ``disarm`` and ``status`` use
    (the gate's caps are in ``hardware.velocity_gate``; its topics are fixed but the
    base's, ``topics.cmd_vel``)."""
    return {
        "input_topic": NAV_CMD_VEL,
        "output_topic": dep.topics.cmd_vel,
        "arm_topic": topic.ARM,
        "diagnostics_topic": topic.DIAGNOSTICS,
        "heartbeat_topic": topic.GATE_HEARTBEAT,
    }


def load_deployment(path: str | Path) -> Deployment:
    """Read and validate a deployment file.

    Raises:
        ConfigError: an invalid key or value; OSError: the file cannot be read.
    """
    path = Path(path).resolve()
    return parse_deployment(read_yaml(path), path)
