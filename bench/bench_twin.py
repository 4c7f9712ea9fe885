"""Benchmark of the digital twin: render, lidar, physics real-time factor, HOG detection.

Run: MUJOCO_GL=egl .venv/bin/python bench/bench_twin.py [--quick]

Prints one line per figure. HOG detection: the person standing at the centre of each of
the 12 cells in 2 headings (side-on and facing the camera) plus walking frames; a frame
counts as detected when a box holds the person's projected centre and is 0.8-2x the
person's projected height; the foot point is the box's bottom centre mapped to the floor
through the camera's ground-plane homography, raw and shrunk by the detector window's
16/128 bottom margin (a fixed shrink, not the calibrated one the thesis's figure 4.9 asks for).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from stack.perception.hog import PersonBox, foot_point  # noqa: E402
from twin.calibration import calibrate_twin  # noqa: E402
from twin.config import TwinConfig  # noqa: E402
from twin.sensors import project  # noqa: E402
from twin.twin import Pose2D, Twin, VelocityCommand  # noqa: E402


def _ms(fn, n: int) -> float:
    fn()  # warm-up (GL context, caches)
    t0 = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - t0) / n * 1000.0


def bench_render(n: int) -> None:
    for w, h in ((640, 400), (1280, 800)):
        for shadows in (True, False):
            cfg = TwinConfig.from_dict(
                {"camera": {"width_px": w, "height_px": h, "shadows": shadows}}
            )
            twin = Twin(cfg, seed=0)
            ms = _ms(twin.render_camera, n)
            twin.close()
            print(f"render {w}x{h} shadows={shadows}: {ms:.1f} ms/frame")


def bench_scan_and_physics(n: int) -> None:
    for beams in (720, 1080):
        twin = Twin(TwinConfig.from_dict({"lidar": {"beams": beams}}), seed=0)
        print(f"scan {beams} beams: {_ms(twin.scan, n):.3f} ms/scan")
    twin = Twin(seed=0)
    steps = 500
    t0 = time.perf_counter()
    for i in range(steps):
        twin.step(VelocityCommand(0.3 * np.sin(i / 50), 0.1, 0.3))
    wall = time.perf_counter() - t0
    rtf = steps * twin.config.control_period_s / wall
    print(f"physics (robot + walking person, no rendering): real-time factor {rtf:.1f}")


def _ground_homography(twin: Twin) -> np.ndarray:
    pts = np.array([[x, y, 0.0] for x in (0.0, 3.0, 6.0) for y in (0.0, 3.0)])
    uv = project(twin.camera_info, twin.camera_pose(), pts)
    hmat, _ = cv2.findHomography(uv, pts[:, :2])
    return hmat


def bench_hog(walk_frames: int) -> None:
    cv2.setNumThreads(2)
    hog = cv2.HOGDescriptor()
    hog.setSVMDetector(cv2.HOGDescriptor_getDefaultPeopleDetector())
    base = TwinConfig()
    frames = []
    for cell in base.grid.cells:
        cx, cy = base.grid.center(cell)
        for heading in (np.pi / 2, np.pi):
            wp = [
                {"x_m": cx, "y_m": cy},
                {"x_m": cx + 0.01 * np.cos(heading), "y_m": cy + 0.01 * np.sin(heading)},
            ]
            frames.append((wp, 0.0))
    walk = [{"x_m": 0.3, "y_m": 0.4}, {"x_m": 5.7, "y_m": 2.6, "speed_mps": 1.2}]
    for t in np.linspace(0.3, 5.0, walk_frames):
        frames.append((walk, float(t)))
    hits = foot_ok = 0
    errs, shrunk_errs, pipe_errs, hog_ms, fp = [], [], [], [], 0
    for wps, t in frames:
        for w in wps[1:]:
            w.setdefault("speed_mps", 0.1)
        twin = Twin(TwinConfig.from_dict({"person": {"waypoints": wps}}), seed=0)
        twin.set_robot_pose(Pose2D(-2.5, -1.6, 0.0))
        twin.run(t)
        img = np.ascontiguousarray(twin.render_camera()[..., ::-1])
        twin.close()
        p = twin.person.pose(twin.time_s)
        x, y = p.position_m
        feet, head = project(
            twin.camera_info, twin.camera_pose(), np.array([[x, y, 0], [x, y, 1.75]])
        )
        t0 = time.perf_counter()
        rects, _ = hog.detectMultiScale(img, winStride=(8, 8), padding=(8, 8), scale=1.05)
        hog_ms.append((time.perf_counter() - t0) * 1000)
        vmid, ph = (feet[1] + head[1]) / 2, feet[1] - head[1]
        good = [
            r
            for r in rects
            if r[0] <= feet[0] <= r[0] + r[2]
            and r[1] <= vmid <= r[1] + r[3]
            and 0.8 < r[3] / ph < 2
        ]
        fp += len(rects) - len(good)
        if good:
            hits += 1
            bx, by, bw, bh = max(good, key=lambda r: r[3])
            hm = _ground_homography(twin)
            # the default window is 64 x 128 with the person in the middle 96 px:
            # shrink the box bottom by that 16/128 margin (thesis figure 4.9)
            pts = np.array([[[bx + bw / 2, by + bh], [bx + bw / 2, by + bh * 112 / 128]]], float)
            raw, shrunk = cv2.perspectiveTransform(pts, hm)[0]
            errs.append(float(np.hypot(raw[0] - x, raw[1] - y)))
            err = float(np.hypot(shrunk[0] - x, shrunk[1] - y))
            shrunk_errs.append(err)
            foot_ok += err <= 0.3
            # perception's foot point (calibrated shrink of fig. 4.9, stack.perception.hog)
            # through the homography the twin's floor points calibrate (twin.calibration)
            u, v = foot_point(PersonBox(int(bx), int(by), int(bw), int(bh), 1.0))
            fx, fy = calibrate_twin(twin).homography.image_to_map(u, v)
            pipe_errs.append(float(np.hypot(fx - x, fy - y)))
    n = len(frames)
    print(
        f"HOG 640x400 (stride 8, scale 1.05): detected {hits}/{n} = {hits / n:.2f}; "
        f"false boxes/frame {fp / n:.2f}; foot point (box bottom less 16/128) within 0.3 m "
        f"{foot_ok}/{n} = {foot_ok / n:.2f}, median error {np.median(shrunk_errs):.2f} m "
        f"(raw box bottom: {np.median(errs):.2f} m); "
        f"HOG {np.median(hog_ms):.0f} ms/frame"
    )
    pipe = np.array(pipe_errs)
    print(
        f"perception foot point (calibrated shrink, twin calibration): within 0.3 m "
        f"{int((pipe <= 0.3).sum())}/{n} = {(pipe <= 0.3).sum() / n:.2f}, "
        f"median {np.median(pipe):.2f} m, p90 {np.percentile(pipe, 90):.2f} m"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = ap.parse_args()
    n = 3 if args.quick else 10
    bench_render(n)
    bench_scan_and_physics(20 if args.quick else 200)
    bench_hog(4 if args.quick else 12)


if __name__ == "__main__":
    main()
