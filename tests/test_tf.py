"""The pure TF tree (stack/tf.py): composition, lookups across the REP-105 tree, time."""

from __future__ import annotations

import math

import pytest

from stack.geometry import Pose2D
from stack.tf import (
    BASE_LINK,
    CAMERA_LINK,
    CAMERA_OPTICAL,
    LASER,
    MAP,
    ODOM,
    ExtrapolationError,
    FrameNotFound,
    NotConnected,
    PendingLookup,
    StampedTransform,
    TfBuffer,
    TfTimeout,
    Transform,
    quaternion_from_matrix,
    quaternion_from_rpy,
)


def close(a, b, tol=1e-9):
    return all(abs(x - y) <= tol for x, y in zip(a, b, strict=True))


def planar(x, y, yaw):
    return Transform.from_pose2d(Pose2D(x, y, yaw))


def test_compose_matches_pose2d_compose_and_inverse_undoes_it():
    a, b = Pose2D(1.0, -2.0, 0.7), Pose2D(0.3, 0.4, -1.9)
    got = Transform.from_pose2d(a).compose(Transform.from_pose2d(b)).to_pose2d()
    want = a.compose(b)
    assert close((got.x_m, got.y_m), (want.x_m, want.y_m))
    assert math.isclose(math.remainder(got.yaw_rad - want.yaw_rad, math.tau), 0, abs_tol=1e-9)
    t = Transform((0.5, -1.0, 2.0), quaternion_from_rpy(0.3, -0.2, 1.1))
    ident = t.compose(t.inverse())
    assert close(ident.translation, (0, 0, 0))
    assert close(ident.apply((1.0, 2.0, 3.0)), (1.0, 2.0, 3.0))


def test_rpy_and_matrix_agree():
    q = quaternion_from_rpy(-math.pi / 2, 0.0, -math.pi / 2)  # camera_link -> optical
    t = Transform((0, 0, 0), q)
    # optical z (forward) is camera_link x; optical x (right) is camera_link -y
    assert close(t.apply((0, 0, 1)), (1, 0, 0))
    assert close(t.apply((1, 0, 0)), (0, -1, 0))
    m = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # columns: optical axes in camera_link
    assert close(quaternion_from_matrix(m), q) or close(quaternion_from_matrix(m), [-c for c in q])


def test_bad_transforms_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="unit quaternion"):
        Transform((0, 0, 0), (0, 0, 0, 2))
    with pytest.raises(ValueError, match="finite"):
        Transform((math.nan, 0, 0))
    buf = TfBuffer()
    with pytest.raises(ValueError, match="own parent"):
        buf.set_transform(StampedTransform(MAP, MAP, 0.0, Transform()))
    buf.set_transform(StampedTransform(MAP, ODOM, 0.0, Transform()))
    with pytest.raises(ValueError, match="loop"):
        buf.set_transform(StampedTransform(ODOM, MAP, 0.0, Transform()))


def rep105(buf: TfBuffer, map_odom=(1.0, 2.0, 0.5), t=(0.0, 1.0)):
    """The tree with odometry driving +x at 1 m/s, and map -> odom offset."""
    buf.set_transform(StampedTransform(BASE_LINK, LASER, 0.0, planar(0.2, 0.0, 0.0)), True)
    cam = Transform((-3.3, 0.0, 2.75), quaternion_from_rpy(0.0, math.radians(22), 0.0))
    buf.set_transform(StampedTransform(MAP, CAMERA_LINK, 0.0, cam), static=True)
    optical = Transform((0, 0, 0), quaternion_from_rpy(-math.pi / 2, 0.0, -math.pi / 2))
    buf.set_transform(StampedTransform(CAMERA_LINK, CAMERA_OPTICAL, 0.0, optical), static=True)
    for ts in t:  # localisation republishes map -> odom as odometry goes on
        buf.set_transform(StampedTransform(MAP, ODOM, ts, planar(*map_odom)))
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, ts, planar(ts, 0.0, 0.0)))
    return buf


def test_map_pose_goes_through_odom_and_laser_points_land_in_the_map():
    buf = rep105(TfBuffer())
    pose = buf.lookup(MAP, BASE_LINK).to_pose2d()  # latest: t = 1, odom x = 1
    want = Pose2D(1.0, 2.0, 0.5).compose(Pose2D(1.0, 0.0, 0.0))
    assert close((pose.x_m, pose.y_m, pose.yaw_rad), (want.x_m, want.y_m, want.yaw_rad))
    # halfway: interpolated odometry
    mid = buf.lookup(MAP, BASE_LINK, 0.5).to_pose2d()
    want = Pose2D(1.0, 2.0, 0.5).compose(Pose2D(0.5, 0.0, 0.0))
    assert close((mid.x_m, mid.y_m), (want.x_m, want.y_m))
    # a point 1 m ahead of the laser, in the map
    p = buf.lookup(MAP, LASER, 1.0).apply((1.0, 0.0, 0.0))
    want = Pose2D(1.0, 2.0, 0.5).compose(Pose2D(2.2, 0.0, 0.0))
    assert close(p[:2], (want.x_m, want.y_m))
    # across branches: the robot seen from the camera's optical frame and back
    there = buf.lookup(CAMERA_OPTICAL, BASE_LINK, 1.0)
    back = buf.lookup(BASE_LINK, CAMERA_OPTICAL, 1.0)
    assert close(there.compose(back).translation, (0, 0, 0))


