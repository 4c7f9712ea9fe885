"""Leg segments in the twin's scans: hand thresholds against a learned random forest.

Usage (repository root; needs scikit-learn, which vigil does not depend on)::

    MUJOCO_GL=egl .venv/bin/python scripts/perception_leg_classifier.py

The person walks four scripted routes through the region (rows, columns, diagonals,
0.3-1.3 m/s, pauses) while the robot stands in one of four cells facing one of four
ways; every scan (10 Hz) is split into segments by ``legs.segment_scan`` and each
segment with ``LegConfig.min_points`` or more points is labelled from the twin's
ground truth: a leg when most of its beams hit the person's geoms
(``Twin.person_geom_ids`` against ``LaserScan.geom_ids``). Negatives are walls,
desk, chair and table legs, the pole, the cabinet.

Both classifiers are scored per segment (precision, recall, F1) on routes they were
not tuned or trained on: the forest is trained on two routes and tested on the other
two, and the other way round (leave-routes-out), so no scan of a test route is seen
in training. The hand rule is ``detect_legs``'s (points, width, bulge) with the
default ``LegConfig``. Segments on the static map are counted as the library counts
them (dropped after classification), in a second table.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stack.perception.legs import (  # noqa: E402
    LegConfig,
    Pose2D,
    Scan,
    StaticMap,
    segment_features,
    segment_scan,
)

FEATURES = (
    "n_points", "width", "bulge", "range", "linearity_rms", "circle_radius",
    "circle_rms", "std_from_centroid", "jump_before", "jump_after", "boundary_length",
)  # fmt: skip


def wp(x, y, speed=1.0, pause=0.0):
    return {"x_m": x, "y_m": y, "speed_mps": speed, "pause_s": pause}


ROUTES = (
    (wp(5.7, 2.25, pause=1), wp(0.3, 2.25, 1.3, 2), wp(5.7, 2.25, 0.3, 1)),
    (wp(0.5, 0.3, pause=1), wp(0.5, 2.7, 1.0, 1), wp(3.5, 2.7, 0.6), wp(3.5, 0.3, 0.6, 2),
     wp(5.5, 0.3, 1.3), wp(5.5, 2.7, 1.3)),
    (wp(5.7, 0.95, pause=1), wp(0.3, 0.95, 0.6, 2), wp(5.7, 2.6, 1.0, 1), wp(0.3, 2.6, 1.3)),
    (wp(0.4, 0.4, pause=1), wp(5.6, 2.6, 1.0, 2), wp(1.5, 2.6, 0.3), wp(4.5, 0.4, 0.6, 1)),
)  # fmt: skip
# robot (x, y, yaw) per route: away from the route's lanes, facing into the region
ROBOTS = ((2.5, 0.3, math.pi / 2), (2.5, 1.4, 0.0), (3.5, 1.9, -math.pi / 2), (6.6, 1.5, math.pi))


def features(points: np.ndarray, jump_before: float, jump_after: float) -> np.ndarray:
    """Segment features in the laser frame (Arras et al. 2007's set, abridged)."""
    n = len(points)
    width, bulge = segment_features(points)
    c = points.mean(axis=0)
    rng = float(np.hypot(*c))
    centred = points - c
    std = float(np.sqrt(np.mean(np.sum(centred**2, axis=1))))
    # line fit: smallest singular value = rms distance from the best line
    sv = np.linalg.svd(centred, compute_uv=False)
    lin = float(sv[-1] / math.sqrt(n)) if n >= 2 else 0.0
    # algebraic circle fit (Kasa)
    if n >= 3:
        a = np.c_[2 * points, np.ones(n)]
        b = np.sum(points**2, axis=1)
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        r = math.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 0.0))
        circ = float(np.sqrt(np.mean((np.hypot(*(points - sol[:2]).T) - r) ** 2)))
    else:
        r, circ = 0.0, 0.0
    boundary = float(np.sum(np.hypot(*np.diff(points, axis=0).T))) if n > 1 else 0.0
    return np.array([n, width, bulge, rng, lin, min(r, 5.0), circ, std,
                     min(jump_before, 5.0), min(jump_after, 5.0), boundary])  # fmt: skip


