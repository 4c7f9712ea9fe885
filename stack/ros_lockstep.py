"""A node's side of lock-step time (see :mod:`stack.lockstep` for the protocol).

Kept apart from the algorithm packages: only node files import it.

A node builds one :class:`Participant` and creates its publishers and subscriptions
through it. Disabled (real time, the robot), they are the plain rclpy objects.
Enabled, the counts are acknowledged after the subscription callbacks: once per batch
(every callback that was ready when the node woke) under
:class:`stack.ros_main.BatchingExecutor`, as :func:`stack.ros_main.spin_node` spins a
node, else after each callback. Subscriptions are made reliable (a lost message would
stall the twin), and the node's time is the coordinator's ``/clock`` as this
participant last processed it, so a callback reads the same time whatever the
machine's speed. Timers (:meth:`timer`,
:meth:`on_clock`) run on the coordinator's ``/lockstep/tick``, which follows only
once every participant has processed the ``/clock``::

    self.lockstep = Participant(self, enabled=declare(self, lockstep=False).lockstep)
    self.pub = self.lockstep.publisher(Bool, "/out", 10)
    self.lockstep.subscription(Bool, "/in", self.on_in, 10)
    ... self.lockstep.now_s() ...
"""

from __future__ import annotations

import os
import time
import uuid
from collections import defaultdict
from collections.abc import Callable
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from vigil_interfaces.msg import LockstepAck

from stack import topics
from stack.lockstep import ACK_TOPIC, RUN_ID_ENV, TICK_TOPIC
from stack.ros_main import BatchingExecutor
from stack.ros_msgs import ack_to_msg

HEARTBEAT_S = 0.5  # wall clock: re-send the counts (lost acks, matching at start-up)
# A participant's first acknowledgement waits until each of its subscriptions has matched
# the publishers the ROS graph knows of (a topic nobody publishes counts once READY_MIN_S
# have passed, time for discovery), then READY_SETTLE_S more for the publishers' side of
# the match; at most READY_MAX_S. The coordinator takes the first acknowledgement of a
# restarted node as "it hears from now on": a message sent before its subscription
# matched is lost (the QoS is volatile), so an early acknowledgement left the coordinator
# waiting for it until the stall timeout (30 s; seen in CI after the fault test's planner
# restart).
READY_MIN_S = 1.0
READY_SETTLE_S = 0.2
READY_MAX_S = 5.0


def _reliable(qos: QoSProfile | int) -> QoSProfile | int:
    if isinstance(qos, int):
        return qos  # a depth: rclpy makes it reliable
    return QoSProfile(
        depth=max(qos.depth, 10),
        history=qos.history,
        durability=qos.durability,
        reliability=ReliabilityPolicy.RELIABLE,
    )


class _CountingPublisher:
    """A publisher that counts what it sends (same ``publish`` as rclpy's)."""

    def __init__(self, participant: Participant, publisher):
        self._participant = participant
        self._pub = publisher
        self.topic_name = publisher.topic_name

    def publish(self, msg: Any) -> None:
        self._pub.publish(msg)
        self._participant.sent[self.topic_name] += 1
        if not self._participant.in_callback:  # a timer's send: tell the coordinator now
            self._participant.ack()

    def get_subscription_count(self) -> int:
        return self._pub.get_subscription_count()


