"""Lock-step bookkeeping: quiescence by message counting, restarts, stalls."""

import pytest

from stack.lockstep import ABORT, CLOCK, SENSORS, TICK, WAIT, Ack, Coordinator, Ledger


def ack(node, inc="a", recv=None, sent=None, matched=None):
    return Ack(node, inc, dict(recv or {}), dict(sent or {}), dict(matched or {}))


def test_quiescent_only_when_every_subscriber_processed_every_send():
    led = Ledger(("cam", "obs"))
    led.update(ack("cam", recv={"/image": 0}), 0.0)
    led.update(ack("obs", recv={"/person": 0}), 0.0)
    assert led.quiescent()
    led.sent("/image")
    assert led.pending() == ["cam /image 0/1"]
    # the camera node processed the image and sent a person message in the same callback
    led.update(ack("cam", recv={"/image": 1}, sent={"/person": 1}), 0.1)
    assert led.pending() == ["obs /person 0/1"]
    led.update(ack("obs", recv={"/person": 1}), 0.2)
    assert led.quiescent()


def test_coordinator_own_subscription_counts():
    led = Ledger(("nav",))
    led.subscribe("/cmd_vel")
    led.update(ack("nav", recv={"/odom": 0}, sent={"/cmd_vel": 1}), 0.0)
    assert led.pending() == ["coordinator /cmd_vel 0/1"]
    led.received("/cmd_vel")
    assert led.quiescent()


def test_receiver_ahead_of_a_senders_ack_is_not_quiescent():
    # a timer's send reached the subscriber before the sender's ack reached us
    led = Ledger()
    led.update(ack("speech", sent={}), 0.0)
    led.update(ack("rec", recv={"/speech/done": 1}), 0.0)
    assert led.pending() == ["rec /speech/done 1/0"]
    led.update(ack("speech", sent={"/speech/done": 1}), 0.1)
    assert led.quiescent()


def test_missing_and_unmatched_before_start():
    led = Ledger(("cam", "legs"))
    led.update(ack("cam", recv={"/image": 0}, matched={"/person": 0}), 0.0)
    assert led.missing() == ["legs"]
    led.update(ack("legs", recv={"/person": 0}), 0.0)
    assert led.unmatched({"/image": 1}) == ["cam -> /person (0/1 subscribers)"]
    assert led.unmatched({"/image": 0})[0] == "coordinator -> /image (0/1 subscribers)"
    led.update(ack("cam", recv={"/image": 0}, matched={"/person": 1}), 0.1)
    assert led.unmatched({"/image": 1}) == []


def test_restart_is_rebased_and_keeps_the_dead_incarnations_sends():
    led = Ledger()
    led.update(ack("planner", "one", recv={"/obs": 3}, sent={"/action": 3}), 0.0)
    led.update(ack("nav", recv={"/action": 3}), 0.0)
    for _ in range(5):
        led.sent("/obs")  # sent while the planner was dead: never received
    led.update(ack("planner", "two", recv={"/obs": 0}, sent={}), 1.0)
    assert led.total_sent("/action") == 3  # the dead incarnation's sends still count
    assert led.quiescent()
    assert led.events == ["planner restarted"]
    led.sent("/obs")
    assert led.pending() == ["planner /obs 0/1"]


def test_a_restarted_receiver_ahead_of_a_senders_ack_waits_for_it():
    # after a restart the planner receives an observation before the observations
    # node's ack of sending it reaches us: not catch-up; taking it for catch-up would
    # leave the planner one message short for good (a 30 s stall, again and again)
    led = Ledger()
    led.update(ack("obs", recv={"/req": 4}, sent={"/observations": 4}), 0.0)
    led.update(ack("planner", "one", recv={"/observations": 4}, sent={"/req": 4}), 0.0)
    led.update(ack("planner", "two", recv={"/observations": 0}, sent={"/req": 1}), 1.0)
    led.update(ack("obs", recv={"/req": 5}, sent={"/observations": 4}), 1.1)
    led.update(ack("planner", "two", recv={"/observations": 1}, sent={"/req": 1}), 1.2)
    assert led.pending() == ["planner /observations 1/0"]
    led.update(ack("obs", recv={"/req": 5}, sent={"/observations": 5}), 1.3)  # the late ack
    assert led.quiescent()
    led.sent("/clock")  # and the counts stay balanced: the next send is waited for
    led.update(ack("obs", recv={"/req": 6}, sent={"/observations": 6}), 1.5)
    assert led.pending() == ["obs /req 6/5", "planner /observations 1/2"]
    led.update(ack("planner", "two", recv={"/observations": 2}, sent={"/req": 2}), 1.6)
    assert led.quiescent()


