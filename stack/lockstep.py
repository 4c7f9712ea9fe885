"""Lock-step time: the twin advances only when the stack has consumed what it sent.

Pure bookkeeping, no rclpy (the ROS side is :mod:`stack.ros_lockstep`).

The protocol counts messages. Every lock-step participant (a stack node) keeps, per
topic, how many messages it has *received and fully processed* and how many it has
*sent*, and after each callback publishes both counts in an acknowledgement. A
callback's sends are counted before its receive is acknowledged, so one
acknowledgement that shows a message as received also shows every message its
processing caused. The coordinator (the twin bridge) sums the sends of every topic
(its own included) and calls the system *quiescent* when each participant that
subscribes to a topic has received exactly that many. Then nothing is in flight or
being processed anywhere and the next tick can start: whatever the machine's speed,
each node sees the same messages in the same state, so a run is repeatable.

Every chain of work starts at the coordinator's publications (its clock and sensor
messages), so a stale acknowledgement can only under-count receives, never make an
unfinished system look finished.

Each tick has three phases, each waiting for quiescence before the next: ``/clock``
(every participant learns the new time, and does nothing else), ``/lockstep/tick``
(timers run: the planner's poll, navigation's control step, watchdogs) and the
sensors. Splitting the first two matters: otherwise a message caused by one node's
timer (the planner's observation request, say) can reach another node before that
node has processed the new ``/clock``, and it would act at the previous tick's time,
or not, depending on the machine's load. Likewise a message sent by one node's timer
can reach another node before or after that node's own timers ran for the tick: the
participant holds such a message back until its timers have run
(:meth:`stack.ros_lockstep.Participant.subscription`), so the order is always the
same.

Faults: a participant that restarts (new ``incarnation``) or loses messages would
leave the sums unbalanced forever; :meth:`Ledger.forgive` rebases it after a stall,
and a participant silent for too long is excused until it speaks again.
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from stack import topics

ACK_TOPIC = topics.LOCKSTEP_ACK
TICK_TOPIC = topics.LOCKSTEP_TICK  # after /clock has reached everyone: run the timers
RUN_ID_ENV = "VIGIL_RUN_ID"  # every node of a run has the run's id in this variable
MAX_FOREIGN = 64  # names of other runs' participants remembered (a hostile peer is bounded)
CATCH_UP_S = 5.0  # after a rebase, a receiver ahead of the sends may be catching up
# ... but only once every participant that publishes the topic has acknowledged again
# this long after the excess was first seen: before that, the receiver may simply be
# ahead of a sender's acknowledgement (a send that is not in the sums yet), and taking
# it for catch-up would leave the receiver one message short for good (a stall).
SETTLE_S = 1.0  # two of a participant's heartbeats (stack.ros_lockstep.HEARTBEAT_S)


@dataclass
class Ack:
    """One participant's counts: what it processed and what it sent, per topic.

    Attributes:
        node: the participant's name (unique in the system).
        incarnation: changes when the process restarts.
        recv: topic -> messages received and processed.
        sent: topic -> messages published.
        matched: topic -> subscriptions matched by this participant's publisher.
        run: the run this participant belongs to (``VIGIL_RUN_ID``; "" outside a run).
    """

    node: str
    incarnation: str
    recv: dict[str, int] = field(default_factory=dict)
    sent: dict[str, int] = field(default_factory=dict)
    matched: dict[str, int] = field(default_factory=dict)
    run: str = ""

    def to_json(self) -> str:
        return json.dumps(
            {
                "node": self.node,
                "run": self.run,
                "incarnation": self.incarnation,
                "recv": self.recv,
                "sent": self.sent,
                "matched": self.matched,
            },
            sort_keys=True,
        )

    @classmethod
    def from_json(cls, text: str) -> Ack:
        """Parse an acknowledgement.

        Raises:
            ValueError: not JSON, or a field of the wrong type.
        """
        return cls.from_dict(json.loads(text))

    @classmethod
    def from_dict(cls, data: Any) -> Ack:
        """An acknowledgement from its fields (the JSON object, or the typed message's
        fields as :func:`stack.ros_msgs.ack_from_msg` gives them).

        Raises:
            ValueError: no node name, or a field of the wrong type.
        """
        if not isinstance(data, dict) or not isinstance(data.get("node"), str):
            raise ValueError(f"lock-step ack without a node name: {str(data)[:80]!r}")
        out = cls(str(data["node"]), str(data.get("incarnation", "")), run=str(data.get("run", "")))
        for name in ("recv", "sent", "matched"):
            counts = data.get(name, {})
            if not isinstance(counts, dict) or not all(
                isinstance(k, str) and isinstance(v, int) and v >= 0 for k, v in counts.items()
            ):
                raise ValueError(f"lock-step ack from {out.node}: bad {name} counts")
            setattr(out, name, dict(counts))
        return out


@dataclass
class _Member:
    ack: Ack
    offset: dict[str, int] = field(default_factory=dict)  # messages it will never see
    last_heard_s: float = 0.0
    excused: bool = False
    rebased_s: float = -1e9  # when its counts were last rebased (wall clock)
    ahead_since: dict[str, float] = field(default_factory=dict)  # topic -> excess first seen


class Ledger:
    """The coordinator's view of every participant's counts.

    Args:
        expected: participants that must be present before the first tick.
        run_id: this run's id: acknowledgements of any other run are ignored (and
            counted in :attr:`foreign`), so two runs that can hear each other never
            take each other's nodes for their own.
    """

    def __init__(self, expected: tuple[str, ...] = (), run_id: str = ""):
        self.expected = tuple(expected)
        self.run_id = run_id
        self.foreign: dict[str, int] = defaultdict(int)  # "node@run" -> acks ignored
        self.members: dict[str, _Member] = {}
        self.own_sent: dict[str, int] = defaultdict(int)
        self.own_recv: dict[str, int] = defaultdict(int)
        self.own_subscribes: set[str] = set()
        self.retired_sent: dict[str, int] = defaultdict(int)
        self.events: list[str] = []  # restarts, excuses: for the log
        self.version = 0  # changes with every count: unchanged counts need no new check
        self.heard_s = 0.0  # the wall clock of the latest acknowledgement

    # -- the coordinator's own traffic ----------------------------------------------
    def sent(self, topic: str, n: int = 1) -> None:
        self.own_sent[topic] += n
        self.version += 1

    def received(self, topic: str) -> None:
        self.own_recv[topic] += 1
        self.version += 1

    def subscribe(self, topic: str) -> None:
        """The coordinator itself consumes ``topic`` (e.g. /cmd_vel)."""
        self.own_subscribes.add(topic)

    # -- participants ---------------------------------------------------------------
    def update(self, ack: Ack, now_s: float) -> bool:
        """Record a participant's latest counts (a restart is noticed and rebased).

        Returns:
            False (and nothing recorded) for an acknowledgement of another run.
        """
        if ack.run != self.run_id:
            key = f"{ack.node[:40]}@{ack.run[:40] or '?'}"
            if key in self.foreign or len(self.foreign) < MAX_FOREIGN:
                self.foreign[key] += 1
            return False
        self.version += 1
        self.heard_s = max(self.heard_s, now_s)
        member = self.members.get(ack.node)
        if member is None:
            self.members[ack.node] = _Member(ack, last_heard_s=now_s)
            return True
        if member.ack.incarnation != ack.incarnation:
            for topic, n in member.ack.sent.items():
                self.retired_sent[topic] += n
            self.events.append(f"{ack.node} restarted")
            member.ack = ack
            member.offset = {}
            member.excused = False
            member.last_heard_s = now_s
            self._rebase(member)
            return True
        member.ack = ack
        member.last_heard_s = now_s
        if member.excused:
            member.excused = False
            self._rebase(member)
            self.events.append(f"{ack.node} is back")
        return True

    def total_sent(self, topic: str) -> int:
        total = self.own_sent.get(topic, 0) + self.retired_sent.get(topic, 0)
        return total + sum(m.ack.sent.get(topic, 0) for m in self.members.values())

    def _totals(self) -> dict[str, int]:
        """:meth:`total_sent` of every topic at once."""
        totals: dict[str, int] = defaultdict(int)
        for counts in (self.own_sent, self.retired_sent):
            for topic, n in counts.items():
                totals[topic] += n
        for m in self.members.values():
            for topic, n in m.ack.sent.items():
                totals[topic] += n
        return totals

    def _rebase(self, member: _Member) -> None:
        """Forgive what ``member`` missed: count it as balanced as of now."""
        member.rebased_s = member.last_heard_s
        member.ahead_since = {}
        for topic in member.ack.recv:
            member.offset[topic] = self.total_sent(topic) - member.ack.recv[topic]

    def missing(self) -> list[str]:
        """Expected participants not heard from yet."""
        return [n for n in self.expected if n not in self.members]

    def unmatched(self, own_matched: dict[str, int]) -> list[str]:
        """Publishers whose subscriptions are not all matched yet.

        Args:
            own_matched: the coordinator's publishers' subscription counts.
        """
        subscribers: dict[str, int] = defaultdict(int)
        for m in self.members.values():
            for topic in m.ack.recv:
                subscribers[topic] += 1
        out = []
        publishers = [("coordinator", own_matched)] + [
            (name, m.ack.matched) for name, m in self.members.items()
        ]
        for name, matched in publishers:
            for topic, count in matched.items():
                if count < subscribers.get(topic, 0):
                    out.append(f"{name} -> {topic} ({count}/{subscribers[topic]} subscribers)")
        return out

    def pending(self) -> list[str]:
        """What keeps the system from being quiescent ([] when it is).

        A participant that received more than the known sends is ahead of a sender's
        acknowledgement (pending too), unless it was rebased in the last
        ``CATCH_UP_S`` and the excess outlived the senders' next acknowledgements
        (:meth:`_caught_up`): then it is still receiving what was in flight at the
        rebase.
        """
        out = []
        totals = self._totals()  # the sums, once a check (they do not change in it)
        for name, m in sorted(self.members.items()):
            if m.excused:
                continue
            for topic, got in sorted(m.ack.recv.items()):
                want = totals.get(topic, 0) - m.offset.get(topic, 0)
                if got <= want:
                    m.ahead_since.pop(topic, None)
                if got > want and self._caught_up(name, m, topic):
                    m.offset[topic] = totals.get(topic, 0) - got
                    m.ahead_since.pop(topic, None)
                elif got != want:
                    out.append(f"{name} {topic} {got}/{want}")
        for topic in sorted(self.own_subscribes):
            got, want = self.own_recv.get(topic, 0), totals.get(topic, 0)
            if got < want:
                out.append(f"coordinator {topic} {got}/{want}")
        return out

    def _caught_up(self, name: str, m: _Member, topic: str) -> bool:
        """``m``, ahead of the sends of ``topic``, is catching up on what was in flight
        at its rebase (not ahead of a sender's acknowledgement): the excess was first
        seen within ``CATCH_UP_S`` of the rebase, and every participant publishing the
        topic has acknowledged ``SETTLE_S`` after that (the coordinator's own sends
        are counted when made: nothing to wait for)."""
        since = m.ahead_since.get(topic)
        if since is None:
            if m.last_heard_s - m.rebased_s >= CATCH_UP_S:
                return False  # long after the rebase: a sender's ack is late
            since = m.ahead_since[topic] = self.heard_s
        senders = [
            s
            for n, s in self.members.items()
            if n != name and not s.excused and (topic in s.ack.sent or topic in s.ack.matched)
        ]
        return all(s.last_heard_s >= since + SETTLE_S for s in senders)

    def quiescent(self) -> bool:
        return not self.pending()

    def stalled_members(self) -> list[str]:
        """Participants named in :meth:`pending`."""
        names = {p.split(" ", 1)[0] for p in self.pending()}
        return sorted(n for n in names if n in self.members)

    def forgive(self, names: list[str], now_s: float, silent_after_s: float) -> list[str]:
        """Give up waiting for ``names``: rebase them; excuse those silent too long.

        Returns:
            What was done, one line per participant, for the log.
        """
        self.version += 1
        out = []
        for name in names:
            m = self.members.get(name)
            if m is None:
                continue
            if now_s - m.last_heard_s > silent_after_s:
                m.excused = True
                out.append(f"{name} silent for {now_s - m.last_heard_s:.1f} s: excused")
            else:
                self._rebase(m)
                out.append(f"{name} lost messages: counts rebased")
        self.events.extend(out)
        return out

    def snapshot(self) -> dict[str, Any]:
        """Counts for a status message or a log."""
        return {
            "members": sorted(self.members),
            "excused": sorted(n for n, m in self.members.items() if m.excused),
            "pending": self.pending(),
        }


# the coordinator's actions (what :meth:`Coordinator.poll` asks the bridge to do)
WAIT = ""  # nothing yet
CLOCK = "clock"  # step the physics to the next sensor time (not before the first), publish /clock
TICK = "tick"  # publish /lockstep/tick: the participants' timers run
SENSORS = "sensors"  # publish the sensors due now
ABORT = "abort"  # no progress for stall_abort_s: end the run


class Coordinator:
    """The coordinator's side of a tick: which phase comes next, and when to give up.

    Pure (no rclpy, wall clock passed in): the twin bridge calls :meth:`ack` with every
    acknowledgement and :meth:`poll` from a short timer, and does what ``poll`` returns.
    The phases: ``start`` (wait for the expected participants and every publisher's
    subscriptions), then per tick ``clock`` -> ``tick`` -> ``sensors`` -> ``clock`` ...,
    each waiting for :meth:`Ledger.pending` to empty.

    Args:
        ledger: the counts (the bridge also records its own sends in it).
        stall_warn_s: wall seconds of waiting before a warning (then one per period).
        stall_timeout_s: wall seconds of waiting before the pending participants are
            forgiven (:meth:`Ledger.forgive`).
        stall_abort_s: wall seconds without a tick (forgiving included) before
            :data:`ABORT`.
        now_s: the wall clock at start.
    """

    def __init__(
        self,
        ledger: Ledger,
        stall_warn_s: float,
        stall_timeout_s: float,
        stall_abort_s: float,
        now_s: float,
    ):
        self.ledger = ledger
        self.stall_warn_s = stall_warn_s
        self.stall_timeout_s = stall_timeout_s
        self.stall_abort_s = stall_abort_s
        self.phase = "start"  # start -> clock -> tick -> sensors -> clock ...
        # (level, line) for the bridge's logger; level "throttled": a warning at most every 5 s
        self.log: list[tuple[str, str]] = []
        self._checked_version = -1  # the ledger's version when last checked
        self._waiting_for = ""  # what that check found pending
        self._wait_since = now_s
        self._progress_s = now_s  # the last tick (or the start)
        self._last_warn = now_s
        self._foreign_seen = 0

    def ack(self, message: str | dict, now_s: float) -> None:
        """Record one acknowledgement (JSON text, or its fields as a dict); a malformed
        one is logged and ignored."""
        try:
            ack = Ack.from_json(message) if isinstance(message, str) else Ack.from_dict(message)
            ours = self.ledger.update(ack, now_s)
        except ValueError as err:
            self.log.append(("throttled", f"lock-step ack ignored: {err}"))
            ours = True
        if not ours and len(self.ledger.foreign) > self._foreign_seen:
            self._foreign_seen = len(self.ledger.foreign)
            self.log.append(
                (
                    "warning",
                    f"lock-step: ignoring another run's participants "
                    f"({', '.join(self.ledger.foreign)}); this run is "
                    f"{self.ledger.run_id or '(no run id)'}",
                )
            )
        self.log.extend(("warning", f"lock-step: {event}") for event in self.ledger.events)
        self.ledger.events.clear()

    def poll(self, now_s: float, own_matched: Callable[[], dict[str, int]], t_sim: float) -> str:
        """What to do now: :data:`WAIT`, :data:`CLOCK`, :data:`TICK`, :data:`SENSORS` or
        :data:`ABORT`.

        Args:
            now_s: the wall clock.
            own_matched: the bridge's publishers' subscription counts (asked only
                before the first tick).
            t_sim: the simulation time, for the log.
        """
        ledger = self.ledger
        if self.phase == "start":
            waiting = ledger.missing() + ledger.unmatched(own_matched()) + ledger.pending()
            if waiting:
                return self._slow(now_s, t_sim, "waiting for " + ", ".join(waiting), False)
            self.log.append(
                (
                    "info",
                    f"lock-step: {len(ledger.members)} participants up "
                    f"({', '.join(sorted(ledger.members))}); starting",
                )
            )
            return self._begin_tick(now_s)
        if ledger.version != self._checked_version:  # new counts: check them
            self._checked_version = ledger.version
            pending = ledger.pending()
            self._waiting_for = "waiting: " + ", ".join(pending) if pending else ""
        if self._waiting_for:
            return self._slow(now_s, t_sim, self._waiting_for, True)
        self._wait_since = now_s
        if self.phase == "clock":  # everyone has the new time: now the timers
            self.phase = "tick"
            return TICK
        if self.phase == "tick":
            self.phase = "sensors"
            return SENSORS
        return self._begin_tick(now_s)  # sensors and all they caused processed: next tick

    def _begin_tick(self, now_s: float) -> str:
        self.phase = "clock"
        self._wait_since = now_s
        self._progress_s = now_s
        return CLOCK

    def _slow(self, now_s: float, t_sim: float, what: str, forgive: bool) -> str:
        stalled = now_s - self._progress_s
        if stalled > self.stall_abort_s:
            self.log.append(
                (
                    "error",
                    f"lock-step stalled: no progress for {stalled:.0f} s at t={t_sim:.2f}: "
                    f"{what}; ending the run",
                )
            )
            return ABORT
        waited = now_s - self._wait_since
        if waited > self.stall_warn_s and now_s - self._last_warn > self.stall_warn_s:
            self._last_warn = now_s
            self.log.append(("warning", f"lock-step: {waited:.0f} s at t={t_sim:.2f}: {what}"))
        if forgive and waited > self.stall_timeout_s:
            names = self.ledger.stalled_members()
            for line in self.ledger.forgive(names, now_s, self.stall_timeout_s):
                self.log.append(("error", f"lock-step: {line}"))
            self._wait_since = now_s
        return WAIT


def stamp_parts(t_s: float) -> tuple[int, int]:
    """(sec, nanosec) of a time [s] as a builtin_interfaces/Time stamps it: rounded to a
    whole number of nanoseconds first, so that 2.9999999999 s is 3 s (not 2 s with the
    nanoseconds wrapped to 0; the twin bridge and the in-process loop both use this)."""
    sec, nanosec = divmod(int(round(t_s * 1e9)), 1_000_000_000)
    return sec, nanosec
