"""Several people at once (issue 16), pure perception: non-maximum suppression, the
multi-target tracker through crossings, camera-laser association and person slots."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError, Direction
from stack.perception.camera import CameraConfig, CameraPeopleTracker
from stack.perception.hog import HogPeopleDetector, PersonBox, box_overlap, non_max_suppression
from stack.perception.homography import calibrate
from stack.perception.legs import LegConfig, Pose2D, detect_legs
from stack.perception.multi import (
    MultiTracker,
    MultiTrackerConfig,
    PeoplePerception,
    associate,
    gnn_assign,
)
from stack.perception.slots import PersonSlots, SlotConfig, slot_labels
from stack.perception.synthetic import (
    PinholeCamera,
    crossing_paths,
    floor_calibration_points,
    render_people_frame,
    simulate_scan,
    walking_legs,
)
from stack.perception.tracker import TrackEstimate

GRID = CellGrid()
CAMERA = PinholeCamera.mount_a(GRID)


def box(x, y, w=60, h=120, weight=1.0):
    return PersonBox(x=x, y=y, width=w, height=h, weight=weight)


def track(tid, xy, confirmed=True, speed=(0.0, 0.0)):
    return TrackEstimate(tid, xy, speed, math.hypot(*speed), 3, 0.0, confirmed)


# -- non-maximum suppression ----------------------------------------------------------
def test_nms_merges_duplicate_boxes_and_keeps_two_separated_people():
    person_a = [box(100, 50, weight=2.0), box(104, 46, 64, 128, weight=1.5), box(98, 52)]
    person_b = [box(300, 60, weight=1.2), box(303, 58, weight=0.9)]
    kept = non_max_suppression(person_a + person_b)
    assert [(b.x, b.y) for b in kept] == [(100, 50), (300, 60)]  # the strongest of each


def test_nms_drops_an_upper_body_box_inside_a_full_body_one():
    full = box(100, 40, 80, 160, weight=1.0)
    upper = box(110, 45, 60, 70, weight=1.4)  # stronger, but inside the full box
    assert box_overlap(full, upper)[1] == 1.0
    assert non_max_suppression([full, upper]) == (upper,)  # the strongest survives
    assert len(non_max_suppression([full, upper], containment_frac=1.0)) == 2


def test_nms_keeps_people_side_by_side():
    a, b = box(100, 50), box(150, 50)  # 10 px overlap of 60 px width
    assert box_overlap(a, b)[0] < 0.2
    assert len(non_max_suppression([a, b])) == 2


@pytest.mark.slow
def test_hog_finds_both_of_two_separated_people_once_each():
    rng = np.random.default_rng(5)
    det = HogPeopleDetector()
    for pair in ([(1.5, 0.7), (1.5, 2.3)], [(2.5, 0.5), (4.0, 2.5)]):
        boxes = det.detect_people(render_people_frame(CAMERA, pair, rng))
        assert len(boxes) == 2
        feet = sorted(b.x + b.width / 2 for b in boxes)
        want = sorted(CAMERA.project(np.array([[x, y, 0.0] for x, y in pair]))[:, 0])
        assert np.allclose(feet, want, atol=25)


# -- data association -------------------------------------------------------------------
def test_gnn_assignment_is_global_not_greedy():
    # greedy nearest-first would give detection 0 to track 0 (0.3) and leave track 1
    # with nothing in its gate; the joint assignment serves both
    means = np.array([[0.0, 0.0], [0.5, 0.0]])
    covs = np.array([np.eye(2) * 0.04] * 2)
    dets = np.array([[0.3, 0.0], [-0.35, 0.0]])
    assert sorted(gnn_assign(means, covs, dets, gate_sigma=3.0)) == [(0, 1), (1, 0)]
    assert gnn_assign(means, covs, np.array([[5.0, 5.0]]), gate_sigma=3.0) == []


def crossing_run(lateral_m, merge_below_m=0.45, noise_m=0.05, seed=0, rate_hz=10.0):
    """Feed a tracker two people crossing; returns the identity switches and both ids."""
    rng = np.random.default_rng(seed)
    tracker = MultiTracker()
    owner: dict[int, int] = {}  # track id -> the person it followed first
    switches = 0
    for k in range(int(3.0 * rate_hz)):
        t = k / rate_hz
        people = crossing_paths(t, lateral_m=lateral_m)
        if math.dist(*people) < merge_below_m:  # one box for both (NMS merged them)
            dets = [tuple(np.mean(people, axis=0) + rng.normal(0, noise_m, 2))]
        else:
            dets = [tuple(np.asarray(p) + rng.normal(0, noise_m, 2)) for p in people]
        for tr in tracker.update(t, dets):
            if not tr.confirmed or tr.last_update_s != t:
                continue
            nearest = int(np.argmin([math.dist(tr.position_m, p) for p in people]))
            if math.dist(*people) < merge_below_m:
                continue  # no truth to judge against while merged
            if owner.setdefault(tr.track_id, nearest) != nearest:
                switches += 1
                owner[tr.track_id] = nearest
    return switches, owner


@pytest.mark.parametrize("lateral_m", [0.0, 0.3, 0.6])
def test_identities_survive_a_crossing(lateral_m):
    switches, owner = crossing_run(lateral_m)
    assert switches == 0
    assert sorted(set(owner.values())) == [0, 1]


def test_identities_survive_crossings_over_many_seeds():
    total = sum(crossing_run(0.2, seed=s)[0] for s in range(20))
    assert total == 0


def test_a_stamp_must_increase():
    tracker = MultiTracker()
    tracker.update(0.0, [(0.0, 0.0)])
    with pytest.raises(Exception, match="not after"):
        tracker.update(0.0, [(0.0, 0.0)])


def test_laser_tracks_of_two_people_crossing_keep_identities():
    rng = np.random.default_rng(2)
    laser = Pose2D(3.0, -1.0, math.pi / 2)  # looking north at the crossing
    tracker = MultiTracker(MultiTrackerConfig())
    owner: dict[int, int] = {}
    switches = 0
    for k in range(30):
        t = k / 10.0
        people = crossing_paths(t, center_m=(3.0, 1.5), lateral_m=0.7)
        legs = []
        for p, heading in zip(people, (math.pi / 2, -math.pi / 2), strict=True):
            for leg in walking_legs(p, heading, t, 0.8):
                legs.append((leg[0], leg[1], 0.06))
        scan = simulate_scan(laser, legs, rng, stamp_s=t)
        found = detect_legs(scan, LegConfig(), laser)
        for tr in tracker.update(t, found.people):
            if tr.confirmed and tr.last_update_s == t:
                nearest = int(np.argmin([math.dist(tr.position_m, p) for p in people]))
                if owner.setdefault(tr.track_id, nearest) != nearest:
                    switches += 1
                    owner[tr.track_id] = nearest
    assert switches == 0
    assert sorted(set(owner.values())) == [0, 1]


def test_associate_pairs_camera_and_laser_people_one_to_one():
    cam = [track(1, (1.0, 1.0)), track(2, (1.6, 1.0))]
    laser = [track(10, (1.5, 1.05)), track(11, (1.1, 0.9)), track(12, (4.0, 2.0))]
    pairs = associate(cam, laser, gate_m=0.8)
    assert {k: v.track_id for k, v in pairs.items()} == {1: 11, 2: 10}
    assert associate(cam, [track(13, (1.2, 1.0), confirmed=False)], 0.8) == {}


# -- person slots -------------------------------------------------------------------------
def test_slots_are_stable_and_a_returning_person_gets_their_slot_back():
    slots = PersonSlots(SlotConfig(slots=2), GRID)
    a, b = track(1, (0.5, 0.5)), track(2, (5.5, 2.5))
    assert [t.track_id for t in slots.assign([a, b])] == [1, 2]
    # order of the input does not matter: a track keeps its slot
    assert [t.track_id for t in slots.assign([b, a])] == [1, 2]
    # person in slot 0 is lost; a third track appears far away, waits not
    assert [None if t is None else t.track_id for t in slots.assign([b])] == [None, 2]
    # person 1 is found again (a new track) near where they vanished: slot 0 again
    back = track(3, (0.6, 0.55))
    assert [t.track_id for t in slots.assign([back, b])] == [3, 2]


def test_slots_with_more_people_than_slots_keep_the_holders():
    slots = PersonSlots(SlotConfig(slots=1))
    assert slots.assign([track(4, (1.0, 1.0)), track(2, (2.0, 2.0))])[0].track_id == 2
    assert slots.assign([track(4, (1.0, 1.0)), track(2, (2.0, 2.0))])[0].track_id == 2
    assert slots.assign([track(4, (1.0, 1.0))])[0].track_id == 4
    assert slots.assign([track(5, (1.0, 1.0), confirmed=False)]) == (None,)


def test_slot_config_is_checked():
    with pytest.raises(ConfigError, match="slots"):
        SlotConfig.from_dict({"slots": 0})


def test_people_perception_reports_each_slot_with_its_laser_speed():
    pp = PeoplePerception(GRID)
    out = ()
    for k in range(12):
        t = k * 0.1
        a = (0.5 + 0.8 * t, 0.7)  # walking east in the south row
        b = (4.5, 2.3)  # standing in cell 4
        laser = [track(20, (a[0] + 0.05, a[1]), speed=(0.8, 0.0)), track(21, b)]
        out = pp.update(t, [a, b], laser)
    assert [p.slot for p in out] == [0, 1]
    assert out[0].cell == GRID.cell_at(1.4, 0.7) and out[1].cell == 4
    assert out[0].direction is Direction.EAST and out[1].direction is Direction.NOT_MOVING
    assert out[0].speed_mps == pytest.approx(0.8) and out[1].speed_mps == 0.0
    assert (out[0].laser_track_id, out[1].laser_track_id) == (20, 21)


# -- the camera pipeline on rendered frames -------------------------------------------------
@pytest.mark.slow
def test_camera_pipeline_keeps_two_people_apart_through_a_crossing():
    """HOG on rendered frames, NMS, floor positions, the tracker and the slots."""
    image_px, map_m = floor_calibration_points(CAMERA, GRID)
    cal = calibrate(image_px, map_m, image_size_px=(CAMERA.width_px, CAMERA.height_px))
    cam = CameraPeopleTracker(CameraConfig(max_people=2), GRID, cal.homography)
    people = PeoplePerception(GRID)
    rng = np.random.default_rng(7)
    slot_of: dict[int, int] = {}
    switches = 0
    for k in range(26):
        t = k * 0.1
        # walking across the camera's view (north and south) 0.5 m apart sideways
        truth = crossing_paths(t, center_m=(2.5, 1.5), lateral_m=0.5, speed_mps=1.0)
        state = cam.process_frame(render_people_frame(CAMERA, truth, rng), t)
        for p in people.update(t, state.people_m):
            if p.position_m is None:
                continue
            nearest = int(np.argmin([math.dist(p.position_m, q) for q in truth]))
            if math.dist(p.position_m, truth[nearest]) > 0.5:
                continue  # a coasted or stray estimate: judged when it is on someone
            if slot_of.setdefault(p.slot, nearest) != nearest:
                switches += 1
                slot_of[p.slot] = nearest
    assert switches == 0
    assert sorted(slot_of.values()) == [0, 1]


def box_at(xy_m, height_px=200.0, weight=1.0):
    """A HOG-like box whose shrunk bottom-middle pixel sees map point xy_m."""
    u, v = CAMERA.project(np.array([[xy_m[0], xy_m[1], 0.0]]))[0]
    h, shrink = height_px, 0.16
    return PersonBox(x=round(u - h / 4), y=round(v - h * (1 - shrink)), width=round(h / 2),
                     height=round(h), weight=weight)  # fmt: skip


def test_camera_state_lists_every_person_of_the_frame_and_only_of_that_frame():
    image_px, map_m = floor_calibration_points(CAMERA, GRID)
    cal = calibrate(image_px, map_m)
    cfg = CameraConfig(short_box_ratio=None)
    cam = CameraPeopleTracker(cfg, GRID, cal.homography)
    a, b = (1.5, 0.7), (3.5, 2.3)
    dup = box_at(a, 190, weight=0.5)  # a second, weaker box on the first person
    st = cam.update((box_at(a, weight=2.0), box_at(b, weight=1.0), dup), 0.0)
    assert len(st.people_m) == 2 and len(st.boxes) == 3
    for got, want in zip(st.people_m, (a, b), strict=True):
        assert math.dist(got, want) < 0.05
    assert math.dist(st.position_m, a) < 0.05  # the one-person choice is unchanged
    st = cam.update((), 0.1)  # one missed frame keeps the person, not the people
    assert st.position_m is not None and st.people_m == ()


def test_slots_become_the_models_per_person_observation():
    from stack.perception.slots import SlotPerson, model_persons

    people = (
        SlotPerson(1),  # nobody in slot 1
        SlotPerson(0, 3, (0.5, 0.7), 11, Direction.EAST, 0.9),
    )
    assert model_persons(people) == [(11, "East higher"), (None, "Not moving")]
    assert SlotPerson(0, 3, (0.5, 0.7), 11, Direction.NORTH, None).velocity_label == "North 0-0.2"
    assert SlotPerson(0, 3, (9.0, 0.7), None, Direction.EAST, 1.0).velocity_label == "Not moving"


# -- a person the camera misses, kept by their laser track ----------------------------------
def _legs(tid, xy, t, speed=(0.0, 0.0)):
    return TrackEstimate(tid, xy, speed, math.hypot(*speed), 5, t, True)


def _walk_in_and_stand(laser_after_stop, furniture=None, frames=26):
    """A person walks east at 1 m/s along y = 0.75 and stands at x = 4.6 (cell 3) from
    t = 1.0; the camera misses them from t = 1.1 on; their laser track (30) follows them
    throughout, or ends when the camera's view does (``laser_after_stop`` False). A
    confirmed laser track that is not a person's (``furniture``) may stand nearby."""
    pp = PeoplePerception(GRID)
    out = ()
    for k in range(frames):
        t = round(k * 0.1, 3)
        x = min(3.6 + t, 4.6)
        camera = t <= 1.0
        laser = []
        if camera or laser_after_stop:
            laser.append(_legs(30, (x + 0.03, 0.76), t, (1.0 if t < 1.0 else 0.0, 0.0)))
        if furniture is not None:
            laser.append(_legs(31, furniture, t))
        out = pp.update(t, [(x, 0.75)] if camera else [], laser)
    return out