def test_a_restarted_receiver_catches_up_once_the_senders_acked_again():
    led = Ledger()
    led.update(ack("obs", recv={}, sent={"/observations": 4}), 0.0)
    led.update(ack("planner", "one", recv={"/observations": 3}), 0.0)  # one in flight
    led.update(ack("planner", "two", recv={"/observations": 0}), 1.0)  # rebased: 0 of 0
    led.update(ack("planner", "two", recv={"/observations": 1}), 1.1)  # the one in flight
    assert led.pending() == ["planner /observations 1/0"]  # perhaps a late ack: wait
    led.update(ack("obs", recv={}, sent={"/observations": 4}), 1.6)  # a heartbeat
    assert led.pending() == ["planner /observations 1/0"]
    led.update(ack("obs", recv={}, sent={"/observations": 4}), 2.2)  # SETTLE_S later
    assert led.quiescent()  # nothing more was sent: it was catch-up
    led.update(ack("obs", recv={}, sent={"/observations": 5}), 2.3)
    assert led.pending() == ["planner /observations 1/2"]


def test_a_restarted_receiver_catches_up_on_the_coordinators_sends_at_once():
    led = Ledger()
    led.update(ack("cam", "one", recv={"/image": 2}), 0.0)
    led.sent("/image", 3)
    led.update(ack("cam", "two", recv={"/image": 0}), 1.0)
    led.update(ack("cam", "two", recv={"/image": 1}), 1.1)  # in flight at the restart
    assert led.quiescent()
    led.update(ack("cam", "two", recv={"/image": 2}), 7.0)  # long after: not catch-up
    assert led.pending() == ["cam /image 2/1"]


def test_forgive_rebases_a_lossy_member_and_excuses_a_silent_one():
    led = Ledger()
    led.update(ack("cam", recv={"/image": 0}), 0.0)
    led.update(ack("legs", recv={"/scan": 0}), 10.0)
    led.sent("/image")
    led.sent("/scan")
    done = led.forgive(["cam", "legs"], now_s=12.0, silent_after_s=5.0)
    assert done == ["cam silent for 12.0 s: excused", "legs lost messages: counts rebased"]
    assert led.quiescent()
    led.sent("/image")
    assert led.quiescent()  # excused: not waited for
    led.update(ack("cam", recv={"/image": 1}), 13.0)  # it speaks again: back in
    assert led.events[-1] == "cam is back"
    assert led.quiescent()
    led.sent("/image")
    assert led.pending() == ["cam /image 1/2"]


def test_ack_json_round_trip_and_errors():
    a = ack("cam", recv={"/image": 2}, sent={"/p": 1}, matched={"/p": 1})
    assert Ack.from_json(a.to_json()) == a
    with pytest.raises(ValueError, match="node name"):
        Ack.from_json('{"recv": {}}')
    with pytest.raises(ValueError, match="bad recv"):
        Ack.from_json('{"node": "x", "recv": {"/a": -1}}')
    with pytest.raises(ValueError):
        Ack.from_json("not json")


def _coordinator(expected=("cam",), warn=5.0, timeout=30.0, abort=90.0):
    led = Ledger(expected)
    return led, Coordinator(led, warn, timeout, abort, now_s=0.0)


