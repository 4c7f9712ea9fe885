"""Test helper: an intruder publishing /arm true and /cmd_vel at 10 Hz for N seconds."""

import sys
import time

import rclpy
from geometry_msgs.msg import Twist
from std_msgs.msg import Bool

rclpy.init()
node = rclpy.create_node("intruder")
arm = node.create_publisher(Bool, "/arm", 10)
cmd = node.create_publisher(Twist, "/cmd_vel", 10)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    arm.publish(Bool(data=True))
    t = Twist()
    t.linear.x = 0.5
    cmd.publish(t)
    rclpy.spin_once(node, timeout_sec=0.1)
print("MATCHED", arm.get_subscription_count(), flush=True)
