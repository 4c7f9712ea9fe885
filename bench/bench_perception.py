"""Perception benchmark: HOG throughput and accuracy, leg detection cost, a twin walk.

Usage (repository root)::

    MUJOCO_GL=egl .venv/bin/python bench/bench_perception.py [--repeat 3] [--walk-s 40]

Sections:

1. HOG frames per second at 640 x 400 and 1280 x 800 (native, downscaled, restricted
   to the region's image area, scale step 1.05 / 1.1) on twin frames of a person
   standing in six cells; per setting: detections and cells right.
2. Leg detection + tracking milliseconds per 720-beam scan (synthetic room with a
   chair, a person, the static map).
3. A scripted walk in the twin (the default person script, robot standing in its start
   cell) against ground truth: detection rate, false positives per frame, foot
   position error, cell accuracy, direction accuracy, speed error and speed class
   accuracy. ``--walk-s 0`` skips it.

Figures go to stdout; copy them into docs/BENCHMARKS.md with the command.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import cv2
import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from stack.cells import CellGrid, Direction  # noqa: E402
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus  # noqa: E402
from stack.perception.direction import classify_displacement  # noqa: E402
from stack.perception.hog import HogConfig, HogPeopleDetector  # noqa: E402
from stack.perception.legs import LegConfig, Pose2D, Scan, StaticMap, detect_legs  # noqa: E402
from stack.perception.observation import speed_class  # noqa: E402
from stack.perception.synthetic import simulate_scan, walking_legs  # noqa: E402
from stack.perception.tracker import LegTracker, TrackerConfig, nearest_track  # noqa: E402

STAND_CELLS = (1, 4, 5, 8, 9, 12)


def twin_setup(width_px: int, height_px: int, person_xy=None, seed=0):
    from twin.config import TwinConfig
    from twin.twin import Twin

    data = {"camera": {"width_px": width_px, "height_px": height_px}}
    if person_xy is not None:
        data["person"] = {"waypoints": [{"x_m": person_xy[0], "y_m": person_xy[1], "pause_s": 1e3}]}
    return Twin(TwinConfig.from_dict(data), seed=seed)


def twin_calibration(tw, grid: CellGrid):
    from twin.calibration import calibrate_twin

    return calibrate_twin(tw, grid)


def region_roi(tw, grid: CellGrid, head_m: float = 2.0, pad_px: int = 24):
    """Image area of the region and of people standing in it (floor to head height)."""
    from twin.sensors import project

    (x0, y0), (w, h) = grid.origin_m, grid.size_m
    corners = [(x, y) for x in (x0, x0 + w) for y in (y0, y0 + h)]
    pts = np.array([(x, y, z) for x, y in corners for z in (0.0, head_m)])
    px = project(tw.camera_info, tw.camera_pose(), pts)
    umin, vmin = np.floor(px.min(axis=0)) - pad_px
    umax, vmax = np.ceil(px.max(axis=0)) + pad_px
    W, H = tw.camera_info.width, tw.camera_info.height
    umin, vmin = max(0, int(umin)), max(0, int(vmin))
    umax, vmax = min(W, int(umax)), min(H, int(vmax))
    return (umin, vmin, umax - umin, vmax - vmin)


def bench_hog(repeat: int) -> None:
    grid = CellGrid()
    print("## HOG throughput (twin frames, person standing in cells", STAND_CELLS, ")")
    print(f"cv2 {cv2.__version__}, threads {cv2.getNumThreads()}, repeat {repeat}")
    print("full: a fresh tracker (whole configured area); tracked: the next frame, searched")
    print("in the window around the last box (CameraConfig.track_roi_margin_frac = 0.5)")
    print("| resolution | setting | full ms/frame | full fps | tracked ms/frame | tracked fps"
          " | detected | cell right |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for width, height in ((640, 400), (1280, 800)):
        frames, truths = [], []
        for cell in STAND_CELLS:
            tw = twin_setup(width, height, grid.center(cell), seed=cell)
            cal = twin_calibration(tw, grid)
            roi = region_roi(tw, grid)
            frames.append(cv2.cvtColor(tw.render_camera(), cv2.COLOR_RGB2BGR))
            truths.append(cell)
            tw.close()
        big = width > 640
        settings = [
            ("native, scale 1.05", HogConfig()),
            ("native, scale 1.1", HogConfig(scale_step=1.1)),
            ("region ROI, scale 1.05", HogConfig(roi_px=roi)),
        ]
        if big:
            settings += [
                ("downscale 0.5, scale 1.05", HogConfig(downscale=0.5)),
                ("downscale 0.5 + ROI, scale 1.05", HogConfig(downscale=0.5, roi_px=roi)),
                ("downscale 0.5 + ROI, scale 1.1",
                 HogConfig(downscale=0.5, roi_px=roi, scale_step=1.1)),
            ]  # fmt: skip
        else:
            settings += [
                ("downscale 0.75 + ROI, scale 1.05", HogConfig(downscale=0.75, roi_px=roi)),
                ("ROI, scale 1.1", HogConfig(roi_px=roi, scale_step=1.1)),
            ]
        for name, cfg in settings:
            det = HogPeopleDetector(cfg)
            times, tracked, found, right = [], [], 0, 0
            for k in range(repeat):
                for frame, cell in zip(frames, truths, strict=True):
                    tracker = CameraPeopleTracker(CameraConfig(hog=cfg), grid, cal.homography, det)
                    t0 = time.perf_counter()
                    state = tracker.process_frame(frame, 1.0)
                    t1 = time.perf_counter()
                    again = tracker.process_frame(frame, 2.0)
                    tracked.append(time.perf_counter() - t1)
                    times.append(t1 - t0)
                    if k == 0:
                        seen = again.status is PersonStatus.PERSON and again.missed_frames == 0
                        found += (state.status is PersonStatus.PERSON) + seen
                        right += (state.cell == cell) + (again.cell == cell)
            ms, ms_t = 1000 * statistics.median(times), 1000 * statistics.median(tracked)
            n = 2 * len(frames)
            print(f"| {width}x{height} | {name} | {ms:.0f} | {1000 / ms:.1f} | {ms_t:.0f} | "
                  f"{1000 / ms_t:.1f} | {found}/{n} | {right}/{n} |")  # fmt: skip
        print(f"(ROI at {width}x{height}: {roi})")


def bench_legs(n_scans: int = 300) -> None:
    rng = np.random.default_rng(0)
    room = [((-1, -1), (8, -1)), ((8, -1), (8, 5)), ((8, 5), (-1, 5)), ((-1, 5), (-1, -1))]
    chair = [(5.0, 3.0), (5.4, 3.0), (5.0, 3.4), (5.4, 3.4)]
    occ = np.zeros((120, 180), bool)
    for x, y in chair:
        occ[int((y + 1) / 0.05), int((x + 1) / 0.05)] = True
    smap = StaticMap(occ, 0.05, (-1.0, -1.0))
    scans = []
    for k in range(n_scans):
        t = 0.1 * k
        c = (1.0 + 0.8 * (t % 4.0), 2.0)
        circles = [(x, y, 0.04) for x, y in chair] + [
            (*p, 0.06) for p in walking_legs(c, 0.0, t, 0.8)
        ]
        scans.append(simulate_scan(Pose2D(3.0, 0.5, 1.57), circles, rng, walls=room, stamp_s=t))
    cfg = LegConfig()
    tracker = LegTracker(TrackerConfig())
    t0 = time.perf_counter()
    for s in scans:
        det = detect_legs(s, cfg, Pose2D(3.0, 0.5, 1.57), smap)
        tracker.update(s.stamp_s, [p.position_m for p in det.people])
    ms = 1000 * (time.perf_counter() - t0) / n_scans
    print("## Leg detection")
    print(f"detect_legs + static map + tracker update: {ms:.2f} ms per 720-beam scan "
          f"({n_scans} scans)")  # fmt: skip


def truth_direction(vx: float, vy: float, min_speed: float = 0.2) -> Direction:
    if math.hypot(vx, vy) < min_speed:
        return Direction.NOT_MOVING
    return classify_displacement(vx, vy, 0.0)


def bench_walk(duration_s: float, camera_hz: float = 5.0, scan_hz: float = 10.0) -> None:
    grid = CellGrid()
    tw = twin_setup(640, 400, None, seed=1)
    cal = twin_calibration(tw, grid)
    roi = region_roi(tw, grid)
    config = CameraConfig(hog=HogConfig(roi_px=roi))
    cam = CameraPeopleTracker(config, grid, cal.homography)
    occ_map = tw.occupancy_map()
    smap = StaticMap(np.asarray(occ_map.data) >= 65, occ_map.resolution_m, occ_map.origin_m)
    legs_cfg, tracker = LegConfig(), LegTracker(TrackerConfig())
    from bench_perception_walks import lidar_mount

    mount = lidar_mount(tw)  # the lidar sits 0.24 m ahead of the robot's centre
    stats = {k: [] for k in ("det", "fp", "err", "cell", "cell_inner", "dir", "spd", "cls", "hog")}
    next_cam = next_scan = 0.0
    tracks = ()
    while tw.time_s < duration_s:
        tw.step()
        t = tw.time_s
        truth = tw.ground_truth()
        p = truth.person
        if t >= next_scan:
            next_scan += 1.0 / scan_hz
            s = tw.scan()
            scan = Scan(np.asarray(s.ranges_m, float), s.angle_min_rad, s.angle_increment_rad,
                        s.range_min_m, s.range_max_m, t)  # fmt: skip
            robot = Pose2D(truth.robot.x_m, truth.robot.y_m, truth.robot.yaw_rad)
            det = detect_legs(scan, legs_cfg, robot.compose(mount), smap)
            tracks = tracker.update(t, [q.position_m for q in det.people])
        if t < next_cam:
            continue
        next_cam += 1.0 / camera_hz
        frame = cv2.cvtColor(tw.render_camera(), cv2.COLOR_RGB2BGR)
        t0 = time.perf_counter()
        state = cam.process_frame(frame, t)
        stats["hog"].append(time.perf_counter() - t0)
        in_region = p is not None and p.cell is not None
        true_xy = (p.pose.x_m, p.pose.y_m) if p is not None else None
        foots = [
            cam.homography.image_to_map(b.x + b.width / 2, b.y + b.height * 0.84)
            for b in state.boxes
        ]
        far = [f for f in foots if f is None or true_xy is None or math.dist(f, true_xy) > 1.0]
        stats["fp"].append(len(far))
        if not in_region:
            continue
        seen = state.status is PersonStatus.PERSON and state.missed_frames == 0
        stats["det"].append(seen)
        if not seen:
            continue
        stats["err"].append(math.dist(state.position_m, true_xy))
        stats["cell"].append(state.cell == p.cell)
        x0, y0, x1, y1 = grid.bounds(p.cell)
        if min(true_xy[0] - x0, x1 - true_xy[0], true_xy[1] - y0, y1 - true_xy[1]) > 0.2:
            stats["cell_inner"].append(state.cell == p.cell)
        stats["dir"].append(state.direction == truth_direction(*p.velocity_mps))
        tr = nearest_track([x for x in tracks if t - x.last_update_s < 0.5], true_xy, 1.0)
        true_speed = math.hypot(*p.velocity_mps)
        if tr is not None:
            stats["spd"].append(tr.speed_mps - true_speed)
            stats["cls"].append(speed_class(tr.speed_mps) == speed_class(true_speed))
    tw.close()

    def pct(v):
        return f"{100 * np.mean(v):.0f}% (n={len(v)})" if v else "n/a"

    err = np.array(stats["err"])
    print(f"## Twin walk: default person script, {duration_s:.0f} s, camera {camera_hz} Hz, "
          f"scans {scan_hz} Hz, 640x400, region ROI {roi}")  # fmt: skip
    print(f"detection rate (person in region): {pct(stats['det'])}")
    print(f"false positives per frame: {np.mean(stats['fp']):.3f} (n={len(stats['fp'])})")
    if err.size:
        print(f"foot position error vs pelvis: median {np.median(err):.2f} m, "
              f"p90 {np.percentile(err, 90):.2f} m")  # fmt: skip
    print(f"cell accuracy: {pct(stats['cell'])}; > 0.2 m from borders: {pct(stats['cell_inner'])}")
    print(f"direction accuracy (truth: dominant axis of velocity, < 0.2 m/s not moving): "
          f"{pct(stats['dir'])}")  # fmt: skip
    if stats["spd"]:
        rms = math.sqrt(np.mean(np.square(stats["spd"])))
        print(f"speed RMS error: {rms:.2f} m/s; speed class accuracy: {pct(stats['cls'])}")
    else:
        print("speed: no laser track associated")
    print(f"camera pipeline: {1000 * np.median(stats['hog']):.0f} ms/frame median")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--walk-s", type=float, default=40.0)
    ap.add_argument("--skip-hog", action="store_true")
    args = ap.parse_args()
    if not args.skip_hog:
        bench_hog(args.repeat)
    bench_legs()
    if args.walk_s > 0:
        bench_walk(args.walk_s)


if __name__ == "__main__":
    main()
