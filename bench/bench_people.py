"""Two people (issue 16): identities through crossings, and HOG on twin frames.

Usage (repository root)::

    MUJOCO_GL=egl .venv/bin/python bench/bench_people.py [--seeds 50] [--no-twin]

Part 1, synthetic crossings (pure, no rendering): two people walk through each other
(``synthetic.crossing_paths``) at 0.5, 1.0 and 1.4 m/s, 0-0.6 m apart sideways, seen
at 10 Hz with Gaussian position noise; while they are closer than 0.45 m the detector
gives one position only, the person nearer the camera (their boxes merged by
non-maximum suppression keep the front one; either at random when level), and each
detection is missed with probability 0.1. Scored: identity switches (a confirmed,
updated track nearer the other person than the one it followed before), for
``multi.MultiTracker`` (Hungarian on the Mahalanobis distance, constant-velocity
prediction) and for the one-person code's ``tracker.LegTracker`` (greedy nearest
neighbour within 0.6 m) as the baseline.

Part 2, twin frames: the three scenarios of ``scenarios/people/`` in the twin, the
robot standing at its start cell, the ceiling camera at 5 Hz (640 x 400). Per frame:
the people visible (more than 300 pixels of a walker's geoms in the segmentation
render), HOG's raw boxes, the boxes after NMS, recall (a visible person with a
``people_m`` position within 0.5 m of their pelvis), extra positions (further than
0.5 m from everyone), and the person slots of ``multi.PeoplePerception`` (slot
switches: a slot's estimate nearest another person than before, judged when within
0.5 m of someone). The lidar (10 Hz) runs ``detect_legs`` with the twin's
occupancy map as the static map and ``MultiTracker`` on the scans; "legs" is the share
of slot estimates on a person (within 0.5 m) that got a laser track, and "right legs"
the share of those whose laser track is on the same person (within 0.5 m).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stack.cells import CellGrid  # noqa: E402
from stack.config import read_yaml  # noqa: E402
from stack.perception.camera import CameraConfig, CameraPeopleTracker  # noqa: E402
from stack.perception.multi import MultiTracker, PeoplePerception  # noqa: E402
from stack.perception.synthetic import crossing_paths  # noqa: E402
from stack.perception.tracker import LegTracker, TrackerConfig  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
LIDAR_X_M = 0.24  # the lidar site on the MBot (twin/assets/mbot.xml)


def crossing_switches(make, lateral_m, speed, noise_m, seed, miss=0.1, merge_m=0.45):
    rng = np.random.default_rng(seed)
    tracker = make()
    owner: dict[int, int] = {}
    switches = 0
    half = 1.2
    duration = 2 * half / speed + 0.6
    for k in range(int(duration * 10)):
        t = k / 10.0
        people = crossing_paths(t, half_length_m=half, speed_mps=speed, lateral_m=lateral_m)
        merged = math.dist(*people) < merge_m
        # merged: NMS keeps one box, the person nearer the camera (west), either if level
        front = int(np.argmin([p[0] for p in people])) if lateral_m > 0 else int(rng.integers(2))
        src = [people[front]] if merged else list(people)
        dets = [
            tuple(np.asarray(p) + rng.normal(0, noise_m, 2)) for p in src if rng.random() >= miss
        ]
        for tr in tracker.update(t, dets):
            if merged or not tr.confirmed or tr.last_update_s != t:
                continue
            nearest = int(np.argmin([math.dist(tr.position_m, p) for p in people]))
            if owner.setdefault(tr.track_id, nearest) != nearest:
                switches += 1
                owner[tr.track_id] = nearest
    return switches


def part_synthetic(seeds: int) -> None:
    makers = {
        "MultiTracker (Hungarian, Mahalanobis)": MultiTracker,
        "LegTracker (greedy, 0.6 m)": lambda: LegTracker(TrackerConfig(measurement_sigma_m=0.15)),
    }
    print("## synthetic crossings: crossings with an identity switch / all (total switches)")
    header = "| tracker | noise | " + " | ".join(f"{lat} m apart" for lat in (0.0, 0.2, 0.4, 0.6))
    print(header + " | all |")
    print("|---|---|" + "---|" * 5)
    for name, make in makers.items():
        for noise in (0.05, 0.10):
            cells, tot_bad, tot_n, tot_sw = [], 0, 0, 0
            for lateral in (0.0, 0.2, 0.4, 0.6):
                bad = n = sw = 0
                for speed in (0.5, 1.0, 1.4):
                    for s in range(seeds):
                        k = crossing_switches(make, lateral, speed, noise, s)
                        bad += k > 0
                        sw += k
                        n += 1
                cells.append(f"{bad}/{n} ({sw})")
                tot_bad, tot_n, tot_sw = tot_bad + bad, tot_n + n, tot_sw + sw
            row = f"| {name} | {noise} m | " + " | ".join(cells)
            print(row + f" | {tot_bad}/{tot_n} ({tot_sw}) |")


def scenario_twin(path: Path):
    from twin.config import TwinConfig
    from twin.scene import layout_of
    from twin.twin import Twin
    from vigil.scenario import load_scenario
    from vigil.system import scene_people

    sc = load_scenario(path)
    section = read_yaml(sc.task).get("grid")
    grid = CellGrid.from_mapping(section) if section else CellGrid()
    scene: dict = {"grid": section} if section else {}
    scene["robot"] = {"start_cell": sc.robot_cell}
    door = layout_of(TwinConfig.from_dict(scene)).door_center_m
    scene.update(scene_people(scene, sc, grid, door))
    return Twin(TwinConfig.from_dict(scene), seed=sc.seed), grid


def part_twin(rate_hz: float) -> None:
    from twin.calibration import calibrate_twin

    print("\n## twin frames (5 Hz, 640 x 400, robot standing at its start cell)")
    from stack.perception.legs import LegConfig, Pose2D, Scan, StaticMap, detect_legs

    print("| scenario | frames | visible people | raw boxes | after NMS | recall | extra "
          "| slot switches | legs | right legs |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    totals = np.zeros(9)
    for path in sorted((REPO / "scenarios" / "people").glob("*.yaml")):
        tw, grid = scenario_twin(path)
        with tw:
            cal = calibrate_twin(tw)
            cam = CameraPeopleTracker(CameraConfig(max_people=2), grid, cal.homography)
            pp = PeoplePerception(grid)
            occ = tw.occupancy_map()
            smap = StaticMap(np.asarray(occ.data) >= 65, occ.resolution_m, occ.origin_m)
            legs = MultiTracker()
            laser_tracks: tuple = ()
            scan_every = round(1.0 / tw.config.lidar.rate_hz / tw.config.control_period_s)
            on_person = with_legs = right_legs = 0
            ids = [set(tw.person_geom_ids(i).tolist()) for i in range(len(tw.people))]
            period = round(1.0 / rate_hz / tw.config.control_period_s)
            end = min(tw.end_time_s, 60.0)
            frames = visible = raw = kept = found = extra = 0
            slot_of: dict[int, int] = {}
            switches = 0
            k = 0
            while tw.time_s < end:
                tw.step()
                k += 1
                if k % scan_every == 0:
                    sc = tw.scan()
                    g = tw.ground_truth().robot
                    c, s_ = math.cos(g.yaw_rad), math.sin(g.yaw_rad)
                    laser = Pose2D(g.x_m + LIDAR_X_M * c, g.y_m + LIDAR_X_M * s_, g.yaw_rad)
                    scan = Scan(np.asarray(sc.ranges_m, float), sc.angle_min_rad,
                                sc.angle_increment_rad, sc.range_min_m, sc.range_max_m)  # fmt: skip
                    found_legs = detect_legs(scan, LegConfig(), laser, smap)
                    laser_tracks = legs.update(tw.time_s, found_legs.people)
                if k % period:
                    continue
                gt = tw.ground_truth()
                seg = tw.render_segmentation()
                counts = [int(np.isin(seg, list(g)).sum()) for g in ids]
                truth = [(p.pose.x_m, p.pose.y_m) for p in gt.people]
                seen = [i for i, c in enumerate(counts) if c > 300]
                img = tw.render_camera()[:, :, ::-1]
                state = cam.process_frame(np.ascontiguousarray(img), tw.time_s)
                frames += 1
                visible += len(seen)
                raw += len(state.boxes)
                kept += len(state.people_m)
                found += sum(
                    any(math.dist(truth[i], q) < 0.5 for q in state.people_m) for i in seen
                )
                extra += sum(all(math.dist(t, q) >= 0.5 for t in truth) for q in state.people_m)
                for p in pp.update(tw.time_s, state.people_m, laser_tracks):
                    if p.position_m is None:
                        continue
                    d = [math.dist(p.position_m, t) for t in truth]
                    i = int(np.argmin(d))
                    if d[i] > 0.5 or math.dist(*truth) < 0.5:
                        continue
                    on_person += 1
                    if p.speed_mps is not None:
                        with_legs += 1
                        leg = [t for t in laser_tracks if t.track_id == p.laser_track_id]
                        right_legs += any(math.dist(t.position_m, truth[i]) < 0.5 for t in leg)
                    if slot_of.setdefault(p.slot, i) != i:
                        switches += 1
                        slot_of[p.slot] = i
            rec = found / max(visible, 1)
            lg, rl = with_legs / max(on_person, 1), right_legs / max(with_legs, 1)
            print(f"| {path.stem} | {frames} | {visible} | {raw} | {kept} | {rec:.2f} | {extra} "
                  f"| {switches} | {lg:.2f} | {rl:.2f} |")  # fmt: skip
            totals += (frames, visible, raw, kept, found, extra, on_person, with_legs, right_legs)
    f, v, r, kk, fo, ex, op, wl, rl = totals
    print(f"| all | {f:.0f} | {v:.0f} | {r:.0f} | {kk:.0f} | {fo / max(v, 1):.2f} | {ex:.0f} "
          f"| | {wl / max(op, 1):.2f} | {rl / max(wl, 1):.2f} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--no-twin", action="store_true")
    ap.add_argument("--camera-hz", type=float, default=5.0)
    args = ap.parse_args()
    part_synthetic(args.seeds)
    if not args.no_twin:
        part_twin(args.camera_hz)


if __name__ == "__main__":
    main()
