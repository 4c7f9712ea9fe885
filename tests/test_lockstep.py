"""Lock-step bookkeeping: quiescence by message counting, restarts, stalls."""

import pytest

from stack.lockstep import Ack, Ledger


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
