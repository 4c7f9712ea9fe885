"""Perception against the twin's ground truth over scripted walks through all 12 cells.

Usage (repository root)::

    MUJOCO_GL=egl .venv/bin/python bench/bench_perception_walks.py [--quick] [--camera-hz 5]

The person walks scripted waypoints (``twin.config.Waypoint``) at 0.3, 0.6, 1.0 and
1.3 m/s with pauses: east-west sweeps along both rows of cells and north-south moves
through five of the six columns, so every cell is crossed in both axes. The robot
stands in cell 7 facing north (the thesis's rest cell, pushed to the cell's south
edge so the person's lanes pass it), except in the last walk, where it drives east
through the south row while the person walks the north row. Per camera frame (640 x
400 at ``--camera-hz``, the resolution decisions use) the whole pipeline runs as
deployed: ``CameraPeopleTracker`` with the default ``CameraConfig``, ``detect_legs``
on every scan (10 Hz) with the twin's occupancy map as the static map, ``LegTracker``,
and the track chosen as ``ObservationCombiner`` chooses it (nearest the *camera's*
position, not the true one).

Metrics (definitions in docs/PERCEPTION.md, "How the benchmark scores"): detection
rate, false positives per frame, foot position error, cell accuracy (all frames and
> 0.15 m from a cell border), direction accuracy, laser association rate, speed RMS
error and speed-class accuracy, and the camera pipeline's frames per second at 640 x
400 and 1280 x 800. The truth for direction and speed is the pelvis's mean velocity
over the last ``TRUTH_WINDOW_S`` (0.5 s, the direction estimator's window); the
instantaneous velocity and "steady" frames (true velocity unchanged for 1 s) are
reported beside it.

``--shadows on|off``, ``--antialias N`` and ``--blur SIGMA`` render the twin's camera
otherwise (the real-time twin's cost; ``--antialias 0 --blur 0.7``: the lens's blur in
place of the multisampling). ``--quick`` runs two short walks and the 640 x 400 timing only
(about a minute);
``--no-short-box`` runs the pipeline without the short-box foot refinement
(``CameraConfig.short_box_ratio=None``), as it was before, for comparison.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stack.cells import CellGrid, Direction  # noqa: E402
from stack.perception.camera import CameraConfig, CameraPeopleTracker, PersonStatus  # noqa: E402
from stack.perception.direction import classify_displacement  # noqa: E402
from stack.perception.hog import HogConfig  # noqa: E402
from stack.perception.legs import LegConfig, Pose2D, Scan, StaticMap, detect_legs  # noqa: E402
from stack.perception.observation import (  # noqa: E402
    CombinerConfig,
    ObservationCombiner,
    speed_class,
)
from stack.perception.tracker import LegTracker, TrackerConfig  # noqa: E402

TRUTH_WINDOW_S = 0.5  # truth velocity = pelvis displacement over this window / window
NOT_MOVING_BELOW_MPS = 0.2  # truth "Not moving" below this mean speed (the slow class)
BORDER_MARGIN_M = 0.15  # "away from borders": farther than this from every cell edge
STEADY_S = 1.0  # "steady" frames: the true velocity has not changed for this long
FP_DISTANCE_M = 1.0  # a box whose floor point is farther than this from the person

ROBOT_STAND = (2.5, 0.3, math.pi / 2)  # cell 7, facing north


def wp(x, y, speed=1.0, pause=0.0):
    return {"x_m": x, "y_m": y, "speed_mps": speed, "pause_s": pause}


@dataclass(frozen=True)
class Walk:
    name: str
    waypoints: tuple[dict, ...]
    robot: tuple[float, float, float] = ROBOT_STAND
    robot_cmd: tuple[float, float, float] | None = None  # body-frame command while driving
    robot_drive_s: float = 0.0
    tail_s: float = 1.0  # run on after the last waypoint is reached

    def duration_s(self) -> float:
        first = self.waypoints[0]
        t, x, y = first["pause_s"], first["x_m"], first["y_m"]
        for w in self.waypoints[1:]:
            t += math.dist((x, y), (w["x_m"], w["y_m"])) / w["speed_mps"] + w["pause_s"]
            x, y = w["x_m"], w["y_m"]
        return t + self.tail_s


N, S = 2.25, 0.95  # lanes of the north and south rows (S clears the robot at y 0..0.6)
WALKS = (
    Walk("north row: west 1.3, east 0.3", (
        wp(5.7, N, pause=1.0), wp(0.3, N, 1.3, 2.0), wp(5.7, N, 0.3, 1.0))),
    Walk("south row: west 1.0, east 0.6", (
        wp(5.7, S, pause=1.0), wp(0.3, S, 1.0, 2.0), wp(5.7, S, 0.6, 1.0))),
    Walk("columns north-south, 1.3 / 0.3 / 1.0 / 0.6 / 1.3", (
        wp(0.5, 0.3, pause=1.0), wp(0.5, 2.7, 1.3, 1.0), wp(1.5, 2.7, 0.6),
        wp(1.5, 0.3, 0.3, 1.0), wp(3.5, 0.3, 1.0), wp(3.5, 2.7, 1.0, 2.0),
        wp(4.5, 2.7, 0.6), wp(4.5, 0.3, 0.6), wp(5.5, 0.3, 0.6), wp(5.5, 2.7, 1.3, 1.0))),
    Walk("robot driving east at 0.3 m/s; person north row east 1.0, west 0.6", (
        wp(0.3, N, pause=1.0), wp(5.7, N, 1.0, 1.0), wp(0.3, N, 0.6, 0.5)),
        robot=(0.5, 0.3, math.pi / 2), robot_cmd=(0.0, -0.3, 0.0), robot_drive_s=16.0),
)  # fmt: skip
QUICK_WALKS = (
    Walk("quick: north row west 1.3, south row east 0.6", (
        wp(5.7, N, pause=1.0), wp(0.3, N, 1.3, 1.0), wp(0.3, S, 0.6), wp(5.7, S, 0.6, 1.0))),
)  # fmt: skip


def truth_direction(vx: float, vy: float) -> Direction:
    if math.hypot(vx, vy) < NOT_MOVING_BELOW_MPS:
        return Direction.NOT_MOVING
    return classify_displacement(vx, vy, 0.0)


def border_distance(grid: CellGrid, cell: int, x: float, y: float) -> float:
    x0, y0, x1, y1 = grid.bounds(cell)
    return min(x - x0, x1 - x, y - y0, y1 - y)


@dataclass
class Frame:
    """One camera frame's truth and estimates (person inside the region or not)."""

    t: float
    in_region: bool
    truth_cell: int | None
    border_m: float
    v_win: tuple[float, float]
    v_inst: tuple[float, float]
    steady: bool
    lidar_hits: int
    detected: bool = False
    false_pos: int = 0
    err_m: float | None = None
    cell: int | None = None
    direction: Direction = Direction.NOT_MOVING
    track_speed: float | None = None
    obs_velocity: str = ""