class Participant:
    """Counts a node's traffic and acknowledges it to the lock-step coordinator.

    Args:
        node: the node.
        enabled: lock-step on; off gives plain publishers and subscriptions.
        clock_topic: the coordinator's clock (subscribed when enabled).
    """

    def __init__(self, node: Node, enabled: bool, clock_topic: str = topics.CLOCK):
        self.node = node
        self.enabled = bool(enabled)
        self.recv: dict[str, int] = defaultdict(int)
        self.sent: dict[str, int] = defaultdict(int)
        self._publishers: list[_CountingPublisher] = []
        self._clock_s: float | None = None
        self._on_clock: list[Callable[[float], None]] = []
        self.incarnation = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.run_id = os.environ.get(RUN_ID_ENV, "")
        self.in_callback = False
        self._ticked_s: float | None = None  # the clock time whose tick was processed
        self._deferred: list[tuple[Callable[[Any], None], Any]] = []
        self._subscriptions: list[Any] = []
        self._made_s = time.monotonic()
        self._matched_s: float | None = None  # when every subscription first had a publisher
        self.ready = False  # acknowledging (see READY_MAX_S)
        self._dirty = False  # counts changed since the last acknowledgement (a batch's)
        self._hooked: BatchingExecutor | None = None  # the executor that flushes them
        # the publishers' subscription counts, as last asked: the coordinator and the bag
        # read them only before the first tick, so after it they are asked on heartbeats
        self._matched: dict[str, int] = {}
        if not self.enabled:
            return
        self._ack_pub = node.create_publisher(LockstepAck, ACK_TOPIC, 50)
        self.subscription(ClockMsg, clock_topic, self._clock_cb, 10, internal=True)
        self.subscription(ClockMsg, TICK_TOPIC, self._tick_cb, 10, internal=True)
        wall = Clock(clock_type=ClockType.STEADY_TIME)
        node.create_timer(HEARTBEAT_S, self._heartbeat, clock=wall)

    # -- time -------------------------------------------------------------------------
    def now_s(self) -> float:
        """Lock-step: the last processed ``/clock``; otherwise the node's clock."""
        if self.enabled:
            return self._clock_s if self._clock_s is not None else 0.0
        return self.node.get_clock().now().nanoseconds * 1e-9

    def on_clock(self, callback: Callable[[float], None]) -> None:
        """Call ``callback(t_s)`` on every lock-step clock tick (a timer's stand-in)."""
        self._on_clock.append(callback)

    def timer(self, period_s: float, callback: Callable[[], None]) -> None:
        """A periodic callback: on lock-step clock ticks (simulated time) when enabled,
        else an rclpy timer on the node's clock."""
        if not self.enabled:
            self.node.create_timer(period_s, callback)
            return
        due: list[float] = []  # the next due time, once the first tick has come

        def on_tick(t_s: float) -> None:
            if not due:
                due.append(t_s)
            if t_s + 1e-9 >= due[0]:
                while due[0] <= t_s + 1e-9:
                    due[0] += period_s
                callback()

        self._on_clock.append(on_tick)

    def _clock_cb(self, msg: ClockMsg) -> None:
        self._clock_s = msg.clock.sec + msg.clock.nanosec * 1e-9

    def _tick_cb(self, msg: ClockMsg) -> None:
        self._clock_s = msg.clock.sec + msg.clock.nanosec * 1e-9
        self._ticked_s = self._clock_s
        for cb in self._on_clock:
            cb(self._clock_s)
        # what another node's timer sent before this node's own timers ran: now, in order
        deferred, self._deferred = self._deferred, []
        for run, m in deferred:
            run(m)

    def _tick_pending(self) -> bool:
        """A new /clock came and its tick (this node's timers) has not run yet."""
        return self._clock_s is not None and self._ticked_s != self._clock_s

    # -- traffic ----------------------------------------------------------------------
    def publisher(self, msg_type, topic: str, qos: QoSProfile | int):
        pub = self.node.create_publisher(msg_type, topic, qos)
        if not self.enabled:
            return pub
        counting = _CountingPublisher(self, pub)
        self._publishers.append(counting)
        return counting

    def subscription(
        self,
        msg_type,
        topic: str,
        callback: Callable,
        qos: QoSProfile | int,
        internal=False,
        raw: bool = False,
    ):
        """A subscription whose messages are counted (lock-step) or a plain one.

        In the tick phase, a message that arrives before this node has run its own
        timers for the tick (another node's timer was quicker) is held back and handled
        right after them: every node runs its timers first and then what the others'
        timers sent, whichever process the machine happened to schedule first.
        ``raw``: the callback gets the serialized bytes (a recorder).
        """
        if not self.enabled:
            return self.node.create_subscription(msg_type, topic, callback, qos, raw=raw)
        holder: dict[str, str] = {}

        def run(msg) -> None:
            self.in_callback = True
            try:
                callback(msg)
            finally:
                self.in_callback = False
                self.recv[holder["topic"]] += 1
                self.ack_soon()

        def counted(msg) -> None:
            if not internal and self._tick_pending():
                self._deferred.append((run, msg))  # counted once handled
                return
            run(msg)

        sub = self.node.create_subscription(msg_type, topic, counted, _reliable(qos), raw=raw)
        holder["topic"] = sub.topic_name
        self._subscriptions.append(sub)
        self.recv[sub.topic_name] += 0  # declare the subscription in every ack
        return sub

    def _check_ready(self) -> bool:
        """Every subscription has matched a publisher where the graph knows one
        (READY_SETTLE_S ago), or READY_MAX_S have passed since the participant was made
        (then the topics still unmatched are logged: a QoS mismatch, say)."""
        now = time.monotonic()
        young = now - self._made_s < READY_MIN_S
        unmatched = [
            s.topic_name
            for s in self._subscriptions
            if s.get_publisher_count() == 0
            and (young or self.node.count_publishers(s.topic_name) > 0)
        ]
        if unmatched:
            self._matched_s = None
            if now - self._made_s < READY_MAX_S:
                return False
            self.node.get_logger().warning(
                f"lock-step: acknowledging after {READY_MAX_S:g} s without a match on "
                + ", ".join(unmatched)
                + " (the graph has publishers: is the QoS compatible?)"
            )
        elif self._matched_s is None:
            self._matched_s = now
            return False
        elif now - self._matched_s < READY_SETTLE_S:
            return False
        self.ready = True
        return True

    def ack_soon(self) -> None:
        """Acknowledge the counts once the executor has run the rest of the batch
        (:class:`stack.ros_main.BatchingExecutor`), or now under another executor.

        One acknowledgement for a batch is as safe as one a callback: it is sent after
        every callback of the batch, and shows every send of a callback whose receive
        it shows (:mod:`stack.lockstep`); the coordinator only sees it later."""
        executor = self.node.executor
        if not isinstance(executor, BatchingExecutor):
            self.ack()
            return
        if self._hooked is not executor:
            self._hooked = executor
            executor.before_wait.append(self._flush)
        self._dirty = True

    def _flush(self) -> None:
        if self._dirty:
            self._dirty = False
            self.ack()

    def _heartbeat(self) -> None:
        self._matched = {}  # asked again
        self.ack()

    def _matched_counts(self) -> dict[str, int]:
        if not self._matched or self._clock_s is None:
            self._matched = {p.topic_name: p.get_subscription_count() for p in self._publishers}
        return self._matched

    def ack(self) -> None:
        if not self.enabled:
            return
        if not self.ready and not self._check_ready():
            return  # counted all the same: the first acknowledgement carries them
        self._dirty = False
        try:
            ack = ack_to_msg(
                self.node.get_name(),
                self.incarnation,
                self.run_id,
                self.recv,
                self.sent,
                self._matched_counts(),
            )
            self._ack_pub.publish(ack)
        except Exception:  # a callback finishing while Ctrl-C shuts the context down
            if self.node.context.ok():
                raise
