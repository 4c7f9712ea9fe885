"""Does the camera's computed visibility predict what HOG misses behind the robot?

Run: MUJOCO_GL=egl .venv/bin/python bench/bench_visibility.py [--quick]

The robot stands at a cell's centre facing east; a person stands still at points spread
over the cells beside and beyond it (3 x 3 per cell, as `stack.perception.visibility`
samples them). Each frame is rendered by the twin and searched by perception's HOG
detector; a detection is a box holding the person's projected centre. Beside each
frame, `CameraVisibility.point_hidden` predicts from the calibration and the robot's
pose alone whether the camera can see the person. Prints the confusion of prediction and
detection, and the foot-point error of detections the prediction called hidden (their
legs are partly behind the robot: the fusion's reason to trust the laser there).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from stack.perception.hog import HogPeopleDetector, foot_point  # noqa: E402
from stack.perception.visibility import CameraVisibility  # noqa: E402
from twin.calibration import calibrate_twin  # noqa: E402
from twin.config import TwinConfig  # noqa: E402
from twin.sensors import project  # noqa: E402
from twin.twin import Pose2D, Twin  # noqa: E402

# robot cell -> cells where it may hide someone (east of it, same row and the row above)
LAYOUT = {7: (5, 3, 1, 6, 4), 5: (3, 1, 4, 2), 3: (1, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one robot cell only")
    args = ap.parse_args()
    base = TwinConfig()
    grid = base.grid
    probe = Twin(base, seed=0)
    cal = calibrate_twin(probe)
    probe.close()
    vis = CameraVisibility(cal.homography, grid)
    detector = HogPeopleDetector()
    layout = {3: LAYOUT[3]} if args.quick else LAYOUT
    rows = []  # (predicted hidden, detected, foot error or nan)
    t0 = time.perf_counter()
    for robot_cell, cells in layout.items():
        robot = Pose2D(*grid.center(robot_cell), 0.0)
        for cell in cells:
            for x, y in vis._samples(cell):
                wp = [{"x_m": x, "y_m": y}, {"x_m": x + 0.01, "y_m": y, "speed_mps": 0.1}]
                tw = Twin(TwinConfig.from_dict({"person": {"waypoints": wp}}), seed=0)
                tw.set_robot_pose(robot)
                tw.run(0.2)
                img = np.ascontiguousarray(tw.render_camera()[..., ::-1])
                px, py = tw.person.pose(tw.time_s).position_m
                feet, head = project(
                    tw.camera_info, tw.camera_pose(), np.array([[px, py, 0], [px, py, 1.75]])
                )
                tw.close()
                mid = (feet + head) / 2
                boxes = [
                    b
                    for b in detector.detect(img)
                    if b.x <= mid[0] <= b.x + b.width and b.y <= mid[1] <= b.y + b.height
                ]
                err = float("nan")
                if boxes:
                    b = max(boxes, key=lambda b: b.height)
                    u, v = foot_point(b)
                    fx, fy = cal.homography.image_to_map(u, v)
                    err = float(np.hypot(fx - px, fy - py))
                rows.append((vis.point_hidden(px, py, robot), bool(boxes), err))
            print(f"robot {robot_cell}, person in {cell}: {len(rows)} frames, "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)  # fmt: skip
    r = np.array([(h, d) for h, d, _ in rows], bool)
    errs = np.array([e for _, _, e in rows])
    hid, det = r[:, 0], r[:, 1]
    n = len(rows)
    print(f"frames {n}: predicted hidden {hid.sum()}, detected {det.sum()}")
    print(f"  predicted visible: detected {(~hid & det).sum()}, missed {(~hid & ~det).sum()}")
    print(f"  predicted hidden:  detected {(hid & det).sum()}, missed {(hid & ~det).sum()}")
    ok_vis = errs[~hid & det]
    ok_hid = errs[hid & det]
    if len(ok_vis):
        print(f"  foot error, visible & detected: median {np.nanmedian(ok_vis):.2f} m, "
              f"p90 {np.nanpercentile(ok_vis, 90):.2f} m")  # fmt: skip
    if len(ok_hid):
        print(f"  foot error, hidden & detected: median {np.nanmedian(ok_hid):.2f} m, "
              f"p90 {np.nanpercentile(ok_hid, 90):.2f} m")  # fmt: skip
    miss_when_hidden = (hid & ~det).sum() / max(1, hid.sum())
    miss_when_visible = (~hid & ~det).sum() / max(1, (~hid).sum())
    print(f"  P(miss | hidden) {miss_when_hidden:.2f}, P(miss | visible) {miss_when_visible:.2f}")


if __name__ == "__main__":
    main()
