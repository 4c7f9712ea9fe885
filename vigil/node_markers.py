"""The markers node: what RViz and Foxglove draw of a running system (issue 14).

Publishes a ``visualization_msgs/MarkerArray`` on ``/vigil/markers`` twice a second:
the grid, the restricted cells and cell numbers, the planner's belief (cells shaded by
P(person there), P(no person)), the robot's likely cell and the people the camera and
the laser see (:mod:`stack.visualization` makes the markers; this node only adapts).

Subscribes: ``/planner/belief`` (the planner's marginals, vigil_interfaces/Belief),
``/perception/person`` (the camera's people, vigil_interfaces/CameraPerson) and
``/perception/leg_people`` (the laser's people, ``geometry_msgs/PoseArray``). Messages
that do not convert (:mod:`stack.ros_msgs`) are logged and ignored; the last good
ones are drawn.

Parameters: ``task_file`` (the grid and the restricted cells), ``rate_hz`` (2.0).
``config/foxglove-layout.json`` is a Foxglove layout showing these markers over the
map, the scan and the camera image.
"""

from __future__ import annotations

from typing import Any

from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, PoseArray
from rclpy.node import Node
from vigil_interfaces.msg import Belief, CameraPerson
from visualization_msgs.msg import Marker, MarkerArray

from stack import topics as topic
from stack.cells import CellGrid, ConfigError
from stack.ros_main import spin_node
from stack.ros_msgs import belief_from_msg, camera_from_msg
from stack.ros_params import declare
from stack.visualization import MarkerSpec, scene_markers


def marker_msg(spec: MarkerSpec, stamp) -> Marker:
    """One Marker message from its spec."""
    m = Marker()
    m.header.frame_id = spec.frame_id
    m.header.stamp = stamp
    m.ns, m.id, m.type, m.action = spec.ns, spec.id, spec.type, spec.action
    m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in spec.position)
    m.pose.orientation.w = 1.0
    m.scale.x, m.scale.y, m.scale.z = (float(v) for v in spec.scale)
    m.color.r, m.color.g, m.color.b, m.color.a = (float(v) for v in spec.colour)
    m.points = [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in spec.points]
    m.text = spec.text
    m.lifetime = Duration(sec=0)  # until replaced (the array starts with DELETEALL)
    return m


def _positions(data: Any) -> list[tuple[float, float]]:
    """Finite (x, y) positions from a person record or a list of them."""
    items = data if isinstance(data, list) else [data]
    out = []
    for item in items:
        pos = item.get("position_m") if isinstance(item, dict) else None
        if isinstance(pos, list | tuple) and len(pos) == 2:
            try:
                x, y = float(pos[0]), float(pos[1])
            except (TypeError, ValueError):
                continue
            if abs(x) < 1e6 and abs(y) < 1e6:  # finite and sane
                out.append((x, y))
    return out


class MarkersNode(Node):
    """Draws the grid, the belief and the people as markers."""

    def __init__(self, **kwargs):
        super().__init__("markers", **kwargs)
        from stack.planning.task import load_task

        v = declare(self, task_file="", rate_hz=2.0)
        task_file, rate_hz = v.task_file, v.rate_hz
        if not rate_hz > 0:
            raise ConfigError("rate_hz", rate_hz, "must be > 0")
        if task_file:
            task = load_task(task_file)
            self.grid, self.restricted = task.grid, tuple(task.restricted_cells)
        else:
            self.grid, self.restricted = CellGrid(), ()
        self.belief: dict[str, Any] | None = None
        self.camera_people: list[tuple[float, float]] = []
        self.leg_people: list[tuple[float, float]] = []
        self.pub = self.create_publisher(MarkerArray, topic.MARKERS, 2)
        self.create_subscription(Belief, topic.PLANNER_BELIEF, self.on_belief, 10)
        self.create_subscription(CameraPerson, topic.PERSON, self.on_person, 10)
        self.create_subscription(PoseArray, topic.LEG_PEOPLE, self.on_legs, 10)
        self.create_timer(1.0 / rate_hz, self.publish)

    def _ignored(self, what: str, err: Exception) -> None:
        self.get_logger().warning(f"{what} ignored: {err}", throttle_duration_sec=10.0)

    def on_belief(self, msg: Belief) -> None:
        try:
            self.belief = belief_from_msg(msg)
        except ValueError as err:
            self._ignored("belief", err)

    def on_person(self, msg: CameraPerson) -> None:
        try:
            data = camera_from_msg(msg)
        except ValueError as err:
            self._ignored("camera person", err)
            return
        people = [{"position_m": q} for q in data["people_m"]]  # several people: all
        self.camera_people = _positions(people or data)

    def on_legs(self, msg: PoseArray) -> None:
        self.leg_people = _positions(
            [{"position_m": [p.position.x, p.position.y]} for p in msg.poses]
        )

    def publish(self) -> None:
        specs = scene_markers(
            self.grid, self.restricted, self.belief, self.camera_people + self.leg_people
        )
        stamp = self.get_clock().now().to_msg()
        self.pub.publish(MarkerArray(markers=[marker_msg(s, stamp) for s in specs]))


def main(args=None) -> None:
    spin_node(MarkersNode, args)


if __name__ == "__main__":
    main()
