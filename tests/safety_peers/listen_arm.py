"""Test helper: subscribe to /arm and /cmd_vel for N seconds, print how many arrived."""

import sys
import time

import rclpy
from geometry_msgs.msg import Twist
from std_msgs.msg import Bool

rclpy.init()
node = rclpy.create_node("listener")
got = {"arm": 0, "cmd_vel": 0}
node.create_subscription(Bool, "/arm", lambda m: got.__setitem__("arm", got["arm"] + 1), 10)
node.create_subscription(
    Twist, "/cmd_vel", lambda m: got.__setitem__("cmd_vel", got["cmd_vel"] + 1), 10
)
print("READY", flush=True)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
print(f"RECEIVED arm={got['arm']} cmd_vel={got['cmd_vel']}", flush=True)