@dataclass
class WalkResult:
    name: str
    frames: list[Frame] = field(default_factory=list)
    ms: list[float] = field(default_factory=list)


def lidar_mount(tw) -> Pose2D:
    """The lidar's pose in the robot frame, read from the twin's model."""
    from twin.scene import LIDAR_SITE

    g = tw.ground_truth().robot
    p = tw.data.site_xpos[tw.model.site(LIDAR_SITE).id]
    c, s = math.cos(g.yaw_rad), math.sin(g.yaw_rad)
    dx, dy = p[0] - g.x_m, p[1] - g.y_m
    return Pose2D(c * dx + s * dy, -s * dx + c * dy, 0.0)


def run_walk(
    walk: Walk,
    camera_hz: float,
    width: int = 640,
    height: int = 400,
    camera_cfg: CameraConfig | None = None,
    leg_cfg: LegConfig | None = None,
    tracker_cfg: TrackerConfig | None = None,
    seed: int = 0,
    render: dict | None = None,
) -> WalkResult:
    from twin.calibration import calibrate_twin
    from twin.config import TwinConfig
    from twin.twin import Pose2D as TwinPose
    from twin.twin import Twin, VelocityCommand

    data = {
        "camera": {"width_px": width, "height_px": height, **(render or {})},
        "person": {"waypoints": list(walk.waypoints)},
    }
    tw = Twin(TwinConfig.from_dict(data), seed=seed)
    tw.set_robot_pose(TwinPose(*walk.robot))
    grid = tw.config.grid
    cal = calibrate_twin(tw)
    cam = CameraPeopleTracker(camera_cfg or CameraConfig(), grid, cal.homography)
    occ = tw.occupancy_map()
    smap = StaticMap(np.asarray(occ.data) >= 65, occ.resolution_m, occ.origin_m)
    mount = lidar_mount(tw)
    leg_cfg = leg_cfg or LegConfig()
    tracker = LegTracker(tracker_cfg or TrackerConfig())
    combiner = ObservationCombiner(grid, CombinerConfig())
    person_ids = set(tw.person_geom_ids().tolist())
    scan_dt = 1.0 / tw.config.lidar.rate_hz
    result = WalkResult(walk.name)
    next_cam = next_scan = 0.0
    tracks = ()
    hits = 0
    duration = walk.duration_s()
    script = tw.person
    while tw.time_s < duration:
        driving = walk.robot_cmd is not None and tw.time_s < walk.robot_drive_s
        tw.step(VelocityCommand(*walk.robot_cmd) if driving else None)
        t = tw.time_s
        if t >= next_scan - 1e-9:
            next_scan += scan_dt
            s = tw.scan()
            scan = Scan(np.asarray(s.ranges_m, float), s.angle_min_rad, s.angle_increment_rad,
                        s.range_min_m, s.range_max_m, t)  # fmt: skip
            if walk.robot_cmd is None:
                g = tw.ground_truth().robot
                robot = Pose2D(g.x_m, g.y_m, g.yaw_rad)
            else:  # a moving robot knows its pose from odometry only
                o = tw.odometry().pose
                robot = Pose2D(o.x_m, o.y_m, o.yaw_rad)
            det = detect_legs(scan, leg_cfg, robot.compose(mount), smap)
            tracks = tracker.update(t, det.people)
            hits = int(sum(1 for gid in s.geom_ids if gid in person_ids))
        if t < next_cam - 1e-9:
            continue
        next_cam += 1.0 / camera_hz
        frame_bgr = cv2.cvtColor(tw.render_camera(), cv2.COLOR_RGB2BGR)
        t0 = time.perf_counter()
        state = cam.process_frame(frame_bgr, t)
        result.ms.append(1000 * (time.perf_counter() - t0))
        p = tw.ground_truth().person
        xy = p.pose.x_m, p.pose.y_m
        then = script.pose(t - TRUTH_WINDOW_S).position_m
        v_win = ((xy[0] - then[0]) / TRUTH_WINDOW_S, (xy[1] - then[1]) / TRUTH_WINDOW_S)
        steady = all(
            np.allclose(script.pose(t - k * 0.1).velocity_mps, p.velocity_mps)
            for k in range(1, int(STEADY_S / 0.1) + 1)
        )
        f = Frame(
            t=t,
            in_region=p.cell is not None,
            truth_cell=p.cell,
            border_m=border_distance(grid, p.cell, *xy) if p.cell is not None else 0.0,
            v_win=v_win,
            v_inst=p.velocity_mps,
            steady=steady,
            lidar_hits=hits,
        )
        foot = cam.config.foot.bottom_shrink_frac
        for b in state.boxes:
            q = cal.homography.image_to_map(b.x + b.width / 2, b.y + b.height * (1 - foot))
            f.false_pos += q is None or math.dist(q, xy) > FP_DISTANCE_M
        f.detected = state.status is PersonStatus.PERSON and state.missed_frames == 0
        if f.detected:
            f.err_m = math.dist(state.position_m, xy)
            f.cell = state.cell
            f.direction = state.direction
        obs = combiner.combine(t, state, tracks, None)
        f.obs_velocity = obs.velocity_label
        f.track_speed = obs.speed_mps
        result.frames.append(f)
    tw.close()
    return result