def test_a_static_only_chain_holds_at_any_time():
    buf = rep105(TfBuffer())
    a = buf.lookup(MAP, CAMERA_OPTICAL, 123.0)
    assert a == buf.lookup(MAP, CAMERA_OPTICAL)
    assert buf.latest_common_time(MAP, CAMERA_OPTICAL) is None


def test_missing_frames_and_times_say_why():
    buf = rep105(TfBuffer())
    with pytest.raises(FrameNotFound, match="'wheel'"):
        buf.lookup(MAP, "wheel")
    with pytest.raises(ExtrapolationError, match="not at 1.500 s"):
        buf.lookup(MAP, BASE_LINK, 1.5)
    buf.set_transform(StampedTransform("world", "other", 0.0, Transform()))
    with pytest.raises(NotConnected):
        buf.lookup(MAP, "other")
    assert not buf.can_transform(MAP, BASE_LINK, -1.0)


def test_latest_time_is_that_of_the_stalest_link():
    buf = TfBuffer()
    buf.set_transform(StampedTransform(MAP, ODOM, 0.0, planar(1, 0, 0)))
    for ts in (0.0, 1.0):
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, ts, planar(ts, 0, 0)))
    assert buf.latest_common_time(MAP, BASE_LINK) == 0.0
    assert buf.lookup(MAP, BASE_LINK).translation[0] == 1.0  # map->odom is known at 0 only


def test_cache_keeps_only_the_last_seconds():
    buf = TfBuffer(cache_s=2.0)
    for i in range(50):
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, i * 0.1, planar(i * 0.1, 0, 0)))
    buf.lookup(ODOM, BASE_LINK, 4.9)
    with pytest.raises(ExtrapolationError):
        buf.lookup(ODOM, BASE_LINK, 2.0)


def test_time_jumping_back_past_the_cache_starts_the_link_over():
    """A restarted run or a looped bag: after 0..100 s, new data at 0..4 s is what
    lookups return (before, the t = 100 s pose stayed forever)."""
    buf = TfBuffer(cache_s=10.0)
    for i in range(101):
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, float(i), planar(100.0, 0, 0)))
    for i in range(5):
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, float(i), planar(float(i), 0, 0)))
    assert buf.lookup(ODOM, BASE_LINK).translation[0] == 4.0
    assert math.isclose(buf.lookup(ODOM, BASE_LINK, 2.5).translation[0], 2.5)


def test_stalest_link_names_the_link_that_went_quiet():
    buf = TfBuffer()
    for t in (0.0, 1.0, 2.0, 3.0):
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, t, planar(t, 0, 0)))
    buf.set_transform(StampedTransform(MAP, ODOM, 1.0, planar(0, 0, 0)))  # localisation quiet
    buf.set_transform(StampedTransform(BASE_LINK, LASER, 0.0, planar(0.2, 0, 0)), static=True)
    assert buf.stalest_link(MAP, LASER) == (MAP, ODOM, 1.0)
    assert buf.stalest_link(BASE_LINK, LASER) is None  # static only


def test_out_of_order_stamps_are_sorted():
    buf = TfBuffer()
    for ts in (0.0, 2.0, 1.0):
        buf.set_transform(StampedTransform(ODOM, BASE_LINK, ts, planar(ts, 0, 0)))
    assert math.isclose(buf.lookup(ODOM, BASE_LINK, 1.5).translation[0], 1.5)


def test_reparenting_a_frame_replaces_its_link():
    buf = TfBuffer()
    buf.set_transform(StampedTransform(ODOM, BASE_LINK, 0.0, planar(1, 0, 0)))
    buf.set_transform(StampedTransform(MAP, BASE_LINK, 0.0, planar(5, 0, 0)))
    assert buf.parent_of(BASE_LINK) == MAP
    assert buf.lookup(MAP, BASE_LINK).translation[0] == 5


def test_pending_lookup_waits_then_times_out_then_succeeds():
    buf = TfBuffer()
    look = PendingLookup(buf, MAP, BASE_LINK, timeout_s=0.5)
    assert look.poll(10.0) is None  # no tree yet: waiting
    assert look.poll(10.4) is None
    with pytest.raises(TfTimeout, match="map <- base_link after 0.50 s"):
        look.poll(10.5)
    assert look.poll(10.6) is None  # a new wait starts
    rep105(buf)
    tf = look.poll(10.7)
    assert tf is not None and math.isclose(tf.to_pose2d().x_m, 1.0 + math.cos(0.5))
    with pytest.raises(ValueError, match="timeout_s"):
        PendingLookup(buf, MAP, BASE_LINK, timeout_s=-1)


def test_map_to_odom_puts_the_robot_at_its_map_pose_whatever_the_drift():
    from stack.tf import map_to_odom

    truth, odom = Pose2D(4.0, -1.0, 2.0), Pose2D(3.1, -0.2, 1.7)  # odometry has drifted
    buf = TfBuffer()
    buf.set_transform(StampedTransform(MAP, ODOM, 5.0, map_to_odom(truth, odom)))
    buf.set_transform(StampedTransform(ODOM, BASE_LINK, 5.0, Transform.from_pose2d(odom)))
    got = buf.lookup(MAP, BASE_LINK).to_pose2d()
    assert close((got.x_m, got.y_m, got.yaw_rad), (truth.x_m, truth.y_m, truth.yaw_rad))
