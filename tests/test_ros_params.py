"""The one parameter helper every node declares its parameters through."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros


def test_declare_gives_overrides_and_defaults_typed(ros):
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from stack.ros_params import declare, declare_topics

    node = Node(
        "params_probe",
        parameter_overrides=[
            Parameter("rate_hz", value=5.0),
            Parameter("lockstep", value=True),
            Parameter("cmd_vel_topic", value="/robot/cmd_vel"),
        ],
    )
    try:
        v = declare(node, config_file="", rate_hz=20.0, lockstep=False, steps=3)
        assert (v.config_file, v.rate_hz, v.lockstep, v.steps) == ("", 5.0, True, 3)
        assert type(v.steps) is int and type(v.rate_hz) is float
        topics = declare_topics(node, cmd_vel="/cmd_vel", result="/nav/result")
        assert topics == {"cmd_vel": "/robot/cmd_vel", "result": "/nav/result"}
        # the parameters exist under their ROS names (a deployment file sets them so)
        assert node.get_parameter("cmd_vel_topic").value == "/robot/cmd_vel"
        assert node.get_parameter("result_topic").value == "/nav/result"
    finally:
        node.destroy_node()


def test_declare_refuses_a_value_of_another_type(ros):
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from stack.ros_params import declare

    node = Node("params_probe2", parameter_overrides=[Parameter("rate_hz", value="fast")])
    try:
        with pytest.raises(InvalidParameterTypeException):
            declare(node, rate_hz=20.0)
    finally:
        node.destroy_node()
