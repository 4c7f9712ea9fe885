"""The navigation node: the planner's action (or a goal pose) in, ``/cmd_vel`` out.

Subscribes (names are parameters):
    ``/nav/action`` vigil_interfaces/NavGoal: the planner's goal, an action ("North",
        "South", "East", "West", "Do nothing") and its ``goal_id``.
    ``/nav/action_id`` std_msgs/Int32: an action as a :class:`stack.cells.Direction`
        number (an operator's; its result has goal id 0).
    ``/goal_pose`` geometry_msgs/PoseStamped: a goal in the map frame (orientation ignored).
    pose: ``/odom`` nav_msgs/Odometry (twin) or ``/amcl_pose``
        geometry_msgs/PoseWithCovarianceStamped (robot), or ``/tf`` and ``/tf_static``
        (``map <- base_link``, any localisation that fills REP-105), chosen by
        ``pose_source``.
    ``/map`` nav_msgs/OccupancyGrid (transient local), unless ``map_yaml`` is given.
    ``/perception/leg_people`` geometry_msgs/PoseArray: people's positions in the map
        frame (the leg detector's tracks).
    ``/stop`` std_msgs/Bool: true stops at once and cancels; goals are refused until false.

Publishes:
    ``/cmd_vel`` geometry_msgs/Twist: body-frame (vx, vy, wz), capped at the limits.
    ``/nav/progress`` vigil_interfaces/NavProgress: {goal_id, state,
        distance_remaining_m, replans, message, cell}.
    ``/nav/result`` vigil_interfaces/NavResult: {goal_id, result, error_code, error_name,
        message, action, from_cell, target_cell, cell}; one per action or goal, including
        Do nothing (succeeded at once) and refused actions; ``goal_id`` is the goal's.

Serves (nav2's way, issue 14):
    ``navigate_to_pose`` vigil_interfaces/action/NavigateToPose: a goal is an action
        (vigil's ``action`` field: "North"... as on ``/nav/action``) or, when ``action`` is
        empty, nav2's ``pose`` (map frame); feedback with each progress (pose, time,
        distance, replans, state); the result (nav2's error code: 0, 9003 timeout, 9000
        otherwise; vigil's ``result`` and ``cell``); cancel stops the robot and ends the
        goal "canceled". A newer goal (from the action or the topics) ends the one under
        way: status aborted, result "canceled" ("superseded by goal N"). The server gives
        each goal its id, from 2^31 up, never a planner step's nor one in use (a
        client's ``goal_id`` is ignored); the id is the goal's on ``/nav/progress`` and
        ``/nav/result`` too. The planner does not use the action: it sends goals on
        ``/nav/action`` and reads ``/nav/result``, the lock-stepped pair (an action's
        services and status topics are outside the lock-step's counts, so the twin
        would no longer be deterministic; docs/INTERFACES.md). A nav2 stack replaces this
        node with a remap of the action (and its type) for goals sent through it.

Parameters: ``config_file`` (YAML with optional ``grid`` and ``follower`` sections),
``pose_source`` (odom | amcl | tf), ``tf_timeout_s`` (1.0), ``pose_topic`` (empty: the
source's default),
``map_yaml``, ``control_rate_hz``, ``progress_rate_hz``, ``action_name``
(``navigate_to_pose``), ``free_map_margin_m`` (the free
map used when there is no map), ``map_frame``, ``lockstep`` (see :mod:`stack.ros_lockstep`:
the control loop then runs on simulated clock ticks).
"""

from __future__ import annotations

from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped, Twist
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from std_msgs.msg import Bool, Int32
from vigil_interfaces.action import NavigateToPose
from vigil_interfaces.msg import NavGoal, NavProgress, NavResult

