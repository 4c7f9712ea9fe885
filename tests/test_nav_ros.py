"""The navigation and speech nodes exchanging real messages over rclpy, in one process.

A small simulator node stands in for the twin: it integrates /cmd_vel with the
kinematic base model and publishes /odom.
"""

import math
import shutil

import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import Twist  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402
from vigil_interfaces.msg import NavGoal, NavResult, PersonObservation, SpeechDone  # noqa: E402

from stack.cells import CellGrid  # noqa: E402
from stack.nav.base_model import KinematicBase  # noqa: E402
from stack.nav.follower import Pose2D, Twist2D  # noqa: E402
from stack.nav.node_navigation import NavigationNode  # noqa: E402
from stack.nav.node_speech import SpeechNode  # noqa: E402
from stack.ros_msgs import (  # noqa: E402
    nav_goal_to_msg,
    nav_result_from_msg,
    observation_to_msg,
    speech_done_from_msg,
)

pytestmark = pytest.mark.ros
GRID = CellGrid()


class SimBase(Node):
    """Integrates /cmd_vel on a kinematic base and publishes /odom; records traffic."""

    def __init__(self, start_xy):
        super().__init__("sim_base")
        self.base = KinematicBase(Pose2D(*start_xy, yaw_rad=0.4))
        self.cmd = Twist2D()
        self.cmds: list[Twist] = []
        self.results: list[dict] = []
        self.speech: list[dict] = []
        self.publish_odom = True
        self.odom_pub = self.create_publisher(Odometry, "/odom", 10)
        self.action_pub = self.create_publisher(NavGoal, "/nav/action", 10)
        self.goal_id = 0
        self.stop_pub = self.create_publisher(Bool, "/stop", 10)
        self.create_subscription(Twist, "/cmd_vel", self.on_cmd, 10)
        self.create_subscription(NavResult, "/nav/result", self.on_result, 10)
        self.create_subscription(SpeechDone, "/speech/done", self.on_speech, 10)
        self.create_timer(0.05, self.on_timer)

    def on_cmd(self, msg: Twist) -> None:
        self.cmds.append(msg)
        self.cmd = Twist2D(msg.linear.x, msg.linear.y, msg.angular.z)

    def act(self, action: str) -> int:
        """Send a goal with the next id (as the planner does); returns the id."""
        self.goal_id += 1
        self.action_pub.publish(nav_goal_to_msg(self.goal_id, action, 0.0))
        return self.goal_id

    def on_result(self, msg: NavResult) -> None:
        self.results.append(nav_result_from_msg(msg))

    def on_speech(self, msg: SpeechDone) -> None:
        self.speech.append(speech_done_from_msg(msg))

    def on_timer(self) -> None:
        pose = self.base.step(self.cmd, 0.05)
        if not self.publish_odom:
            return
        odom = Odometry()
        odom.header.frame_id = "map"
        odom.pose.pose.position.x, odom.pose.pose.position.y = pose.x_m, pose.y_m
        odom.pose.pose.orientation.z = math.sin(pose.yaw_rad / 2)
        odom.pose.pose.orientation.w = math.cos(pose.yaw_rad / 2)
        self.odom_pub.publish(odom)


from rostest import spin_until  # noqa: E402  (the ros fixture: conftest.py)


