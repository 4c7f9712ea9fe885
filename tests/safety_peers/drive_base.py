"""Test helper: a base driver's sender, /cmd_vel vx = 0.3 m/s at 20 Hz until killed.

``drive_base.py lockstep`` takes part in lock-step as node ``driver`` (its commands are
counted and it acknowledges every tick), as navigation does in a twin run. It prints
SENDING once its first command is out; the test SIGKILLs it (no last words).
"""

import sys

import rclpy
from geometry_msgs.msg import Twist

from stack.ros_lockstep import Participant

rclpy.init()
node = rclpy.create_node("driver")
part = Participant(node, enabled=sys.argv[1:] == ["lockstep"])
pub = part.publisher(Twist, "/cmd_vel", 10)
said = []


def send() -> None:
    msg = Twist()
    msg.linear.x = 0.3
    pub.publish(msg)
    if not said:
        said.append(print("SENDING", flush=True))


part.timer(0.05, send)
rclpy.spin(node)
