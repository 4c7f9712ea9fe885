"""QoS chosen per topic, in one place (ROS side: only node files import it).

Camera frames (:data:`FRAME_QOS`): reliable, keep the last 2. A 640x400 rgb8 frame is
768 kB, a dozen UDP fragments; best effort loses the whole frame with any lost
fragment (what the AXIS camera's frames suffered), reliable repairs it, and a depth of
2 keeps a slow detector on the newest frames rather than a growing queue. The
publishers (camera_stream, the twin bridge) are reliable too; a best-effort
subscriber would match them but drop frames.

Laser scans stay on ``qos_profile_sensor_data`` (best effort): lidar drivers commonly
publish best effort, which a reliable subscriber would not match at all, and a scan is
small (one datagram). Latched topics (``/map``) are reliable + transient local.
See docs/SAFETY.md.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

FRAME_QOS = QoSProfile(
    depth=2,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