def test_navigation_node_moves_the_base_to_the_next_cell(ros, tmp_path):
    sim = SimBase(GRID.center(3))
    nav = NavigationNode(
        parameter_overrides=[Parameter("control_rate_hz", value=20.0)],
    )
    for node in (sim, nav):
        ros.add_node(node)
    try:
        assert spin_until(ros, lambda: nav.pose is not None, 5.0), "no odometry reached the node"
        # a bad action: warned about, reported, and the node keeps working
        first = sim.act("Upwards")
        assert spin_until(ros, lambda: len(sim.results) == 1, 3.0)
        assert sim.results[0]["result"] == "refused" and sim.results[0]["goal_id"] == first
        assert sim.results[0]["error_name"] == "INVALID_ACTION"
        # East from cell 3 is cell 1; East again leaves the map and is refused
        east = sim.act("East")
        assert spin_until(ros, lambda: len(sim.results) == 2, 15.0), "no result for East"
        result = sim.results[1]
        assert result["result"] == "succeeded" and result["goal_id"] == east, result
        assert (result["from_cell"], result["target_cell"], result["cell"]) == (3, 1, 1)
        # reported on entering the cell; the robot goes on to settle on its waypoint
        assert result["message"] == "in the target cell"
        assert spin_until(ros, lambda: not nav.follower.active, 10.0), "never settled"
        pose = sim.base.pose
        assert math.dist((pose.x_m, pose.y_m), GRID.center(1)) < 0.1
        assert len(sim.results) == 2  # one result per action
        spin_until(ros, lambda: False, 0.2)
        n_cmds = len(sim.cmds)
        sim.act("East")
        assert spin_until(ros, lambda: len(sim.results) == 3, 3.0)
        assert sim.results[2]["result"] == "refused"
        assert sim.results[2]["error_name"] == "ACTION_LEAVES_MAP"
        assert all(c.linear.x == c.linear.y == 0.0 for c in sim.cmds[n_cmds:])
        # every command within the configured limits
        cfg = nav.config
        assert max(abs(c.linear.x) for c in sim.cmds) <= cfg.max_vx_mps + 1e-9
        assert max(abs(c.linear.y) for c in sim.cmds) <= cfg.max_vy_mps + 1e-9
        # stale pose: odometry stops, so the node commands zero while the task continues
        sim.publish_odom = False
        sim.act("North")
        spin_until(ros, lambda: False, 1.5)
        assert sim.cmds and sim.cmds[-1].linear.x == 0.0 and sim.cmds[-1].linear.y == 0.0
        # /stop cancels it with a result
        sim.stop_pub.publish(Bool(data=True))
        assert spin_until(ros, lambda: len(sim.results) == 4, 3.0)
        assert sim.results[3]["result"] == "canceled"
    finally:
        for node in (sim, nav):
            ros.remove_node(node)
            node.destroy_node()


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="needs espeak-ng")
def test_speech_node_warns_a_person_in_the_restricted_cell_with_the_robot(ros, tmp_path):
    sim = SimBase(GRID.center(1))
    speech = SpeechNode(parameter_overrides=[Parameter("out_dir", value=str(tmp_path))])
    obs_pub = sim.create_publisher(PersonObservation, "/observations", 10)
    for node in (sim, speech):
        ros.add_node(node)

    def observe(robot, person):
        obs_pub.publish(observation_to_msg({"robot": robot, "person": person, "velocity": ""}))

    try:
        spin_until(ros, lambda: False, 0.3)  # discovery
        # robot in 7 (not restricted) with the person: silence; robot in 1, person in 3
        # (only near): silence; a malformed message is skipped
        observe("7", "7")
        observe("1", "3")
        bad = observation_to_msg({"robot": "1", "person": "1", "velocity": ""})
        bad.hidden_cells = [4]  # no fraction for it: malformed, skipped
        obs_pub.publish(bad)
        assert spin_until(ros, lambda: speech.warner.person_cell == 3, 3.0)
        spin_until(ros, lambda: False, 0.3)
        assert sim.speech == []
        observe("1", "1")  # together in restricted cell 1 ...
        spin_until(ros, lambda: False, 0.7)
        assert sim.speech == []
        observe("1", "1")  # ... for confirm_s (0.5 s): warn
        assert spin_until(ros, lambda: len(sim.speech) >= 1, 10.0), "no speech report"
        done = sim.speech[0]
        assert done["kind"] == "finished" and done["voice"] == "en"
        assert done["text"] == speech.config.warning
        assert len(list(tmp_path.glob("*.wav"))) == 1
        assert (tmp_path / "speech_log.tsv").read_text().count("\n") == 2
    finally:
        for node in (sim, speech):
            ros.remove_node(node)
            node.destroy_node()


