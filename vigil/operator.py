"""``vigil arm``, ``vigil disarm``, ``vigil status``: the operator's commands, over rclpy.

They need nothing but the project's own set-up (no ``ros2`` command line). Each takes a
hardware deployment file and talks to the running system as one more participant on
its ROS domain (``ros.domain_id``), with the DDS profile every node of ``vigil launch``
gets (:mod:`vigil.dds`: the same interfaces), and with a keystore in the operator's
enclave ``/vigil/operator`` (the one allowed to arm, :mod:`vigil.security`). The gate's
topics are :func:`vigil.deployment.gate_topics`; the caps it should have are the file's
``hardware.velocity_gate``.

- :func:`arm`: waits for the gate's parameter service (``--timeout``), listens for the
  gate's state and everyone's ``/diagnostics`` for a moment (and, within the timeout,
  until the gate's and the camera's statuses were heard), refuses what
  :func:`vigil.operator_report.arm_refusals` names (unless ``force``), sets ``armed``
  true through ``/velocity_gate/set_parameters`` and confirms it from the gate's own
  status (``armed: true`` on ``/diagnostics``) or, failing that, the parameter read back.
- :func:`disarm`: both ways at once: ``armed`` false through the parameter service and
  false on the arm topic, repeated until the gate's status (or parameter) says disarmed,
  so a slow or absent parameter service does not hold it up.
- :func:`status`: listens ``wait`` seconds and prints one screen
  (:func:`vigil.operator_report.status_lines`) or its JSON: the gate, the base, every
  ``/diagnostics`` status and the robot side's inputs (:func:`robot_inputs`).

Exit codes: :data:`EXIT_OK` 0; 1 ``vigil status`` heard a problem; 2 bad input (the
deployment); :data:`EXIT_NO_GATE` 3 no gate answered within the timeout;
:data:`EXIT_REFUSED` 4 the gate refused or did not confirm; :data:`EXIT_CHECKS` 5
``vigil arm`` found a reason not to arm (``--force`` arms anyway).

One module over 500 lines: the three verbs are short and share the :class:`Session`
(discovery, listening, the gate's parameter service), which is most of it; what they
print and when they refuse is already apart (:mod:`vigil.operator_report`).
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import stack.topics as topic
from stack.cells import ConfigError
from stack.tf import MAP as MAP_FRAME
from stack.tf import ODOM as ODOM_FRAME
from vigil.deployment import Deployment, gate_topics
from vigil.operator_report import (
    CAMERA,
    CAPS,
    GATE,
    Heard,
    Input,
    arm_notes,
    arm_refusals,
    caps_text,
    status_exit_code,
    status_lines,
    status_record,
)

EXIT_OK = 0
EXIT_NO_GATE = 3
EXIT_REFUSED = 4
EXIT_CHECKS = 5
OPERATOR_ENCLAVE = "operator"  # vigil.security's enclave allowed to arm
GATE_PARAMS = ("armed", *CAPS, "rate_hz")
REPEAT_S = 0.25  # disarm: false on the arm topic this often until confirmed
UNKNOWN = "_UNKNOWN_"  # rmw's node name of a publisher whose node is not known yet


class OperatorError(Exception):
    """A command that could not do its job: one line and its exit code."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code


def hardware_deployment(dep: Deployment) -> Deployment:
    """``dep`` if it is a hardware deployment (the twin has no velocity gate).

    Raises:
        ConfigError: a twin deployment.
    """
    if dep.mode != "hardware":
        raise ConfigError(
            "mode", dep.mode, "the twin has no velocity gate: give the robot's deployment"
        )
    return dep


def operator_env(dep: Deployment, folder: Path) -> dict[str, str]:
    """The environment the launcher's nodes get (domain, DDS profile written into
    ``folder``, security), in the operator's enclave."""
    from vigil.dds import deployment_env
    from vigil.security import ENCLAVE_ROOT, security_env

    ros = dep.ros
    env = deployment_env(folder, ros.localhost_only, ros.interfaces, ros.peers)
    env["ROS_DOMAIN_ID"] = str(dep.ros.domain_id)
    if dep.ros.keystore:
        env.update(security_env(dep.resolve(dep.ros.keystore) or dep.ros.keystore))
        env["ROS_SECURITY_ENCLAVE_OVERRIDE"] = f"{ENCLAVE_ROOT}/{OPERATOR_ENCLAVE}"
    return env


