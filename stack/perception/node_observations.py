"""The observations node: one combined observation per decision step for the planner.

Subscribes (names are parameters):
    ``/perception/person`` vigil_interfaces/CameraPerson: the camera people node's state.
    ``/perception/legs`` vigil_interfaces/LegTracks: the legs node's tracks with speeds.
    ``/odom`` nav_msgs/Odometry: the robot's pose in the map frame; with
        ``pose_source: tf`` instead ``/tf`` and ``/tf_static`` (``map <- base_link``:
        on a robot, where odometry drifts from the map).
    ``/observations/request`` std_msgs/Empty: publish an observation now (the planner
        asks when the robot has finished its action).

Publishes (every ``decision_period_s`` and on request):
    ``/observations`` vigil_interfaces/PersonObservation: the planner's labels, e.g.
        robot "7", person "9", velocity "East higher", with the person's position, the
        speed, the hidden cells and (several people) one label pair per person slot.
    with ``label_topics`` (off by default): ``/observations/robot``,
        ``/observations/person``, ``/observations/velocity`` std_msgs/String: the three
        labels on their own; ``/observations/direction``, ``/observations/speed``: the
        two components of the velocity, as the thesis published them ("East",
        "higher"; "Not moving", "Not moving"). The typed message carries all of it.

Freshness is judged on this node's clock at reception, so publishers' stamps need
not share its clock. Parameters: ``config_file`` (optional ``grid``, ``observations``
and ``visibility`` sections), ``calibration_file`` (the camera's; with it the cells the
robot hides from the camera are known, see :mod:`stack.perception.visibility`),
``lockstep`` (see :mod:`stack.ros_lockstep`), ``pose_source`` (odom | tf),
``tf_timeout_s`` (1.0), ``label_topics`` (false), ``decision_period_s`` (0: only on
request), ``people`` (the task's; 2 or more adds ``"people"``: one {person,
velocity} per person slot, slot 0 first, from
:class:`stack.perception.multi.PeoplePerception` on the camera's
``people_m`` and the laser tracks; docs/PERCEPTION.md), topic names. A message that
cannot be used is logged and skipped; the node never dies of one.
"""

from __future__ import annotations

from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import Empty, String
from vigil_interfaces.msg import CameraPerson, LegTracks, PersonObservation

import stack.topics as topic
from stack.cells import ConfigError
from stack.perception.errors import PerceptionError
from stack.perception.legs import Pose2D
from stack.perception.messages import camera_state_from_dict, pose_from_msg, tracks_from_dict
from stack.perception.observation import NOT_MOVING
from stack.perception.observer import Observer
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node
from stack.ros_msgs import camera_from_msg, legs_from_msg, observation_to_msg
from stack.ros_params import declare, declare_topics
from stack.ros_tf import MapPose

# the thesis's one-label topics, ``/observations/<name>`` (``label_topics``)
LABELS = ("robot", "person", "velocity", "direction", "speed")


class ObservationsNode(Node):
    """Joins camera, laser and pose into the planner's observation."""

    def __init__(self, **kwargs):
        super().__init__("observations", **kwargs)
        v = declare(
            self,
            config_file="",
            calibration_file="",
            decision_period_s=1.0,
            pose_source="odom",
            tf_timeout_s=1.0,
            lockstep=False,
            people=1,
            label_topics=False,
        )
        calibration_file, period_s = v.calibration_file, v.decision_period_s
        if v.pose_source not in ("odom", "tf"):
            raise ConfigError("pose_source", v.pose_source, "must be odom or tf")
        topics = declare_topics(
            self,
            person=topic.PERSON,
            legs=topic.LEGS,
            odom=topic.ODOM,
            request=topic.OBSERVATIONS_REQUEST,
            observations=topic.OBSERVATIONS,
        )
        if period_s < 0:
            raise ConfigError("decision_period_s", period_s, "must be >= 0")
        self.core = Observer(
            v.config_file, calibration_file, v.people, on_error=self.get_logger().error
        )
        ls = self.lockstep = Participant(self, v.lockstep)
        base = topics["observations"]
        self.pub = ls.publisher(PersonObservation, base, 10)
        self.label_pubs = {
            name: ls.publisher(String, f"{base}/{name}", 10)
            for name in (LABELS if v.label_topics else ())
        }
        ls.subscription(CameraPerson, topics["person"], self.on_person, 10)
        ls.subscription(LegTracks, topics["legs"], self.on_legs, 10)
        if v.pose_source == "tf":
            self.map_pose = MapPose(ls, self.on_map_pose, v.tf_timeout_s)
        else:
            ls.subscription(Odometry, topics["odom"], self.on_odom, 20)
        ls.subscription(Empty, topics["request"], lambda _msg: self.publish_now(), 10)
        if period_s > 0:
            ls.timer(period_s, self.publish_now)

    def _now_s(self) -> float:
        return self.lockstep.now_s()

    def on_person(self, msg: CameraPerson) -> None:
        try:
            self.core.on_camera(camera_state_from_dict(camera_from_msg(msg), self._now_s()))
        except (ValueError, PerceptionError) as err:
            self.get_logger().warning(f"person message ignored: {err}", throttle_duration_sec=5.0)

    def on_legs(self, msg: LegTracks) -> None:
        try:
            self.core.on_tracks(tracks_from_dict(legs_from_msg(msg), self._now_s()))
        except (ValueError, TypeError) as err:
            self.get_logger().warning(f"legs message ignored: {err}", throttle_duration_sec=5.0)

    def on_odom(self, msg: Odometry) -> None:
        try:
            self.core.on_pose(pose_from_msg(msg.pose.pose))
        except ValueError as err:
            self.get_logger().warning(f"pose ignored: {err}", throttle_duration_sec=5.0)

    def on_map_pose(self, stamp_s: float, pose: Pose2D) -> None:
        """The map pose through TF (``pose_source: tf``)."""
        self.core.on_pose(pose)

    def publish_now(self) -> None:
        try:
            obs, record = self.core.observe(self._now_s())
        except (ValueError, ArithmeticError) as err:  # never die of one bad input
            self.get_logger().error(f"observation skipped: {err}", throttle_duration_sec=5.0)
            return
        self.pub.publish(observation_to_msg(record))
        if not self.label_pubs:
            return
        labels = {
            "robot": obs.robot_label,
            "person": obs.person_label,
            "velocity": obs.velocity_label,
            "direction": obs.direction.label,
            "speed": NOT_MOVING if obs.speed is None else obs.speed.label,
        }
        for name, text in labels.items():
            self.label_pubs[name].publish(String(data=text))


def main(args=None) -> None:
    spin_node(ObservationsNode, args)


if __name__ == "__main__":
    main()