def test_coordinator_waits_for_participants_then_runs_the_three_phases():
    led, co = _coordinator()
    matched = {"/clock": 1, "/image": 1}
    assert co.poll(0.1, lambda: matched, 0.0) == WAIT  # cam not heard from yet
    led.update(ack("cam", recv={"/clock": 0, "/lockstep/tick": 0, "/image": 0}), 0.2)
    assert co.poll(0.2, lambda: {"/clock": 0}, 0.0) == WAIT  # the clock not matched yet
    assert co.poll(0.3, lambda: matched, 0.0) == CLOCK
    assert co.log == [("info", "lock-step: 1 participants up (cam); starting")]
    led.sent("/clock")  # the bridge published the clock
    assert co.poll(0.4, lambda: matched, 0.0) == WAIT  # cam has not processed it
    led.update(ack("cam", recv={"/clock": 1, "/lockstep/tick": 0, "/image": 0}), 0.5)
    assert co.poll(0.5, lambda: matched, 0.0) == TICK
    led.sent("/lockstep/tick")
    led.update(ack("cam", recv={"/clock": 1, "/lockstep/tick": 1, "/image": 0}), 0.6)
    assert co.poll(0.6, lambda: matched, 0.0) == SENSORS
    led.sent("/image")
    assert co.poll(0.7, lambda: matched, 0.0) == WAIT
    led.update(ack("cam", recv={"/clock": 1, "/lockstep/tick": 1, "/image": 1}), 0.8)
    assert co.poll(0.8, lambda: matched, 0.0) == CLOCK  # the next tick


def test_coordinator_same_acks_same_actions():
    """The phases depend on the counts only, not on when the polls come (determinism)."""

    def run(poll_times):
        led, co = _coordinator()
        led.update(ack("cam", recv={"/clock": 0, "/image": 0}), 0.0)
        actions = []
        for t in poll_times:
            a = co.poll(t, lambda: {"/clock": 1, "/image": 1}, 0.0)
            if a == CLOCK:
                led.sent("/clock")
                led.update(ack("cam", recv={"/clock": led.total_sent("/clock"), "/image": 0}), t)
            elif a == SENSORS:
                led.sent("/image")
            elif a == WAIT and led.pending():
                recv = {"/clock": led.total_sent("/clock"), "/image": led.total_sent("/image")}
                led.update(ack("cam", recv=recv), t)
            if a != WAIT:
                actions.append(a)
        return actions[:9]

    fast = run([i * 0.001 for i in range(40)])
    slow = run([i * 0.5 for i in range(40)])
    assert fast == slow == [CLOCK, TICK, SENSORS] * 3


def test_coordinator_forgives_a_stalled_participant_and_aborts_without_progress():
    led, co = _coordinator(warn=1.0, timeout=2.0, abort=10.0)
    led.update(ack("cam", recv={"/clock": 0}), 0.0)
    assert co.poll(0.0, dict, 0.0) == CLOCK
    led.sent("/clock")
    assert co.poll(1.5, dict, 0.0) == WAIT
    assert co.log[-1] == ("warning", "lock-step: 2 s at t=0.00: waiting: cam /clock 0/1")
    co.log.clear()
    led.update(ack("cam", recv={"/clock": 0}), 2.2)  # alive (a heartbeat) but lost the clock
    assert co.poll(2.5, dict, 0.0) == WAIT  # past stall_timeout_s: cam is forgiven
    assert ("error", "lock-step: cam lost messages: counts rebased") in co.log
    assert co.poll(2.6, dict, 0.0) == TICK  # the rebased counts balance


def test_coordinator_aborts_without_progress():
    led, co = _coordinator(expected=("cam", "legs"), warn=1.0, timeout=2.0, abort=10.0)
    led.update(ack("cam", recv={"/clock": 0}), 0.0)
    assert co.poll(9.0, dict, 0.0) == WAIT  # legs never comes
    assert co.log[-1] == ("warning", "lock-step: 9 s at t=0.00: waiting for legs")
    assert co.poll(10.5, dict, 0.0) == ABORT
    assert co.log[-1] == (
        "error",
        "lock-step stalled: no progress for 10 s at t=0.00: waiting for legs; ending the run",
    )


def test_coordinator_logs_bad_and_foreign_acks():
    led, co = _coordinator()
    led.run_id = "run-a"
    co.ack("not json {", 0.0)
    assert co.log[0][0] == "throttled" and "lock-step ack ignored" in co.log[0][1]
    co.log.clear()
    co.ack(ack("cam").to_json(), 0.0)  # run "" is not run-a
    assert co.log == [
        ("warning", "lock-step: ignoring another run's participants (cam@?); this run is run-a")
    ]
    assert "cam" not in led.members
