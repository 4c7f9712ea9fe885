"""The markers node publishes the grid, the belief and the people (issue 14)."""

import math
from pathlib import Path

import pytest

pytest.importorskip("visualization_msgs")
from geometry_msgs.msg import Pose, PoseArray  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from vigil_interfaces.msg import Belief  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from stack import topics as topic  # noqa: E402
from stack.ros_msgs import belief_to_msg  # noqa: E402
from vigil.node_markers import MarkersNode  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def test_markers_follow_the_belief_and_people_and_survive_junk(ros):
    import rclpy

    node = MarkersNode(
        parameter_overrides=[
            Parameter("task_file", value=str(REPO / "config" / "task-r2.yaml")),
            Parameter("rate_hz", value=20.0),
        ]
    )
    probe = rclpy.create_node("probe")
    got: list[MarkerArray] = []
    probe.create_subscription(MarkerArray, topic.MARKERS, got.append, 10)
    belief = probe.create_publisher(Belief, topic.PLANNER_BELIEF, 10)
    legs = probe.create_publisher(PoseArray, topic.LEG_PEOPLE, 10)
    ros.add_node(node)
    ros.add_node(probe)
    try:
        junk = belief_to_msg({"person": {"5": 0.9}}, 1, 0.0)
        junk.variables[0].probabilities = [float("nan"), 0.5]  # ignored, the node keeps running
        belief.publish(junk)
        marginals = {"person": {"5": 0.9, "No person": 0.1}, "robot": {"7": 1.0}}
        belief.publish(belief_to_msg(marginals, 1, 0.0))
        pose = Pose()
        pose.position.x, pose.position.y = 2.5, 0.7
        legs.publish(PoseArray(poses=[pose]))
        for _ in range(200):
            ros.spin_once(timeout_sec=0.05)
            last = got[-1] if got else None
            if (
                last
                and any(m.ns == "people" for m in last.markers)
                and any(m.ns == "belief" and m.id == 5 and m.color.a > 0.5 for m in last.markers)
            ):
                break
        assert got, "no MarkerArray published"
        ms = got[-1].markers
        assert ms[0].action == Marker.DELETEALL
        restricted = sorted(m.id for m in ms if m.ns == "restricted")
        assert restricted == [1, 12]  # task r2's restricted cells
        (person,) = [m for m in ms if m.ns == "people"]
        assert math.isclose(person.pose.position.x, 2.5) and person.header.frame_id == "map"
        shade = {m.id: m.color.a for m in ms if m.ns == "belief" and m.type == Marker.CUBE}
        assert shade[5] == pytest.approx(0.8) and shade[3] == 0.0
        assert any(m.text == "P(no person) 0.10" for m in ms)
    finally:
        for n in (node, probe):
            ros.remove_node(n)
            n.destroy_node()