import stack.topics as topic
from stack.cells import CellGrid, ConfigError
from stack.geometry import Pose2D, yaw_from_quaternion
from stack.nav.config import FollowerConfig, read_node_config
from stack.nav.executor import ActionExecutor, Output
from stack.nav.follower import ZERO_TWIST, Twist2D
from stack.nav.occupancy import MapError, OccupancyMap, from_occupancy_grid, load_map_yaml
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node
from stack.ros_msgs import (
    nav_action_feedback_to_msg,
    nav_action_goal_from_msg,
    nav_action_result_to_msg,
    nav_goal_from_msg,
    nav_progress_to_msg,
    nav_result_to_msg,
)
from stack.ros_params import declare, declare_topics
from stack.ros_tf import MapPose

POSE_SOURCES = {"odom": topic.ODOM, "amcl": topic.AMCL_POSE, "tf": topic.TF}
ACTION_GOAL_ID_BASE = 1 << 31  # ids given to action goals that bring none (nav2 clients)


def twist_to_msg(cmd: Twist2D) -> Twist:
    msg = Twist()
    msg.linear.x, msg.linear.y, msg.angular.z = cmd.vx_mps, cmd.vy_mps, cmd.wz_radps
    return msg


def occupancy_from_msg(msg: OccupancyGrid) -> OccupancyMap:
    """Convert a nav_msgs/OccupancyGrid (raises MapError when malformed)."""
    info = msg.info
    return from_occupancy_grid(
        msg.data,
        info.width,
        info.height,
        info.resolution,
        (info.origin.position.x, info.origin.position.y),
        yaw_from_quaternion(info.origin.orientation),
    )


def load_config_file(path: str) -> tuple[CellGrid, FollowerConfig]:
    """Read the ``grid`` and ``follower`` sections of a YAML file (both optional).

    Raises:
        ConfigError: unreadable file or an invalid value.
    """
    return read_node_config(path, "follower", FollowerConfig)