def test_a_person_the_camera_misses_is_kept_where_their_laser_track_stands():
    out = _walk_in_and_stand(laser_after_stop=True)  # 1.5 s of misses: past max_coast_s
    person = out[0]
    assert person.cell == 3 and person.measured
    assert math.dist(person.position_m, (4.63, 0.76)) < 0.1  # not carried on east
    assert slot_labels(out)[0]["position_m"] is not None


def test_without_their_laser_track_a_missed_person_coasts_unmeasured_and_is_dropped():
    coasting = _walk_in_and_stand(laser_after_stop=False, frames=14)  # t = 1.3
    assert not coasting[0].measured and coasting[0].position_m[0] > 4.75  # the prediction
    assert slot_labels(coasting)[0]["position_m"] is None  # no evidence for the goal inference
    assert _walk_in_and_stand(laser_after_stop=False)[0].cell is None  # dropped by t = 2.5


def test_a_laser_track_that_was_not_the_persons_does_not_keep_them():
    # a chair's legs 0.5 m from where the person stands: the coasting track drifts past
    # them, but they were never this person's legs
    out = _walk_in_and_stand(laser_after_stop=False, furniture=(4.9, 1.2), frames=14)
    assert not out[0].measured
    assert math.dist(out[0].position_m, (4.9, 1.2)) > 0.2
