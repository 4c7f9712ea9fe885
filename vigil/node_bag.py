"""The bag node: records a run's topics into a rosbag2 bag (MCAP), ``<out_dir>/bag``
(``bag_1``... when that exists: a restarted node never overwrites a bag).

Raw subscriptions (``raw=True``): each message arrives as its CDR bytes and goes into
the bag as it is (:class:`vigil.bag.BagWriter`), never deserialised. A topic is
subscribed once it appears in the ROS graph (checked every ``DISCOVER_S``), with the type
its publishers advertise and a QoS that matches them (best effort when one publishes
best effort, transient local when all of them are latched; a topic with no publisher
known yet waits, so ``/tf_static`` arrives).

Log time: with lock-step, see below; else with ``sim_clock``, the latest ``/clock``
(simulated time, 0 before the first), so the bag plays in the run's own time; without it
(hardware) the wall clock until a ``/clock`` arrives.

Lock-step (the twin, ``lockstep: true``): the bag is a participant, so that the bag
holds every message in the lock-step phase it was sent in, whatever the machine's load
(what ``vigil replay-bag`` needs to re-enact the run). It waits until every other
participant (``participants``) has been heard on ``/lockstep/ack`` and the graph shows
the publishers of the topics they publish (their acks list them) and of ``/clock``,
subscribes to every wanted topic that has a publisher then, and only then acknowledges
(the twin waits for it before its first tick, so no counted message is missed); then it
stops listening to the acks. Its log
time is the lock-step clock, made strictly increasing by one nanosecond per message, so
the bag's order is the order the bag received the messages in; every ``/lockstep/tick``
is written (a ``rosgraph_msgs/Clock``) before the messages of that tick. A counted topic
that appears after the start, and ``/vigil/markers`` (not counted), are recorded without
being acknowledged. Without lock-step (a robot) the bag sends no acks: a slow disk cannot
slow the run (it may only fall behind). Camera frames are kept to one per
``camera_period_s`` of log time.
SIGINT (the launcher's stop) closes the bag cleanly (:func:`stack.ros_main.spin_node`
destroys the node); a SIGKILLed recorder leaves an MCAP without its summary and no
``metadata.yaml`` (``vigil bag-reindex`` salvages its complete messages,
:mod:`vigil.bag_salvage`). A full disk: the writer holds a reserve (:data:`RESERVE_BYTES`) that
it frees to write the summary and ``metadata.yaml``; the node stops recording, closes
the bag and exits :data:`stack.exits.EXIT_DISK_FULL` (issue 23).

Parameters: ``out_dir``, ``camera_period_s`` (1.0; 0 keeps every frame), ``sim_clock``,
``lockstep``, ``participants`` (the other lock-step participants' node names).
"""

from __future__ import annotations

import time
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from vigil_interfaces.msg import LockstepAck

import stack.topics as topic
from stack.cells import ConfigError
from stack.lockstep import Ack, stamp_parts
from stack.ros_lockstep import Participant
from stack.ros_main import Releasing, spin_node
from stack.ros_msgs import ack_from_msg
from stack.ros_params import declare
from vigil.bag import BagError, BagWriter, RateLimit, fresh_path, message_class

DISCOVER_S = 0.5
RESERVE_BYTES = 4 << 20  # room for the summary and metadata.yaml of a bag on a full disk
# what a run shows (sensors, TF, perception, planner, navigation, speech, truth)
TOPICS = (
    topic.TF,
    topic.TF_STATIC,
    topic.SCAN,
    topic.MAP,
    topic.ODOM,
    topic.CMD_VEL,
    topic.CAMERA_IMAGE,
    topic.CAMERA_INFO,
    topic.PERSON,
    topic.PERSON_POSITION,
    topic.LEGS,
    topic.LEG_PEOPLE,
    topic.OBSERVATIONS,
    topic.PLANNER_BELIEF,
    topic.PLANNER_STEP,
    topic.PLANNER_DONE,
    topic.NAV_ACTION,
    topic.NAV_PROGRESS,
    topic.NAV_RESULT,
    topic.SPEECH_WARNING,
    topic.SPEECH_DONE,
    topic.SPEECH_SPEAKING,
    topic.TWIN_TRUTH,
    topic.MARKERS,
    topic.DIAGNOSTICS,  # the hardware nodes' health (none in the twin)
)
RATE_LIMITED = (topic.CAMERA_IMAGE,)
UNCOUNTED = (topic.MARKERS,)  # published by a node outside the lock-step
TICK_TYPE = "rosgraph_msgs/msg/Clock"  # the type of the /lockstep/tick records