def pct(values) -> str:
    v = list(values)
    return f"{100 * np.mean(v):.1f} % (n={len(v)})" if v else "n/a"


def truth_label(v: tuple[float, float]) -> str:
    d = truth_direction(*v)
    if d is Direction.NOT_MOVING:
        return "Not moving"
    return f"{d.label} {speed_class(math.hypot(*v)).label}"


def metrics(frames: list[Frame]) -> dict[str, str]:
    inr = [f for f in frames if f.in_region]
    det = [f for f in inr if f.detected]
    err = np.array([f.err_m for f in det])
    m: dict[str, str] = {}
    m["camera frames (person in region / all)"] = f"{len(inr)} / {len(frames)}"
    m["detection rate"] = pct(f.detected for f in inr)
    m["false positives per frame"] = f"{np.mean([f.false_pos for f in frames]):.3f}"
    if err.size:
        m["foot error median / p90"] = (
            f"{np.median(err):.2f} m / {np.percentile(err, 90):.2f} m; "
            f"within 0.3 m: {100 * np.mean(err <= 0.3):.0f} %"
        )
    m["cell accuracy: all"] = pct(f.cell == f.truth_cell for f in det)
    m[f"cell accuracy: > {BORDER_MARGIN_M} m from borders"] = pct(
        f.cell == f.truth_cell for f in det if f.border_m > BORDER_MARGIN_M
    )
    m["direction accuracy (truth: 0.5 s mean velocity)"] = pct(
        f.direction == truth_direction(*f.v_win) for f in det
    )
    m["direction accuracy, steady frames"] = pct(
        f.direction == truth_direction(*f.v_win) for f in det if f.steady
    )
    m["direction accuracy (truth: instantaneous)"] = pct(
        f.direction == truth_direction(*f.v_inst) for f in det
    )
    m["lidar sees the person (>= 1 beam)"] = pct(f.lidar_hits > 0 for f in det)
    m["laser association rate (camera person has a track)"] = pct(
        f.track_speed is not None for f in det
    )
    m["laser association rate, lidar sees the person"] = pct(
        f.track_speed is not None for f in det if f.lidar_hits > 0
    )
    sp = [f for f in det if f.track_speed is not None]
    if sp:
        e = [f.track_speed - math.hypot(*f.v_win) for f in sp]
        e_inst = [f.track_speed - math.hypot(*f.v_inst) for f in sp]
        m["speed RMS error (0.5 s truth / instantaneous)"] = (
            f"{math.sqrt(np.mean(np.square(e))):.2f} / "
            f"{math.sqrt(np.mean(np.square(e_inst))):.2f} m/s"
        )
        m["speed-class accuracy (0.5 s truth)"] = pct(
            speed_class(f.track_speed) == speed_class(math.hypot(*f.v_win)) for f in sp
        )
        m["speed-class accuracy, steady frames"] = pct(
            speed_class(f.track_speed) == speed_class(math.hypot(*f.v_win)) for f in sp if f.steady
        )
        m["speed-class accuracy (instantaneous truth)"] = pct(
            speed_class(f.track_speed) == speed_class(math.hypot(*f.v_inst)) for f in sp
        )
    m["observation velocity label (direction + class) accuracy"] = pct(
        f.obs_velocity == truth_label(f.v_win) for f in det
    )
    return m


