"""The bag player: the lock-step coordinator of ``vigil replay-bag`` (:mod:`vigil.replay_bag`).

It takes the twin bridge's place for the replayed nodes: a :class:`stack.lockstep.Ledger`
of their acknowledgements, and per recorded tick ``/clock`` -> wait -> ``/lockstep/tick``
-> wait -> each recorded message of the tick -> wait, where "wait" is the lock-step's
quiescence (every replayed node has processed every message sent, its own included), so
the machine's load changes only how long the replay takes, never what the nodes see.

What is fed: the topics the replayed nodes subscribe to (their acknowledgements list
them) and do not publish themselves, as the recorded CDR bytes with a publisher of the
recorded type (looked up by name: :func:`vigil.bag.message_class`), so the player works
with any message types. A recorded type other than the one a node now subscribes with is
an error (a bag of another vigil version).

Runs in the ``vigil replay-bag`` process (:func:`play`), not as a launched node.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from vigil_interfaces.msg import LockstepAck

import stack.topics as topic
from stack.lockstep import ACK_TOPIC, TICK_TOPIC, Ack, Ledger
from stack.ros_msgs import ack_from_msg
from vigil.bag import Recording, ReplayError, message_class

PROGRESS_S = 1.0
ALIVE_S = 1.0


def _stamp(t_ns: int) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
    return msg


class BagPlayer(Node):
    """Publishes the clock, the ticks and the recorded messages; counts the acks."""

    def __init__(self, run_id: str, expected: tuple[str, ...], **kwargs):
        super().__init__("bag_player", **kwargs)
        self.ledger = Ledger(expected, run_id=run_id)
        self.heard_s = time.monotonic()
        self.create_subscription(LockstepAck, ACK_TOPIC, self.on_ack, 100)
        self.pub_clock = self.create_publisher(Clock, topic.CLOCK, 10)
        self.pub_tick = self.create_publisher(Clock, TICK_TOPIC, 10)
        self.pubs: dict[str, object] = {}
        self.fed: dict[str, int] = {}

    def on_ack(self, msg: LockstepAck) -> None:
        try:
            ack = Ack.from_dict(ack_from_msg(msg))
        except ValueError as err:
            self.get_logger().warning(f"ack ignored: {err}", throttle_duration_sec=5.0)
            return
        if self.ledger.update(ack, time.monotonic()):
            self.heard_s = time.monotonic()

    def inputs(self) -> list[str]:
        """What the replayed nodes read and do not write (besides the clock and ticks)."""
        read: set[str] = set()
        written: set[str] = set()
        for m in self.ledger.members.values():
            read |= set(m.ack.recv)
            written |= set(m.ack.matched) | set(m.ack.sent)
        return sorted(read - written - {topic.CLOCK, TICK_TOPIC})

    def add_input(self, name: str, type_name: str) -> None:
        """A publisher for ``name`` of the recorded type, with a QoS its readers take."""
        subs = self.get_subscriptions_info_by_topic(name)
        for s in subs:
            if s.topic_type != type_name:
                raise ReplayError(
                    f"the bag's {name} is {type_name} but node {s.node_name} reads "
                    f"{s.topic_type}: the bag was recorded by another version of vigil"
                )
        latched = any(s.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for s in subs)
        qos = QoSProfile(
            depth=100,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )
        try:
            cls = message_class(type_name)
        except (ImportError, AttributeError, ValueError) as err:
            raise ReplayError(f"{name}: no message class for {type_name} ({err})") from err
        self.pubs[name] = self.create_publisher(cls, name, qos)
        self.fed[name] = 0

    def own_matched(self) -> dict[str, int]:
        pubs = [self.pub_clock, self.pub_tick, *self.pubs.values()]
        return {p.topic_name: p.get_subscription_count() for p in pubs}  # type: ignore[attr-defined]

    def send(self, name: str, data) -> None:
        pub = self.pubs[name] if name in self.pubs else None
        if name == topic.CLOCK:
            pub = self.pub_clock
        elif name == TICK_TOPIC:
            pub = self.pub_tick
        pub.publish(data)  # type: ignore[union-attr]  # a message or the recorded CDR bytes
        self.ledger.sent(name)
        if name in self.fed:
            self.fed[name] += 1

    def steps(self) -> int:
        """Step records the replayed planner has published."""
        m = self.ledger.members.get("planner")
        return m.ack.sent.get(topic.PLANNER_STEP, 0) if m is not None else 0


def play(
    recording: Recording,
    expected: tuple[str, ...],
    run_id: str,
    domain_id: int,
    steps: int,
    alive: Callable[[], bool],
    stall_s: float,
    say: Callable[[str], None] = print,
) -> dict[str, int]:
    """Play ``recording`` into the ``expected`` lock-step participants until they have
    made ``steps`` step records (or the recording ends). Returns the messages fed per
    topic.

    Raises:
        ReplayError: a node died (``alive()`` false), or no acknowledgement came for
            ``stall_s`` wall seconds while waiting (names what was pending).
    """
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    node = BagPlayer(run_id, expected, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ledger = node.ledger
    state = {"alive_s": time.monotonic(), "shown_s": time.monotonic(), "t_ns": 0}
    total_t = recording.ticks[-1].t_ns
    started: list[bool] = []  # empty until the nodes are up and matched

    def wait(done: Callable[[], bool], what: Callable[[], str]) -> None:
        while not done():
            ex.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if now - state["alive_s"] > ALIVE_S:
                state["alive_s"] = now
                if not alive():
                    raise ReplayError("a replayed node stopped (see its log in the replay folder)")
            if now - node.heard_s > stall_s:
                raise ReplayError(f"replay stalled for {stall_s:.0f} s: {what()}")
            if now - state["shown_s"] >= PROGRESS_S:
                state["shown_s"] = now
                if not started:
                    say(f"[replay-bag] starting: {what()}")
                else:
                    say(
                        f"[replay-bag] t={state['t_ns'] / 1e9:.2f}/{total_t / 1e9:.2f} s, "
                        f"step {node.steps()}/{steps}, {sum(node.fed.values())} messages fed"
                    )

    def quiet() -> None:
        wait(ledger.quiescent, lambda: "waiting for " + ", ".join(ledger.pending()))

    try:
        wait(
            lambda: not ledger.missing(),
            lambda: "waiting for the nodes " + ", ".join(ledger.missing()),
        )
        inputs = node.inputs()
        absent = [t for t in inputs if t not in recording.types]
        for name in inputs:
            if name in recording.types:
                node.add_input(name, recording.types[name])
        say(
            "[replay-bag] feeding "
            + ", ".join(f"{t} ({recording.count(t)})" for t in node.pubs)
            + (f"; not in the bag: {', '.join(absent)}" if absent else "")
        )
        wait(
            lambda: not ledger.unmatched(node.own_matched()) and ledger.quiescent(),
            lambda: (
                "matching " + ", ".join(ledger.unmatched(node.own_matched()) + ledger.pending())
            ),
        )
        started.append(True)
        for name, cdr in recording.before:
            if name in node.pubs:
                node.send(name, cdr)
                quiet()
        for tick in recording.ticks:
            state["t_ns"] = tick.t_ns
            node.send(topic.CLOCK, _stamp(tick.t_ns))
            quiet()
            node.send(TICK_TOPIC, _stamp(tick.t_ns))
            quiet()
            for name, cdr in tick.messages:
                if name in node.pubs:
                    node.send(name, cdr)
                    quiet()
            if node.steps() >= steps:
                break
        say(
            f"[replay-bag] played to t={state['t_ns'] / 1e9:.2f} s: "
            f"{node.steps()} steps replayed, {sum(node.fed.values())} messages fed"
        )
        return dict(node.fed)
    finally:
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