class BagNode(Releasing, Node):
    """Every topic of :data:`TOPICS` into ``<out_dir>/bag``."""

    def __init__(self, **kwargs):
        super().__init__("bag", **kwargs)
        v = declare(
            self,
            out_dir="runs/recording",
            camera_period_s=1.0,
            sim_clock=False,
            lockstep=False,
            participants=[""],
        )
        if v.camera_period_s < 0:
            raise ConfigError("camera_period_s", v.camera_period_s, "must be >= 0")
        out = Path(v.out_dir)
        out.mkdir(parents=True, exist_ok=True)
        self.bag = BagWriter(fresh_path(out), reserve_bytes=RESERVE_BYTES)
        self.limits = {t: RateLimit(int(v.camera_period_s * 1e9)) for t in RATE_LIMITED}
        # the twin's time: 0 until its first /clock, never the wall clock mixed in
        self.clock_ns: int | None = 0 if v.sim_clock else None
        self.subs: dict[str, object] = {}
        # lock-step: a participant once the others are up (None until then)
        self.lockstep: Participant | None = None
        self.waiting_for = {n for n in v.participants if n and n != self.get_name()}
        self.announced: set[str] = set()  # wanted topics the participants say they publish
        self.last_ns = -1
        self.started = False  # lock-step: subscribed and acknowledged
        self.ack_sub = None  # lock-step: the others' acks, read only until the bag starts
        if v.lockstep:
            self.ack_sub = self.create_subscription(
                LockstepAck, topic.LOCKSTEP_ACK, self.on_ack, 50
            )
        else:
            self.create_subscription(Clock, topic.CLOCK, self.on_clock, 10)
        self.want_lockstep = bool(v.lockstep)
        self.create_timer(DISCOVER_S, self.discover)
        self.get_logger().info(f"recording a bag into {self.bag.path}")

    def on_clock(self, msg: Clock) -> None:
        self.clock_ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec

    def on_ack(self, msg: LockstepAck) -> None:
        try:
            ack = Ack.from_dict(ack_from_msg(msg))
        except ValueError:
            return
        self.waiting_for.discard(ack.node)
        self.announced |= set(ack.matched) & set(TOPICS)

    def now_ns(self) -> int:
        if self.lockstep is not None:  # the lock-step clock, strictly increasing
            t_ns = max(round(self.lockstep.now_s() * 1e9), self.last_ns + 1)
            self.last_ns = t_ns
            return t_ns
        return self.clock_ns if self.clock_ns is not None else time.time_ns()

    def on_tick(self, t_s: float) -> None:
        """A lock-step tick: its record goes before the tick's messages."""
        sec, nsec = stamp_parts(t_s)
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = sec, nsec
        self.bag.write(topic.LOCKSTEP_TICK, self.now_ns(), serialize_message(msg))

    def discover(self) -> None:
        """Subscribe to the wanted topics that have appeared since the last look.

        Lock-step: nothing until every other participant has been heard and the publishers
        of the wanted topics they announce (their acks' ``matched``) and of ``/clock`` are
        in the graph; then one pass subscribes to every wanted topic with a publisher and
        the bag joins the lock-step.
        """
        if self.want_lockstep and self.lockstep is None:
            # every participant heard, and every topic they publish (and the
            # coordinator's clock) seen in the graph: then one pass finds them all
            unseen = [
                t
                for t in sorted(self.announced) + [topic.CLOCK]
                if not self.get_publishers_info_by_topic(t)
            ]
            if self.waiting_for or unseen:
                return
            self.lockstep = Participant(self, True)
            self.bag.add_topic(topic.LOCKSTEP_TICK, TICK_TYPE)
            self.lockstep.on_clock(self.on_tick)
        graph = dict(self.get_topic_names_and_types())
        for name in TOPICS:
            if name in self.subs or not graph.get(name):
                continue
            pubs = self.get_publishers_info_by_topic(name)
            if not pubs:  # only subscribers known yet: wait to match the publishers' QoS
                continue
            type_name = graph[name][0]
            try:
                cls = message_class(type_name)
                self.bag.add_topic(name, type_name)
            except (BagError, ImportError, AttributeError, ValueError) as exc:
                self.subs[name] = None  # said once, not retried
                self.get_logger().warning(f"{name} ({type_name}) not recorded: {exc}")
                continue
            qos = _qos(pubs)
            if self.lockstep is not None and name not in UNCOUNTED and not self.started:
                self.subs[name] = self.lockstep.subscription(
                    cls, name, self._recorder(name), qos, raw=True
                )
            else:
                self.subs[name] = self.create_subscription(
                    cls, name, self._recorder(name), qos, raw=True
                )
        if self.lockstep is not None and not self.started:
            self.started = True
            self.lockstep.ack()
            if self.ack_sub is not None:  # every participant's ack from now on: unread
                self.destroy_subscription(self.ack_sub)
                self.ack_sub = None

    def _recorder(self, name: str):
        limit = self.limits.get(name)

        def record(data: bytes) -> None:
            t_ns = self.now_ns()
            if limit is not None and not limit.admit(t_ns):
                return
            self.bag.write(name, t_ns, data)  # a full disk ends the node (spin_node)

        return record

    def _release(self) -> None:
        """Close the bag, once (:class:`stack.ros_main.Releasing`): before the middleware's
        teardown, whose alarm must not cut a bag's index short."""
        self.bag.close()
        counts = ", ".join(f"{k} {n}" for k, n in sorted(self.bag.counts.items()))
        self.get_logger().info(f"bag closed: {counts}")


def _qos(pubs) -> QoSProfile:
    """A subscription QoS that matches every publisher (latched ones included)."""
    best_effort = any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in pubs)
    latched = bool(pubs) and all(
        p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in pubs
    )
    return QoSProfile(
        depth=100 if latched else 20,
        history=HistoryPolicy.KEEP_LAST,
        reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def main(args=None) -> None:
    spin_node(BagNode, args)


if __name__ == "__main__":
    main()