class NavigationNode(Node):
    """Turns actions into waypoints and follows A* paths to them."""

    def __init__(self, **kwargs):
        super().__init__("navigation", **kwargs)
        v = declare(
            self,
            config_file="",
            pose_source="odom",
            tf_timeout_s=1.0,
            pose_topic="",
            map_yaml="",
            control_rate_hz=20.0,
            progress_rate_hz=2.0,
            free_map_margin_m=1.0,
            map_frame="map",
            lockstep=False,
            action_name=topic.NAVIGATE_TO_POSE,
        )
        source, pose_topic, map_yaml = v.pose_source, v.pose_topic, v.map_yaml
        rate_hz, progress_hz, margin_m = v.control_rate_hz, v.progress_rate_hz, v.free_map_margin_m
        self.map_frame = v.map_frame
        topics = declare_topics(
            self,
            action=topic.NAV_ACTION,
            action_id=topic.NAV_ACTION_ID,
            goal=topic.GOAL_POSE,
            map=topic.MAP,
            people=topic.LEG_PEOPLE,
            stop=topic.STOP,
            cmd_vel=topic.CMD_VEL,
            progress=topic.NAV_PROGRESS,
            result=topic.NAV_RESULT,
        )
        if source not in POSE_SOURCES:
            raise ConfigError("pose_source", source, f"must be one of {sorted(POSE_SOURCES)}")
        if not rate_hz > 0 or not progress_hz > 0:
            raise ConfigError("control_rate_hz", (rate_hz, progress_hz), "rates must be > 0")
        self.grid, self.config = load_config_file(v.config_file)
        if map_yaml:
            occ_map = load_map_yaml(map_yaml)
        else:  # until /map arrives: free floor around the cells, so the robot can still move
            w, h = self.grid.size_m
            x0, y0 = self.grid.origin_m
            occ_map = OccupancyMap.empty(
                w + 2 * margin_m, h + 2 * margin_m, 0.05, (x0 - margin_m, y0 - margin_m)
            )
        self.core = ActionExecutor(
            self.grid, self.config, occ_map, max(1, round(rate_hz / progress_hz))
        )

        ls = self.lockstep = Participant(self, v.lockstep)
        self.cmd_pub = ls.publisher(Twist, topics["cmd_vel"], 10)
        self.progress_pub = ls.publisher(NavProgress, topics["progress"], 10)
        self.result_pub = ls.publisher(NavResult, topics["result"], 10)
        ls.subscription(NavGoal, topics["action"], self.on_action, 10)
        ls.subscription(Int32, topics["action_id"], self.on_action_id, 10)
        ls.subscription(PoseStamped, topics["goal"], self.on_goal, 10)
        ls.subscription(PoseArray, topics["people"], self.on_people, 10)
        ls.subscription(Bool, topics["stop"], self.on_stop, 10)
        if source == "tf":
            self.map_pose = MapPose(ls, self.on_map_pose, v.tf_timeout_s, self.map_frame)
        else:
            pose_topic = pose_topic or POSE_SOURCES[source]
            pose_type = Odometry if source == "odom" else PoseWithCovarianceStamped
            ls.subscription(pose_type, pose_topic, self.on_pose, 10)
        if not map_yaml:
            latched = QoSProfile(
                depth=1,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
                reliability=ReliabilityPolicy.RELIABLE,
            )
            ls.subscription(OccupancyGrid, topics["map"], self.on_map, latched)
        ls.timer(1.0 / rate_hz, self.on_timer)
        # the NavigateToPose action: goal id -> (its result's future, handle, start time)
        self._action_goals: dict[int, tuple[Future, object, float]] = {}
        self._next_action_id = ACTION_GOAL_ID_BASE
        self.action_server = ActionServer(
            self,
            NavigateToPose,
            v.action_name,
            execute_callback=self.execute_goal,
            goal_callback=self.on_goal_request,
            cancel_callback=self.on_cancel_request,
        )
        self.get_logger().info(
            f"navigation: pose from {pose_topic} ({source}), map "
            f"{map_yaml or topics['map']}, {rate_hz:g} Hz"
        )

    # -- inputs --------------------------------------------------------------
    def now_s(self) -> float:
        return self.lockstep.now_s()

    @property
    def follower(self):
        return self.core.follower

    @property
    def pose(self) -> Pose2D | None:
        return self.core.pose

    def on_pose(self, msg) -> None:
        pose = msg.pose.pose
        yaw = yaw_from_quaternion(pose.orientation)
        self.emit(self.core.set_pose(Pose2D(pose.position.x, pose.position.y, yaw), self.now_s()))

    def on_map_pose(self, stamp_s: float, pose: Pose2D) -> None:
        """The map pose through TF (``pose_source: tf``)."""
        self.emit(self.core.set_pose(pose, self.now_s()))

    def on_people(self, msg: PoseArray) -> None:
        self.core.set_people([(p.position.x, p.position.y) for p in msg.poses])

    def on_map(self, msg: OccupancyGrid) -> None:
        try:
            occ_map = occupancy_from_msg(msg)
        except MapError as exc:
            self.get_logger().warning(f"ignoring a malformed map: {exc}")
            return
        self.core.set_map(occ_map)
        self.get_logger().info(f"map {occ_map.shape[1]}x{occ_map.shape[0]} received")

    def on_stop(self, msg: Bool) -> None:
        self.emit(self.core.stop(bool(msg.data)))

    def on_action_id(self, msg: Int32) -> None:
        self.emit(self.core.action(int(msg.data), self.now_s()))

    def on_action(self, msg: NavGoal) -> None:
        try:
            goal_id, action = nav_goal_from_msg(msg)
        except ValueError as err:
            self.get_logger().warning(f"navigation goal ignored: {err}")
            return
        self.emit(self.core.action(action, self.now_s(), goal_id))

    def on_goal(self, msg: PoseStamped) -> None:
        frame = msg.header.frame_id
        if frame and frame != self.map_frame:
            self.get_logger().warning(f"ignoring goal in frame {frame!r}, need {self.map_frame!r}")
            return
        self.emit(self.core.goal(msg.pose.position.x, msg.pose.position.y, self.now_s()))

    def on_timer(self) -> None:
        self.emit(self.core.tick(self.now_s()))

    # -- the NavigateToPose action ---------------------------------------------
    def on_goal_request(self, goal) -> GoalResponse:
        try:
            nav_action_goal_from_msg(goal, self.map_frame)
        except ValueError as err:
            self.get_logger().warning(f"NavigateToPose goal rejected: {err}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def on_cancel_request(self, handle) -> CancelResponse:
        for goal_id, (_, h, _) in self._action_goals.items():
            if h is handle:
                self.emit(self.core.cancel(goal_id, "canceled by the action client"))
        return CancelResponse.ACCEPT

    async def execute_goal(self, handle):
        goal = nav_action_goal_from_msg(handle.request, self.map_frame)  # checked on accept
        # the server gives the id (a client's own could be a planner step's, or one in use)
        while self._next_action_id in self._action_goals:
            self._next_action_id += 1
        goal_id, self._next_action_id = self._next_action_id, self._next_action_id + 1
        if handle.is_cancel_requested:  # canceled before it started: never move for it
            handle.canceled()
            return nav_action_result_to_msg({"goal_id": goal_id, "result": "canceled",
                                             "error_name": "CANCELED",
                                             "message": "canceled before it started"})  # fmt: skip
        done: Future = Future()
        now = self.now_s()
        self._action_goals[goal_id] = (done, handle, now)
        if "action" in goal:
            self.emit(self.core.action(goal["action"], now, goal_id))
        else:
            self.emit(self.core.goal(goal["x"], goal["y"], now, goal_id))
        if goal_id != self.core.goal_id and not done.done():  # the core refused it outright
            done.set_result({"goal_id": goal_id, "result": "refused", "error_name": "INVALID",
                             "message": "goal not started"})  # fmt: skip
        body = await done
        self._action_goals.pop(goal_id, None)
        if body.get("result") == "succeeded":
            handle.succeed()
        elif handle.is_cancel_requested:
            handle.canceled()
        else:
            handle.abort()
        return nav_action_result_to_msg(body)

    def _action_outputs(self, o: Output) -> None:
        """A result or progress of an action goal: its future, its feedback."""
        goal_id = (o.body or {}).get("goal_id")
        entry = self._action_goals.get(goal_id) if goal_id is not None else None
        if entry is None:
            return
        done, handle, start_s = entry
        if o.kind == "result" and not done.done():
            done.set_result(o.body)
        elif o.kind == "progress":
            p = self.core.pose
            pose = None if p is None else (p.x_m, p.y_m, p.yaw_rad)
            handle.publish_feedback(  # type: ignore[attr-defined]
                nav_action_feedback_to_msg(o.body, pose, self.now_s() - start_s)
            )

    def _supersede(self) -> None:
        """Action goals that are no longer the one under way end "canceled"."""
        for goal_id, (done, _, _) in self._action_goals.items():
            if goal_id != self.core.goal_id and not done.done():
                done.set_result({"goal_id": goal_id, "result": "canceled",
                                 "error_name": "CANCELED",
                                 "message": f"superseded by goal {self.core.goal_id}"})  # fmt: skip

    # -- outputs -------------------------------------------------------------
    def emit(self, outputs: list[Output]) -> None:
        for o in outputs:
            if o.kind == "cmd":
                self.cmd_pub.publish(twist_to_msg(o.cmd))
            elif o.kind == "result":
                self.result_pub.publish(nav_result_to_msg(o.body, self.now_s()))
                self._action_outputs(o)
            elif o.kind == "progress":
                self.progress_pub.publish(nav_progress_to_msg(o.body, self.now_s()))
                self._action_outputs(o)
            elif o.kind == "log":
                self.get_logger().warning(o.text, throttle_duration_sec=1.0)
        if self._action_goals:
            self._supersede()


def stop_base(node: NavigationNode) -> None:
    """The node's last words: leave the base standing still on the way out."""
    node.cmd_pub.publish(twist_to_msg(ZERO_TWIST))


def main(args=None) -> None:
    spin_node(NavigationNode, args, on_exit=stop_base)


if __name__ == "__main__":
    main()