def timing(width: int, height: int, camera_cfg: CameraConfig, label: str, seconds: float) -> str:
    """Camera pipeline ms/frame on the first walk's frames at one resolution."""
    walk = Walk("timing", WALKS[0].waypoints, tail_s=0.0)
    walk = Walk("timing", walk.waypoints[:2], tail_s=0.0)
    r = run_walk(walk, 5.0, width, height, camera_cfg)
    ms = r.ms[: int(seconds * 5)]
    det = [f.detected for f in r.frames if f.in_region]
    med = statistics.median(ms)
    return (
        f"| {width}x{height} | {label} | {med:.0f} | {1000 / med:.1f} | "
        f"{np.percentile(ms, 90):.0f} | {100 * np.mean(det):.0f} % |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one short walk, 640x400 timing only")
    ap.add_argument("--camera-hz", type=float, default=5.0)
    ap.add_argument("--no-short-box", action="store_true",
                    help="CameraConfig(short_box_ratio=None): the pipeline before short boxes' "
                         "foreground feet (for comparison)")  # fmt: skip
    ap.add_argument(
        "--shadows",
        choices=("on", "off"),
        default=None,
        help="the twin's camera.shadows (default: the twin's default)",
    )
    ap.add_argument(
        "--antialias",
        type=int,
        default=None,
        help="the twin's camera.antialias_samples (default: the twin's default)",
    )
    ap.add_argument(
        "--blur",
        type=float,
        default=None,
        help="the twin's camera.blur_sigma_px, the lens's blur (default: the twin's default)",
    )
    args = ap.parse_args()
    render = {}
    if args.shadows is not None:
        render["shadows"] = args.shadows == "on"
    if args.antialias is not None:
        render["antialias_samples"] = args.antialias
    if args.blur is not None:
        render["blur_sigma_px"] = args.blur
    walks = QUICK_WALKS if args.quick else WALKS
    camera_cfg = CameraConfig(short_box_ratio=None) if args.no_short_box else CameraConfig()
    setting = "short_box_ratio=None" if args.no_short_box else "default"
    print(f"cv2 {cv2.__version__}, threads {cv2.getNumThreads()}, camera {args.camera_hz} Hz, "
          f"640x400, {setting} CameraConfig, default LegConfig / TrackerConfig, "
          f"render {render or 'default'}")  # fmt: skip
    t_start = time.perf_counter()
    all_frames: list[Frame] = []
    all_ms: list[float] = []
    for walk in walks:
        t0 = time.perf_counter()
        r = run_walk(walk, args.camera_hz, camera_cfg=camera_cfg, render=render)
        all_frames += r.frames
        all_ms += r.ms
        cells = sorted({f.truth_cell for f in r.frames if f.truth_cell is not None})
        print(f"\n## {walk.name} ({walk.duration_s():.0f} s, cells {cells}, "
              f"{time.perf_counter() - t0:.0f} s wall)")  # fmt: skip
        for k, v in metrics(r.frames).items():
            print(f"- {k}: {v}")
    cells = sorted({f.truth_cell for f in all_frames if f.truth_cell is not None})
    print(f"\n## All walks ({len(cells)} cells visited)")
    print("| metric | value |\n|---|---|")
    for k, v in metrics(all_frames).items():
        print(f"| {k} | {v} |")
    print(f"| camera pipeline in the walks, median | {statistics.median(all_ms):.0f} ms/frame |")
    print("\n## Camera pipeline timing (process_frame on twin frames of the first walk)")
    print("| resolution | setting | median ms | fps | p90 ms | detected |")
    print("|---|---|---:|---:|---:|---:|")
    print(timing(640, 400, camera_cfg, f"{setting} (scale 1.05, tracking window)", 20))
    if not args.quick:
        print(timing(1280, 800, camera_cfg, f"{setting} (scale 1.05, tracking window)", 20))
        print(timing(1280, 800, replace(camera_cfg, hog=HogConfig(downscale=0.5)),
                     "downscale 0.5", 20))  # fmt: skip
    print(f"\ntotal wall time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