def test_navigation_node_reads_amcl_pose_and_a_map_file(ros, tmp_path):
    from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: PLC0415

    from stack.cells import ConfigError  # noqa: PLC0415
    from stack.nav.occupancy import OccupancyMap, save_map_yaml  # noqa: PLC0415

    map_yaml = save_map_yaml(OccupancyMap.empty(7.0, 4.0, 0.05, (-0.5, -0.5)), tmp_path / "m.yaml")
    nav = NavigationNode(
        parameter_overrides=[
            Parameter("pose_source", value="amcl"),
            Parameter("map_yaml", value=str(map_yaml)),
        ]
    )
    try:
        subs = {s.topic_name: s.msg_type for s in nav.subscriptions}
        assert subs["/amcl_pose"] is PoseWithCovarianceStamped
        assert "/odom" not in subs and "/map" not in subs
        assert nav.follower.map.shape == (80, 140)
    finally:
        nav.destroy_node()
    with pytest.raises(ConfigError, match="pose_source: 'gps' is invalid"):
        NavigationNode(parameter_overrides=[Parameter("pose_source", value="gps")])


def test_navigate_to_pose_action_goal_feedback_result_cancel_and_reject(ros):
    """Issue 14: the navigation node serves a NavigateToPose-shaped action, the nav2
    way: an action goal drives the robot and ends with its result (also on /nav/result,
    under the same goal id); a pose goal gives feedback and is canceled; a goal in
    another frame is rejected."""
    from action_msgs.msg import GoalStatus
    from rclpy.action import ActionClient
    from vigil_interfaces.action import NavigateToPose

    sim = SimBase(GRID.center(3))
    nav = NavigationNode(parameter_overrides=[Parameter("control_rate_hz", value=20.0)])
    client = ActionClient(sim, NavigateToPose, "navigate_to_pose")
    for node in (sim, nav):
        ros.add_node(node)

    def send(goal, feedback):
        future = client.send_goal_async(goal, feedback_callback=lambda f: feedback.append(f))
        assert spin_until(ros, future.done, 5.0), "no answer to the goal"
        return future.result()

    try:
        assert spin_until(ros, lambda: nav.pose is not None and client.server_is_ready(), 5.0)
        handle = send(NavigateToPose.Goal(action="East"), [])  # cell 3 -> cell 1
        assert handle.accepted
        result = handle.get_result_async()
        assert spin_until(ros, result.done, 15.0), "no result for East"
        r = result.result()
        assert r.status == GoalStatus.STATUS_SUCCEEDED
        assert (r.result.result, r.result.error_code, r.result.cell) == ("succeeded", 0, 1)
        assert r.result.goal_id >= 2**31  # given by the server: never a planner step's
        assert spin_until(
            ros, lambda: sim.results and sim.results[-1]["goal_id"] == r.result.goal_id, 2.0
        )
        # a pose goal far away: feedback while it drives, then canceled
        goal = NavigateToPose.Goal()
        goal.pose.header.frame_id = "map"
        goal.pose.pose.position.x, goal.pose.pose.position.y = GRID.center(12)
        feedback: list = []
        handle = send(goal, feedback)
        assert handle.accepted
        assert spin_until(ros, lambda: len(feedback) >= 1, 10.0), "no feedback"
        fb = feedback[-1].feedback
        assert fb.state and fb.current_pose.header.frame_id == "map"
        assert fb.goal_id >= 2**31 and fb.distance_remaining > 0
        cancel = handle.cancel_goal_async()
        assert spin_until(ros, cancel.done, 5.0)
        result = handle.get_result_async()
        assert spin_until(ros, result.done, 5.0)
        assert result.result().status == GoalStatus.STATUS_CANCELED
        assert result.result().result.result == "canceled"
        assert spin_until(ros, lambda: not nav.follower.active, 2.0)
        # a goal from the planner's topic while an action goal drives: the action goal
        # ends "canceled" (superseded), the topic goal goes on under its own id
        handle = send(goal, [])
        assert handle.accepted and spin_until(ros, lambda: nav.follower.active, 3.0)
        result = handle.get_result_async()
        planner_goal = sim.act("West")
        assert spin_until(ros, result.done, 5.0)
        assert result.result().status == GoalStatus.STATUS_ABORTED
        assert "superseded by goal" in result.result().result.error_msg
        assert spin_until(ros, lambda: sim.results[-1]["goal_id"] == planner_goal, 15.0)
        # a goal in another frame: rejected, the node keeps serving
        goal.pose.header.frame_id = "odom"
        assert not send(goal, []).accepted
    finally:
        client.destroy()
        for node in (sim, nav):
            ros.remove_node(node)
            node.destroy_node()
