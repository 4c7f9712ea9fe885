"""The table player: a thesis table's observations, entered as the thesis entered them.

Chapter 5's simulation (table 5.1) fed the planner observations by hand. This node
stands in for navigation and perception: every ``/nav/action`` is reported done at
once on ``/nav/result`` (in the row's robot cell), and every
``/observations/request`` is answered on ``/observations`` with the next row of the
table (robot cell, person cell, velocity). The planner node is the real one.

Parameters: ``table`` ("5.1" ... "5.4", :data:`stack.planning.replay.TABLES`).
"""

from __future__ import annotations

from rclpy.node import Node
from std_msgs.msg import Empty
from vigil_interfaces.msg import NavGoal, NavResult, PersonObservation

import stack.topics as topic
from stack.cells import ConfigError
from stack.planning.replay import TABLES
from stack.ros_main import spin_node
from stack.ros_msgs import nav_goal_from_msg, nav_result_to_msg, observation_to_msg
from stack.ros_params import declare


class TablePlayerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("table_player", **kwargs)
        name = declare(self, table="5.1").table
        if name not in TABLES:
            raise ConfigError("table", name, f"must be one of {sorted(TABLES)}")
        self.rows = TABLES[name].steps
        self.row = 0
        self.pub_result = self.create_publisher(NavResult, topic.NAV_RESULT, 10)
        self.pub_obs = self.create_publisher(PersonObservation, topic.OBSERVATIONS, 10)
        self.create_subscription(NavGoal, topic.NAV_ACTION, self.on_action, 10)
        self.create_subscription(Empty, topic.OBSERVATIONS_REQUEST, self.on_request, 10)
        self.get_logger().info(f"table {name}: {len(self.rows)} rows of observations")

    def _current(self):
        return self.rows[min(self.row, len(self.rows) - 1)]

    def on_action(self, msg: NavGoal) -> None:
        try:
            goal_id, action = nav_goal_from_msg(msg)
        except ValueError as err:
            self.get_logger().warning(f"goal ignored: {err}")
            return
        body = {
            "goal_id": goal_id,
            "result": "succeeded",
            "error_code": 0,
            "error_name": "NONE",
            "message": "table row",
            "action": action,
            "cell": self._current().robot,
        }
        self.pub_result.publish(nav_result_to_msg(body))

    def on_request(self, _msg: Empty) -> None:
        if self.row >= len(self.rows):
            self.get_logger().warning("the table has no more rows: repeating the last")
        st = self._current()
        obs = {
            "robot": str(st.robot),
            "person": "No person" if st.person is None else str(st.person),
            "velocity": st.velocity,
            "source": f"table row {self.row + 1}",
        }
        self.row += 1
        self.pub_obs.publish(observation_to_msg(obs))


def main(args=None) -> None:
    spin_node(TablePlayerNode, args)


if __name__ == "__main__":
    main()
