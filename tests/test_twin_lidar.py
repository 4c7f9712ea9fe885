"""The planar lidar: beam layout, true wall distances, the person's two legs, noise."""

import math

import numpy as np
import pytest

from twin.config import TwinConfig
from twin.twin import Pose2D, Twin


def _bare(lidar: dict, person: dict | None = None) -> Twin:
    data = {"room": {"furniture": False}, "lidar": lidar}
    data["person"] = person if person is not None else {"present": False}
    return Twin(TwinConfig.from_dict(data), seed=0)


def test_beam_count_angles_and_limits():
    twin = _bare({"beams": 720, "fov_deg": 270, "range_max_m": 8.0})
    scan = twin.scan()
    assert scan.ranges_m.shape == scan.angles_rad.shape == (720,)
    assert scan.angle_min_rad == pytest.approx(-math.radians(135))
    assert scan.angle_max_rad == pytest.approx(math.radians(135))
    assert np.allclose(np.diff(scan.angles_rad), scan.angle_increment_rad)
    finite = scan.ranges_m[np.isfinite(scan.ranges_m)]
    assert finite.max() <= 8.0 and finite.min() >= scan.range_min_m
    assert np.isinf(scan.ranges_m).any()  # the room's far corners lie beyond 8 m
    # a full circle does not measure the same direction twice
    full = _bare({"beams": 360, "fov_deg": 360}).scan()
    assert full.angle_max_rad - full.angle_min_rad == pytest.approx(2 * math.pi * 359 / 360)


def test_never_sees_the_robot_and_sees_walls_at_their_true_distance():
    twin = _bare({"beams": 720, "fov_deg": 360, "noise_std_m": 0.0, "range_max_m": 20.0})
    twin.set_robot_pose(Pose2D(1.3, 1.1, 0.4))
    scan = twin.scan()
    robot = twin.model.body("mbot/base").id
    assert not np.isin(scan.geom_ids, np.nonzero(twin.model.geom_bodyid == robot)[0]).any()
    origin = twin.data.site_xpos[twin.model.site("mbot/lidar").id]
    x0, y0, x1, y1 = twin.layout.room
    d0, d1 = twin.layout.door_x_m
    checked = 0
    for r, a in zip(scan.ranges_m, scan.angles_rad, strict=True):
        dx, dy = math.cos(a + 0.4), math.sin(a + 0.4)
        # distance to the room's rectangle of wall faces along this beam
        ts = []
        if dx > 1e-9:
            ts.append((x1 - origin[0]) / dx)
        if dx < -1e-9:
            ts.append((x0 - origin[0]) / dx)
        if dy > 1e-9:
            ts.append((y1 - origin[1]) / dy)
        if dy < -1e-9:
            ts.append((y0 - origin[1]) / dy)
        t = min(ts)
        hx, hy = origin[0] + t * dx, origin[1] + t * dy
        near_door = abs(hy - y1) < 1e-6 and d0 - 0.1 < hx < d1 + 0.1
        near_cabinet = hx > x1 - 0.5 and hy < y0 + 1.1
        if near_door or near_cabinet:
            continue
        assert r == pytest.approx(t, abs=1e-4)
        checked += 1
    assert checked > 650


def _leg_clusters(twin: Twin, scan) -> list[np.ndarray]:
    """Consecutive beams on the person's legs, split at range jumps (a leg detector's view)."""
    legs = {
        twin.model.geom(f"person/{k}_{s}_geom").id
        for k in ("shin", "thigh", "foot")
        for s in ("l", "r")
    }
    on = np.isin(scan.geom_ids, list(legs))
    pts = np.column_stack(
        [scan.ranges_m * np.cos(scan.angles_rad), scan.ranges_m * np.sin(scan.angles_rad)]
    )
    clusters, current = [], []
    for i in range(len(on)):
        if on[i] and current and np.linalg.norm(pts[i] - pts[current[-1]]) > 0.05:
            clusters.append(current)
            current = []
        if on[i]:
            current.append(i)
        elif current:
            clusters.append(current)
            current = []
    if current:
        clusters.append(current)
    return [pts[c] for c in clusters]


@pytest.mark.parametrize("distance_m", [1.0, 2.0, 3.0])
def test_sees_the_person_as_two_legs_of_leg_width(distance_m):
    person = {"waypoints": [{"x_m": 1.24 + distance_m, "y_m": 0.75}]}
    twin = _bare({"beams": 720, "fov_deg": 270, "noise_std_m": 0.0}, person)
    twin.set_robot_pose(Pose2D(1.0, 0.75, 0.0))  # lidar 0.24 m ahead of the base centre
    clusters = _leg_clusters(twin, twin.scan())
    assert len(clusters) == 2
    for c in clusters:
        assert len(c) >= 3
        width = np.linalg.norm(c[0] - c[-1])
        assert 0.06 < width < 0.16
        assert np.mean(c[:, 0]) == pytest.approx(distance_m, abs=0.12)
    gap = np.linalg.norm(clusters[0].mean(0) - clusters[1].mean(0))
    assert 0.12 < gap < 0.35


def test_range_noise_follows_the_configured_sigma():
    quiet = _bare({"beams": 720, "fov_deg": 360, "noise_std_m": 0.0}).scan()
    noisy = _bare({"beams": 720, "fov_deg": 360, "noise_std_m": 0.02}).scan()
    ok = np.isfinite(quiet.ranges_m) & np.isfinite(noisy.ranges_m)
    err = noisy.ranges_m[ok] - quiet.ranges_m[ok]
    assert np.std(err) == pytest.approx(0.02, rel=0.15)
    assert abs(np.mean(err)) < 0.005
