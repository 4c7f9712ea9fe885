"""The hardware side of the deployment switch: the real ceiling camera and the robot's drivers.

On the real robot (no twin) the same stack runs against the AXIS P1344 ceiling camera
(:mod:`stack.hardware.camera_stream`, node ``camera_stream``) and the robot's own base
driver behind a velocity safety gate (:mod:`stack.hardware.velocity_gate`, node
``velocity_gate``). The pure modules never import rclpy; each ``node_*.py`` adapts them.
See docs/HARDWARE.md.
"""
