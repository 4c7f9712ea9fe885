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
