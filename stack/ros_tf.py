"""TF on ROS: ``tf2_msgs/TFMessage`` on ``/tf`` and ``/tf_static`` to and from the core.

Kept apart from the algorithm packages (like :mod:`stack.ros_lockstep`): only node files
import it. The core is :mod:`stack.tf`; ``tf2_msgs`` is built in the set-up step
(``interfaces/``, upstream's definition).

QoS as tf2_ros: ``/tf`` reliable, volatile, depth 100; ``/tf_static`` reliable, transient
local, depth 1 per publisher (a late subscriber still gets every static transform) and
depth 100 for the listener (with depth 1 it keeps only the last of the publishers'
samples that arrive together: measured, the bridge's laser was lost to the camera's).

Both topics go through the node's lock-step :class:`~stack.ros_lockstep.Participant`:
counted like every other topic, so a consumer has the transforms of a tick before the
twin steps on.
"""

from __future__ import annotations

from collections.abc import Callable

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from stack import topics as topic
from stack.geometry import Pose2D
from stack.lockstep import stamp_parts
from stack.tf import (
    BASE_LINK,
    MAP,
    PendingLookup,
    StampedTransform,
    TfBuffer,
    TfError,
    TfTimeout,
    Transform,
)

TF_QOS = QoSProfile(
    depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE
)
TF_STATIC_QOS = QoSProfile(
    depth=1,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
TF_STATIC_LISTENER_QOS = QoSProfile(
    depth=100,
    history=HistoryPolicy.KEEP_LAST,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def _stamp(t_s: float) -> Time:
    sec, nanosec = stamp_parts(t_s)
    return Time(sec=sec, nanosec=nanosec)


def to_msg(st: StampedTransform) -> TransformStamped:
    """geometry_msgs/TransformStamped of a core transform."""
    msg = TransformStamped()
    msg.header.stamp, msg.header.frame_id = _stamp(st.stamp_s), st.parent
    msg.child_frame_id = st.child
    t, q = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = st.transform.translation
    q.x, q.y, q.z, q.w = st.transform.rotation
    return msg


def from_msg(msg: TransformStamped) -> StampedTransform:
    """The core transform of a message.

    Raises:
        ValueError: not finite, or not a unit quaternion.
    """
    t, q = msg.transform.translation, msg.transform.rotation
    return StampedTransform(
        msg.header.frame_id.lstrip("/"),
        msg.child_frame_id.lstrip("/"),
        msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9,
        Transform((t.x, t.y, t.z), (q.x, q.y, q.z, q.w)),
    )


def tf_message(transforms: list[StampedTransform]) -> TFMessage:
    return TFMessage(transforms=[to_msg(st) for st in transforms])


def tf_publishers(participant, static: bool = True, dynamic: bool = True):
    """(``/tf`` publisher or None, ``/tf_static`` publisher or None), through the
    participant so that lock-step counts them."""
    pub = participant.publisher(TFMessage, topic.TF, TF_QOS) if dynamic else None
    spub = participant.publisher(TFMessage, topic.TF_STATIC, TF_STATIC_QOS) if static else None
    return pub, spub


class TfListener:
    """Fills a :class:`~stack.tf.TfBuffer` from ``/tf`` and ``/tf_static``.

    A malformed transform is skipped with a warning naming it; the node keeps running.
    ``on_update`` (optional) is called after each message has been added.
    """

    def __init__(
        self,
        participant,
        buffer: TfBuffer | None = None,
        on_update: Callable[[], None] | None = None,
    ):
        self.buffer = buffer if buffer is not None else TfBuffer()
        self._node = participant.node
        self._on_update = on_update
        participant.subscription(TFMessage, topic.TF, self._on_tf, TF_QOS)
        participant.subscription(
            TFMessage, topic.TF_STATIC, self._on_static, TF_STATIC_LISTENER_QOS
        )

    def _add(self, msg: TFMessage, static: bool) -> None:
        for m in msg.transforms:
            try:
                self.buffer.set_transform(from_msg(m), static=static)
            except ValueError as err:
                self._node.get_logger().warning(
                    f"transform {m.header.frame_id!r} -> {m.child_frame_id!r} skipped: {err}",
                    throttle_duration_sec=5.0,
                )
        if self._on_update is not None:
            self._on_update()

    def _on_tf(self, msg: TFMessage) -> None:
        self._add(msg, static=False)

    def _on_static(self, msg: TFMessage) -> None:
        self._add(msg, static=True)


class MapPose:
    """The robot's pose in the map through TF (``map <- base_link``), for consumer nodes.

    Each time ``/tf`` or ``/tf_static`` brings a newer time at which the whole chain is
    known, ``on_pose(stamp_s, pose)`` is called with the pose at that time. While the
    chain is incomplete nothing is called; after ``timeout_s`` (of the participant's
    clock) without it, a warning names the missing link, and the wait starts again.
    """

    def __init__(
        self,
        participant,
        on_pose: Callable[[float, Pose2D], None],
        timeout_s: float = 1.0,
        map_frame: str = MAP,
        base_frame: str = BASE_LINK,
    ):
        self._participant = participant
        self._on_pose = on_pose
        self.listener = TfListener(participant, on_update=self._update)
        self.buffer = self.listener.buffer
        self._frames = (map_frame, base_frame)
        self._lookup = PendingLookup(self.buffer, map_frame, base_frame, timeout_s)
        self._last_s: float | None = None
        self._timeout_s = timeout_s
        participant.timer(timeout_s, self._check_stale)

    def _check_stale(self) -> None:
        """Warn when the chain stops moving: a localisation or odometry that went quiet
        leaves lookups at the last common time, and consumers would get no new pose."""
        now = self._participant.now_s()
        try:
            stalest = self.buffer.stalest_link(*self._frames)
        except TfError:
            return  # incomplete chain: the pending lookup's timeout names the missing link
        if stalest is not None and now - stalest[2] > self._timeout_s:
            parent, child, stamp_s = stalest
            self._participant.node.get_logger().warning(
                f"TF {self._frames[0]} <- {self._frames[1]} is stale: {parent} -> {child} "
                f"last heard at {stamp_s:.2f} s, {now - stamp_s:.1f} s ago (no new pose)",
                throttle_duration_sec=5.0,
            )

    def _update(self) -> None:
        try:
            tf = self._lookup.poll(self._participant.now_s())
        except TfTimeout as err:
            self._participant.node.get_logger().warning(str(err), throttle_duration_sec=5.0)
            return
        if tf is None:
            return
        t = self.buffer.latest_common_time(*self._frames)
        stamp_s = self._participant.now_s() if t is None else t
        if stamp_s == self._last_s:
            return  # a message that did not move the chain's latest time (a static one)
        self._last_s = stamp_s
        self._on_pose(stamp_s, tf.to_pose2d())
