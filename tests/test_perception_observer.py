"""stack.perception.observer: the observations node's core (pure)."""

import pytest

from stack.cells import ConfigError
from stack.perception.camera import CameraPersonState, PersonStatus
from stack.perception.observer import Observer


def _seen(t, *people):
    return CameraPersonState(
        stamp_s=t,
        status=PersonStatus.PERSON,
        position_m=people[0],
        cell=None,
        people_m=tuple(people),
    )


def test_two_camera_messages_in_one_instant_move_the_slots_on_once():
    """After a camera outage the frame watchdog's "silent" and the first frame can
    come at the same instant; the person slots' tracker refused the second (an
    exception that ended 11 of 1,000 two-person episodes, and would have killed the
    observations node)."""
    obs = Observer("", people=2)
    obs.on_camera(_seen(1.0, (4.5, 0.8), (1.5, 2.2)))
    obs.on_camera(_seen(1.1, (4.5, 0.8), (1.5, 2.2)))
    before = obs.slot_people
    silent = CameraPersonState(stamp_s=2.0, status=PersonStatus.UNKNOWN)
    obs.on_camera(silent)
    obs.on_camera(_seen(2.0, (4.6, 0.8), (1.5, 2.3)))  # same instant: no error
    assert obs.camera.stamp_s == 2.0 and obs.camera.status is PersonStatus.PERSON
    obs.on_camera(_seen(2.1, (4.6, 0.8), (1.5, 2.3)))  # and on from there
    _, record = obs.observe(2.2)
    assert len(record["people"]) == 2 and before  # a label pair per slot


def test_one_person_has_no_slots_and_people_must_be_one_or_more():
    obs = Observer("", people=1)
    obs.on_camera(_seen(1.0, (4.5, 0.8)))
    obs.on_camera(_seen(1.0, (4.5, 0.8)))
    _, record = obs.observe(1.0)
    assert "people" not in record and obs.slots is None
    with pytest.raises(ConfigError, match="people"):
        Observer("", people=0)


def _legs(t, track_id, xy, vx=0.0):
    from stack.perception.tracker import TrackEstimate

    return TrackEstimate(track_id, xy, (vx, 0.0), abs(vx), 10, t, True)


def test_a_person_who_comes_in_while_the_camera_is_blind_is_tracked_by_the_laser():
    """Two people, the camera off (no frame since 1.0 s): a person the laser sees
    walking in fills a slot, where they walk, with their direction; with the camera
    looking (a frame that sees nobody), the laser's people do not: the camera's misses
    are not filled with whatever the laser sees (a chair leg, another person)."""
    blind = Observer("", people=2)
    blind.on_camera(CameraPersonState(stamp_s=1.0, status=PersonStatus.NO_PERSON))
    looking = Observer("", people=2)
    seen = []
    for k in range(12):
        t = 2.0 + 0.25 * k
        legs = (_legs(t, 7, (6.0 - 0.25 * k, 1.0), vx=-1.0),)
        looking.on_camera(CameraPersonState(stamp_s=t, status=PersonStatus.NO_PERSON))
        for o in (blind, looking):
            o.on_tracks(legs)
        _, record = blind.observe(t)
        _, other = looking.observe(t)
        assert all(p["person"] == "No person" and p["position_m"] is None for p in other["people"])
        seen.append(next((p for p in blind.slot_people if p.position_m is not None), None))
    last = seen[-1]
    assert last is not None and last.measured
    assert abs(last.position_m[0] - 3.25) < 0.2 and abs(last.position_m[1] - 1.0) < 0.2
    assert last.direction.label == "West"
    assert record["people"][last.slot]["person"] == "5"  # x 3-4, y 0-1.5: cell 5
    assert record["people"][last.slot]["position_m"] is not None