@contextmanager
def _environment(env: dict[str, str]) -> Iterator[None]:
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def robot_inputs(dep: Deployment) -> dict[str, Input]:
    """What the stack reads from the robot side (docs/INTERFACES.md): the lidar's scan,
    the base's odometry, the map, the localisation's ``map -> odom`` on ``/tf`` and,
    with ``navigation.pose_source: amcl``, AMCL's pose; label -> :class:`Input`."""
    t = dep.topics
    out = {
        t.scan: Input("scan", t.scan, "the lidar driver"),
        t.odom: Input("odom", t.odom, "the base driver"),
        topic.MAP: Input("map", topic.MAP, "a map server, e.g. nav2's map_server", False),
        f"{MAP_FRAME} -> {ODOM_FRAME}": Input(
            "map_odom", topic.TF, "the localisation on /tf, e.g. nav2's AMCL"
        ),
    }
    if dep.navigation.pose_source == "amcl":  # AMCL publishes it when its filter updates
        pose = dep.navigation.pose_topic or topic.AMCL_POSE
        out[pose] = Input("pose", pose, "AMCL, for navigation.pose_source: amcl", False)
    return out


class Session:
    """One rclpy participant on the deployment's domain that hears the gate, the base,
    navigation and ``/diagnostics``, and can set the gate's parameters."""

    def __init__(self, dep: Deployment, verb: str, robot: bool = False):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Twist
        from rcl_interfaces.srv import GetParameters, SetParameters
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Bool, UInt64

        self._rclpy = rclpy
        self.topics = gate_topics(dep)
        self.heard = Heard(
            dep.ros.domain_id, self.topics["output_topic"], self.topics["input_topic"]
        )
        self.start = time.monotonic()
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=dep.ros.domain_id)
        self.node = rclpy.create_node(
            f"vigil_{verb}_{os.getpid()}", context=self.context, start_parameter_services=False
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        # a listener: best effort matches reliable and best-effort publishers alike and
        # never makes a publisher resend to it
        listen = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        sub = self.node.create_subscription
        sub(DiagnosticArray, self.topics["diagnostics_topic"], self._on_diagnostics, listen)
        sub(UInt64, self.topics["heartbeat_topic"], self._on_beat, listen)
        sub(Twist, self.topics["input_topic"], self._cmd(self.heard.nav_cmds), listen)
        self.base_visible = not dep.ros.keystore  # SROS2: only the base driver may read it
        if self.base_visible:
            sub(Twist, self.topics["output_topic"], self._cmd(self.heard.base_cmds), listen)
        self.arm_pub = self.node.create_publisher(Bool, self.topics["arm_topic"], 10)
        self._bool = Bool
        self.set_client = self.node.create_client(SetParameters, topic.GATE_SET_PARAMETERS)
        self.get_client = self.node.create_client(GetParameters, topic.GATE_GET_PARAMETERS)
        if robot:
            self._listen_robot(robot_inputs(dep), listen)

    def _listen_robot(self, inputs: dict[str, Input], listen: Any) -> None:
        """Hear the robot side's inputs (:func:`robot_inputs`) into ``heard.robot``."""
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import OccupancyGrid, Odometry
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import LaserScan
        from tf2_msgs.msg import TFMessage

        latched = QoSProfile(  # as a map server offers it: the map sent before we joined
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        self.heard.robot = inputs
        types = {"scan": LaserScan, "odom": Odometry, "map": OccupancyGrid,
                 "pose": PoseWithCovarianceStamped}  # fmt: skip
        for i in inputs.values():
            if i.kind == "map_odom":
                self.node.create_subscription(TFMessage, i.topic, self._map_odom(i.times), listen)
            else:
                qos = latched if i.kind == "map" else listen
                self.node.create_subscription(types[i.kind], i.topic, self._stamp(i.times), qos)

    @staticmethod
    def _stamp(into: list[float]) -> Callable[[Any], None]:
        return lambda _msg: into.append(time.monotonic())

    @staticmethod
    def _map_odom(into: list[float]) -> Callable[[Any], None]:
        def on_tf(msg: Any) -> None:
            for t in msg.transforms:
                pair = (t.header.frame_id.lstrip("/"), t.child_frame_id.lstrip("/"))
                if pair == (MAP_FRAME, ODOM_FRAME):
                    into.append(time.monotonic())
                    return

        return on_tf

    # -- what is heard --------------------------------------------------------------
    def _on_diagnostics(self, msg: Any) -> None:
        from stack.ros_msgs import diagnostics_from_msg

        now = time.monotonic()
        for name, entry in diagnostics_from_msg(msg).items():
            self.heard.statuses[name] = entry
            self.heard.status_at[name] = now
            if name == GATE:
                self.heard.gate_reasons.append(str(entry.get("reason", entry["message"])))

    def _on_beat(self, msg: Any) -> None:
        self.heard.beats.append((time.monotonic(), int(msg.data)))

    @staticmethod
    def _cmd(into: list) -> Callable[[Any], None]:
        def on_cmd(msg: Any) -> None:
            cmd = (float(msg.linear.x), float(msg.linear.y), float(msg.angular.z))
            into.append((time.monotonic(), cmd))

        return on_cmd

    # -- spinning -------------------------------------------------------------------
    def spin_until(self, done: Callable[[], bool], deadline: float) -> bool:
        """Spin until ``done()`` holds (True) or the monotonic ``deadline`` passes."""
        while True:
            if done():
                return True
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            self.executor.spin_once(timeout_sec=min(0.05, left))

    def gate_seen(self) -> bool:
        """The gate is discovered: its parameter service matched, or it was heard."""
        h = self.heard
        return self.set_client.service_is_ready() or bool(h.beats) or h.gate_status() is not None

    def call(self, client: Any, request: Any, deadline: float) -> Any | None:
        """A service's response, or None when none came by ``deadline``."""
        future = client.call_async(request)
        if not self.spin_until(future.done, deadline):
            client.remove_pending_request(future)
            return None
        return future.result()

    def set_armed(self, armed: bool, deadline: float) -> Any | None:
        """The gate's SetParametersResult for ``armed``; None without an answer."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter

        request = SetParameters.Request(
            parameters=[Parameter("armed", Parameter.Type.BOOL, armed).to_parameter_msg()]
        )
        response = self.call(self.set_client, request, deadline)
        return None if response is None or not response.results else response.results[0]

    def read_params(self, deadline: float) -> dict[str, Any] | None:
        """The gate's :data:`GATE_PARAMS` (unset ones left out); None without an answer."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        if not self.get_client.service_is_ready():
            return None
        response = self.call(
            self.get_client, GetParameters.Request(names=list(GATE_PARAMS)), deadline
        )
        if response is None:
            return None
        values = {
            n: parameter_value_to_python(v)
            for n, v in zip(GATE_PARAMS, response.values, strict=False)
        }
        self.heard.params = {n: v for n, v in values.items() if v is not None}
        return self.heard.params

    def publish_arm(self, armed: bool) -> None:
        self.arm_pub.publish(self._bool(data=armed))

    def publishers(self, name: str, deadline: float) -> list[str]:
        """The nodes publishing topic ``name``. A participant whose node names have not
        arrived yet shows as ``_NODE_NAME_UNKNOWN_``: asked again until ``deadline``."""

        def names() -> list[str]:
            infos = self.node.get_publishers_info_by_topic(name)
            return [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos]

        found = names()
        while any(UNKNOWN in n for n in found) and time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
            found = names()
        return found

    def base_publishers(self, deadline: float) -> list[str]:
        """The nodes publishing the base's topic (:meth:`publishers`)."""
        self.heard.base_publishers = self.publishers(self.topics["output_topic"], deadline)
        return self.heard.base_publishers

    def robot_streams_heard(self) -> bool:
        """Every robot stream with a publisher in the graph was heard at least once."""
        return all(
            i.times or self.node.count_publishers(i.topic) == 0
            for i in self.heard.robot.values()
            if i.stream
        )

    def robot_publishers(self, deadline: float) -> None:
        """The publishers of each robot input but ``/tf`` (whose publishers say nothing
        about ``map -> odom``)."""
        for i in self.heard.robot.values():
            if i.kind != "map_odom":
                i.publishers = self.publishers(i.topic, deadline)

    def finish(self) -> Heard:
        """The window closes: what was heard, its length and end."""
        self.heard.now = time.monotonic()
        self.heard.window_s = round(self.heard.now - self.start, 1)
        return self.heard

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


@contextmanager
def session(dep: Deployment, verb: str, robot: bool = False) -> Iterator[Session]:
    """A :class:`Session` in the deployment's environment (its DDS profile in a folder of
    this process's own, removed afterwards); ``robot``: it hears the robot's inputs too."""
    from vigil.private_dir import private_dir

    folder = private_dir(f"operator-{os.getpid()}")
    try:
        with _environment(operator_env(hardware_deployment(dep), folder)):
            s = Session(dep, verb, robot)
            try:
                yield s
            finally:
                s.close()
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _where(dep: Deployment) -> str:
    return f"ROS domain {dep.ros.domain_id}"


def expected_caps(dep: Deployment) -> dict[str, float]:
    """The caps the deployment gives the gate (its defaults where the file says none)."""
    from stack.hardware.velocity_gate import GateConfig

    cfg = GateConfig.from_dict(dep.hardware.get("velocity_gate"), "hardware.velocity_gate")
    return {key: float(getattr(cfg, key)) for key in CAPS}


def _confirm(s: Session, armed: bool, deadline: float) -> str | None:
    """How the gate confirmed ``armed`` by ``deadline`` ("status" or "parameter"), or None."""
    if s.spin_until(lambda: s.heard.gate_armed() is armed, deadline):
        return "status"
    params = s.read_params(time.monotonic() + 1.0)
    if params is not None and params.get("armed") is armed:
        return "parameter"
    return None


def arm(
    dep: Deployment,
    timeout_s: float = 5.0,
    wait_s: float = 1.5,
    force: bool = False,
    say: Callable[[str], None] = print,
    warn: Callable[[str], None] = print,
) -> int:
    """Arm the deployment's velocity gate (module docstring); the exit code.

    Raises:
        OperatorError: no gate answered (3), it refused or did not confirm (4), the checks
            refused (5).
    """
    expected = expected_caps(dep)
    with session(dep, "arm") as s:
        service = topic.GATE_SET_PARAMETERS
        if not s.spin_until(s.set_client.service_is_ready, s.start + timeout_s):
            raise OperatorError(
                EXIT_NO_GATE,
                f"no velocity gate answered within {timeout_s:g} s: service {service} not "
                f"found on {_where(dep)} (is `vigil launch` running with this deployment?)",
            )
        # the gate's state (2 Hz) and everyone's diagnostics, for at least wait_s more
        s.spin_until(lambda: False, time.monotonic() + wait_s)
        s.spin_until(lambda: s.heard.gate_status() is not None, time.monotonic() + timeout_s)
        # the camera's status (1 Hz) too: its participant may be discovered after the gate's
        s.spin_until(lambda: CAMERA in s.heard.statuses, time.monotonic() + timeout_s)
        s.read_params(time.monotonic() + timeout_s)
        s.base_publishers(time.monotonic() + 1.0)
        heard = s.finish()
        st = heard.gate_status()
        if st is not None:
            warn(f"vigil arm: the gate says: {'armed' if st.get('armed') else 'disarmed'}, "
                 f"{st.get('reason', st['message'])}")  # fmt: skip
        for note in arm_notes(heard):
            warn(f"vigil arm: note: {note}")
        refusals = arm_refusals(heard, expected)
        if refusals and not force:
            raise OperatorError(
                EXIT_CHECKS, "not arming: " + "; ".join(refusals) + " (--force arms anyway)"
            )
        for r in refusals:
            warn(f"vigil arm: --force: arming despite: {r}")
        result = s.set_armed(True, time.monotonic() + timeout_s)
        if result is None:
            raise OperatorError(
                EXIT_NO_GATE,
                f"the velocity gate did not answer on {service} within {timeout_s:g} s "
                f"({_where(dep)}); the request was sent, so it may still arm: `vigil status` "
                "shows its state, `vigil disarm` makes sure",
            )
        if not result.successful:
            raise OperatorError(EXIT_REFUSED, f"the velocity gate refused: {result.reason}")
        how = _confirm(s, True, time.monotonic() + timeout_s)
        if how is None:
            raise OperatorError(
                EXIT_REFUSED,
                f"the velocity gate accepted armed=true but did not confirm it (no "
                f"{GATE} status armed=true on {s.topics['diagnostics_topic']}, nor the "
                f"parameter read back) within {timeout_s:g} s: `vigil status`",
            )
        s.read_params(time.monotonic() + 1.0)
        caps = dict(heard.gate_status() or {}) | (s.heard.params or {})
    say(
        f"velocity gate armed: caps {caps_text(caps)} ({_where(dep)}; confirmed by its "
        f"{'/diagnostics status' if how == 'status' else 'parameter'}); the next "
        "navigation command moves the base"
    )
    return EXIT_OK


def disarm(
    dep: Deployment,
    timeout_s: float = 5.0,
    say: Callable[[str], None] = print,
) -> int:
    """Disarm the deployment's velocity gate by both ways at once; the exit code.

    Raises:
        OperatorError: nothing confirmed the disarm within ``timeout_s`` (3: no gate
            heard at all; 4: heard, but not confirmed).
    """
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    off = Parameter("armed", Parameter.Type.BOOL, False).to_parameter_msg()
    with session(dep, "disarm") as s:
        deadline = s.start + timeout_s
        future = None
        last_pub = -1e9

        def sent() -> bool:  # at least one way reached the gate
            return last_pub > 0 or (future is not None and future.done())

        while time.monotonic() < deadline and not (s.heard.gate_armed() is False and sent()):
            now = time.monotonic()
            if s.arm_pub.get_subscription_count() > 0 and now - last_pub >= REPEAT_S:
                s.publish_arm(False)  # the gate disarms on either; repeated until confirmed
                last_pub = now
            if future is None and s.set_client.service_is_ready():
                future = s.set_client.call_async(SetParameters.Request(parameters=[off]))
            s.executor.spin_once(timeout_sec=0.05)
        how = "status" if s.heard.gate_armed() is False and sent() else None
        answer = future.result() if future is not None and future.done() else None
        if how is None and answer is not None and answer.results and answer.results[0].successful:
            params = s.read_params(time.monotonic() + 1.0)
            how = "parameter" if params is not None and params.get("armed") is False else None
        heard = s.finish()
        if how is None:
            seen = heard.gate_status() is not None or bool(heard.beats) or future is not None
            raise OperatorError(
                EXIT_REFUSED if seen else EXIT_NO_GATE,
                ("the velocity gate did not confirm the disarm" if seen else
                 "no velocity gate answered") + f" within {timeout_s:g} s on {_where(dep)} "
                f"({topic.GATE_SET_PARAMETERS}, {s.topics['arm_topic']}, "
                f"{s.topics['diagnostics_topic']}): if it runs it may still be ARMED: use the "
                "e-stop",
            )  # fmt: skip
        ways = [
            "parameter" if answer is not None else "",
            s.topics["arm_topic"] if last_pub > 0 else "",
        ]
    say(
        f"velocity gate disarmed: zero velocity ({_where(dep)}; sent by "
        f"{' and '.join(w for w in ways if w)}; confirmed by its "
        f"{'/diagnostics status' if how == 'status' else 'parameter'})"
    )
    return EXIT_OK


def status(
    dep: Deployment,
    wait_s: float = 2.0,
    as_json: bool = False,
    timeout_s: float = 5.0,
    say: Callable[[str], None] = print,
) -> int:
    """Wait up to ``timeout_s`` for the gate to be discovered, listen ``wait_s`` seconds
    more and print the system's state, the robot's inputs included; 0 all OK, 1
    otherwise."""
    import json

    with session(dep, "status", robot=True) as s:
        # DDS discovery of a running participant takes 0-3 s here (its announcements)
        s.spin_until(s.gate_seen, s.start + timeout_s)
        s.spin_until(lambda: False, time.monotonic() + wait_s)
        # a stream whose publisher is known but not yet heard: its first message, within
        # the timeout (a driver discovered late)
        s.spin_until(s.robot_streams_heard, time.monotonic() + timeout_s)
        s.read_params(time.monotonic() + 1.0)
        s.base_publishers(time.monotonic() + 1.0)
        s.robot_publishers(time.monotonic() + 1.0)
        record = status_record(s.finish())
        if not s.base_visible:
            record["base"]["note"] = "not readable from the operator's enclave (SROS2)"
    if dep.source is not None:
        record["deployment"] = str(dep.source)
    if as_json:
        say(json.dumps(record, indent=2, sort_keys=True))
    else:
        for line in status_lines(record):
            say(line)
    return status_exit_code(record)