def collect(route: int, cfg: LegConfig, seconds: float | None = None):
    """Segments of one route's scans: features, labels, hand-rule verdicts, on-map flags."""
    from twin.config import TwinConfig
    from twin.twin import Pose2D as TwinPose
    from twin.twin import Twin

    tw = Twin(TwinConfig.from_dict({"person": {"waypoints": list(ROUTES[route])}}), seed=route)
    tw.set_robot_pose(TwinPose(*ROBOTS[route]))
    occ = tw.occupancy_map()
    smap = StaticMap(np.asarray(occ.data) >= 65, occ.resolution_m, occ.origin_m)
    person = set(tw.person_geom_ids().tolist())
    end = seconds or tw.person.end_time_s + 1.0
    rows, labels, hand, on_map = [], [], [], []
    next_scan = 0.0
    from twin.scene import LIDAR_SITE

    site = tw.model.site(LIDAR_SITE).id
    while tw.time_s < end:
        tw.step()
        if tw.time_s < next_scan - 1e-9:
            continue
        next_scan += 0.1
        s = tw.scan()
        scan = Scan(np.asarray(s.ranges_m, float), s.angle_min_rad, s.angle_increment_rad,
                    s.range_min_m, s.range_max_m, tw.time_s)  # fmt: skip
        origin = tw.data.site_xpos[site]
        laser_pose = Pose2D(float(origin[0]), float(origin[1]), tw.ground_truth().robot.yaw_rad)
        pts = scan.points()
        segs = segment_scan(scan, cfg)
        for k, seg in enumerate(segs):
            if len(seg) < cfg.min_points:
                continue
            p = pts[seg]
            before = math.dist(pts[segs[k - 1][-1]], p[0]) if k > 0 else 5.0
            after = math.dist(p[-1], pts[segs[k + 1][0]]) if k + 1 < len(segs) else 5.0
            f = features(p, before, after)
            rows.append(f)
            labels.append(np.mean([g in person for g in s.geom_ids[seg]]) > 0.5)
            width, bulge = f[1], f[2]
            hand.append(
                len(seg) <= cfg.max_points
                and cfg.min_width_m <= width <= cfg.max_width_m
                and cfg.min_bulge_m <= bulge <= cfg.max_bulge_m
            )
            near = smap.distance_m(laser_pose.transform(p)) <= cfg.obstacle_clearance_m
            on_map.append(near.mean() >= cfg.obstacle_fraction)
    tw.close()
    return np.array(rows), np.array(labels), np.array(hand), np.array(on_map)


def prf(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    tp = float(np.sum(pred & truth))
    p = tp / max(1, int(pred.sum()))
    r = tp / max(1, int(truth.sum()))
    return p, r, (2 * p * r / (p + r) if p + r else 0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trees", type=int, default=100)
    args = ap.parse_args()
    try:
        from sklearn.ensemble import RandomForestClassifier
    except ImportError:
        sys.exit("needs scikit-learn: pip install scikit-learn (not a vigil dependency)")
    cfg = LegConfig()
    t0 = time.perf_counter()
    data = [collect(i, cfg) for i in range(len(ROUTES))]
    print(f"collected {sum(len(d[1]) for d in data)} segments "
          f"({sum(int(d[1].sum()) for d in data)} legs) from {len(ROUTES)} routes in "
          f"{time.perf_counter() - t0:.0f} s")  # fmt: skip
    folds = (((0, 1), (2, 3)), ((2, 3), (0, 1)), ((0, 2), (1, 3)), ((1, 3), (0, 2)))
    print("| test routes | classifier | precision | recall | F1 | "
          "after the static map: precision | recall |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|")
    totals = {"hand": [], "forest": []}
    for train, test in folds:
        xtr = np.vstack([data[i][0] for i in train])
        ytr = np.concatenate([data[i][1] for i in train])
        xte = np.vstack([data[i][0] for i in test])
        yte = np.concatenate([data[i][1] for i in test])
        hand = np.concatenate([data[i][2] for i in test])
        on_map = np.concatenate([data[i][3] for i in test])
        rf = RandomForestClassifier(n_estimators=args.trees, min_samples_leaf=2, random_state=0,
                                    n_jobs=1, class_weight="balanced")  # fmt: skip
        rf.fit(xtr, ytr)
        forest = rf.predict(xte).astype(bool)
        for name, pred in (("hand thresholds", hand), ("random forest", forest)):
            p, r, f1 = prf(pred, yte)
            pm, rm, _ = prf(pred & ~on_map, yte)
            totals["hand" if name.startswith("hand") else "forest"].append((p, r, f1, pm, rm))
            print(f"| {test} | {name} | {p:.3f} | {r:.3f} | {f1:.3f} | {pm:.3f} | {rm:.3f} |")
    for k, v in totals.items():
        m = np.mean(v, axis=0)
        print(f"| mean | {k} | {m[0]:.3f} | {m[1]:.3f} | {m[2]:.3f} | {m[3]:.3f} | {m[4]:.3f} |")
    rf = RandomForestClassifier(n_estimators=args.trees, random_state=0).fit(
        np.vstack([d[0] for d in data]), np.concatenate([d[1] for d in data])
    )
    imp = sorted(zip(rf.feature_importances_, FEATURES, strict=True), reverse=True)
    print("forest feature importance:", ", ".join(f"{n} {v:.2f}" for v, n in imp))


if __name__ == "__main__":
    main()
