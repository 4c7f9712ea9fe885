"""Several walkers in the twin and people in scenarios (issue 16)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from stack.cells import CellGrid, ConfigError
from stack.geometry import Pose2D
from stack.perception.legs import LegConfig, Scan, detect_legs
from twin.config import PersonConfig, TwinConfig, Waypoint, walker_config
from twin.scene import person_prefix
from twin.twin import Twin
from vigil.scenario import load_scenario, parse_scenario
from vigil.system import scene_people

REPO = Path(__file__).resolve().parents[1]
PEOPLE = sorted((REPO / "scenarios" / "people").glob("*.yaml"))
LIDAR_X_M = 0.24  # twin/assets/mbot.xml


def standing(x, y, **kw):
    return PersonConfig(waypoints=(Waypoint(x_m=x, y_m=y),), **kw)


def two_walkers(**kw) -> TwinConfig:
    a = PersonConfig(
        waypoints=(Waypoint(x_m=2.5, y_m=0.6), Waypoint(x_m=4.5, y_m=0.6, speed_mps=0.8))
    )
    return TwinConfig(people=(a, standing(2.6, 2.4)), **kw)


# -- configuration ------------------------------------------------------------------------
def test_person_still_means_one_walker_and_people_a_list():
    assert len(TwinConfig().walkers) == 1
    assert TwinConfig().walkers[0] == TwinConfig().person
    assert TwinConfig(person=PersonConfig(present=False)).walkers == ()
    cfg = TwinConfig.from_dict({"people": [{"height_m": 1.6}, {"height_m": 1.9}]})
    assert [w.height_m for w in cfg.walkers] == [1.6, 1.9]


def test_walkers_after_the_first_are_dressed_apart_unless_dressed_by_the_file():
    cfg = TwinConfig(people=(PersonConfig(), PersonConfig(), PersonConfig()))
    shirts = {w.shirt_rgb for w in cfg.walkers}
    assert len(shirts) == 3 and cfg.walkers[0].shirt_rgb == PersonConfig().shirt_rgb
    mine = PersonConfig(shirt_rgb=(0.9, 0.9, 0.9))
    assert walker_config(mine, 1) is mine


def test_bad_people_entries_name_the_key():
    with pytest.raises(ConfigError) as err:
        TwinConfig.from_dict({"people": [{}, {"height_m": 3.0}]}, "twin")
    assert err.value.key == "twin.people[1].height_m"
    with pytest.raises(ConfigError) as err:
        TwinConfig.from_dict({"person": {}, "people": [{}]})
    assert err.value.key == "people"


# -- the scene and the sensors -------------------------------------------------------------
def test_two_walkers_are_placed_and_reported():
    with Twin(two_walkers(), seed=0) as tw:
        assert len(tw.people) == 2 and tw.person is tw.people[0]
        m = tw.model
        for i in range(2):
            assert m.body(person_prefix(i) + "torso").mocapid[0] >= 0
        assert set(tw.person_geom_ids(0)).isdisjoint(tw.person_geom_ids(1))
        assert len(tw.person_geom_ids()) == len(tw.person_geom_ids(0)) * 2
        tw.run(1.0)
        gt = tw.ground_truth()
        assert len(gt.people) == 2 and gt.person == gt.people[0]
        a, b = gt.people
        assert a.pose.x_m == pytest.approx(3.3, abs=0.05)  # 0.8 m/s for 1 s
        assert (b.pose.x_m, b.pose.y_m) == pytest.approx((2.6, 2.4))
        assert a.cell == CellGrid().cell_at(3.3, 0.6) and b.cell == CellGrid().cell_at(2.6, 2.4)
        # each walker's torso is where its truth says
        for i, p in enumerate(gt.people):
            xyz = tw.data.xpos[m.body(person_prefix(i) + "torso").id]
            assert (xyz[0], xyz[1]) == pytest.approx((p.pose.x_m, p.pose.y_m), abs=1e-6)


def test_the_lidar_sees_two_pairs_of_legs():
    cfg = TwinConfig(people=(standing(2.6, 0.8), standing(2.6, 2.2)))
    with Twin(cfg, seed=1) as tw:
        tw.set_robot_pose(Pose2D(0.5, 1.5, 0.0))  # west of both, facing east
        tw.step()
        scan = tw.scan()
        hits = set(scan.geom_ids.tolist())
        for i in range(2):
            assert hits & set(tw.person_geom_ids(i).tolist()), f"walker {i} not hit"
        rob = tw.ground_truth().robot
        laser = Pose2D(
            rob.x_m + LIDAR_X_M * math.cos(rob.yaw_rad),
            rob.y_m + LIDAR_X_M * math.sin(rob.yaw_rad),
            rob.yaw_rad,
        )
        s = Scan(
            np.asarray(scan.ranges_m, float),
            scan.angle_min_rad,
            scan.angle_increment_rad,
            scan.range_min_m,
            scan.range_max_m,
        )
        found = detect_legs(s, LegConfig(allow_single_leg=False), laser)
        pairs = [p for p in found.people if len(p.legs) == 2]
        near = [min(math.dist(p.position_m, w) for p in pairs) for w in ((2.6, 0.8), (2.6, 2.2))]
        assert max(near) < 0.15, near


def test_one_walker_scene_is_unchanged():
    with Twin(TwinConfig(), seed=0) as tw:
        names = [tw.model.body(i).name for i in range(tw.model.nbody)]
        assert not any(n.startswith("person2/") for n in names)
        assert len(tw.ground_truth().people) == 1


@pytest.mark.slow
def test_the_camera_sees_both_walkers_in_their_own_clothes():
    with Twin(two_walkers(), seed=0) as tw:
        seg = tw.render_segmentation()
        img = tw.render_camera()
        shirts = []
        for i in range(2):
            mask = np.isin(seg, tw.person_geom_ids(i))
            assert mask.sum() > 500, f"walker {i} hardly visible"
            shirts.append(img[mask].mean(axis=0))
        assert np.abs(shirts[0] - shirts[1]).max() > 20  # red against blue


# -- scenarios ----------------------------------------------------------------------------
def test_the_people_scenarios_validate_and_give_two_walks():
    assert {p.stem for p in PEOPLE} == {"split", "linger", "crossing"}
    for path in PEOPLE:
        sc = load_scenario(path)
        assert len(sc.walkers) == 2, path
        walks = sc.people_waypoints(CellGrid(), (7.0, 5.2))
        assert len(walks) == 2 and all(len(w) >= 4 for w in walks)
        scene = scene_people({}, sc, CellGrid(), (7.0, 5.2))
        cfg = TwinConfig.from_dict(scene)
        assert len(cfg.walkers) == 2 and cfg.walkers[0].shirt_rgb != cfg.walkers[1].shirt_rgb


def scenario(**over):
    data = {"name": "t", "task": str(REPO / "config" / "task-r2.yaml")}
    data.update(over)
    return data


@pytest.mark.parametrize(
    "people, key",
    [
        ([{"walk": []}, {"walk": [{"speed_mps": 1.0}]}], "people[1].walk[0].to"),
        ([{"walk": [{"to": "door", "speed_mps": 3.0}]}], "people[0].walk[0].speed_mps"),
        ([{"start": "roof"}], "people[0].start"),
        ([{"walk": [], "run": 1}], "people[0].run"),
        ([{"walk": [{"to": "door", "pace": 1}]}], "people[0].walk[0].pace"),
        ([], "people"),
        ({"start": "outside"}, "people"),
        (["door"], "people[0]"),
    ],
)
def test_a_malformed_people_entry_is_refused_with_its_key(people, key):
    with pytest.raises(ConfigError) as err:
        parse_scenario(scenario(people=people))
    assert err.value.key == key


def test_person_and_people_exclude_each_other_and_person_still_works():
    with pytest.raises(ConfigError) as err:
        parse_scenario(scenario(person={}, people=[{}]))
    assert err.value.key == "people"
    sc = parse_scenario(scenario(person={"walk": [{"to": 1}]}))
    assert len(sc.walkers) == 1 and sc.walk[0].to == 1
    assert list(scene_people({}, sc, CellGrid(), (7.0, 5.2))) == ["person"]


def test_an_unknown_cell_in_a_second_walk_names_it():
    # refused where it is read (issue 23), against the task's grid
    with pytest.raises(ConfigError) as err:
        parse_scenario(scenario(people=[{}, {"walk": [{"to": 40}]}]))
    assert err.value.key == "people[1].walk[0].to"


def test_prepare_writes_every_walker_into_the_twin_scene(tmp_path):
    import yaml

    from vigil.deployment import parse_deployment
    from vigil.system import prepare

    (tmp_path / "policy.npz").write_bytes(b"")
    data = yaml.safe_load((REPO / "config" / "twin.yaml").read_text())
    task = str(REPO / "config" / "task-r2-n2.yaml")
    data.update(task=task, policy=str(tmp_path / "policy.npz"))
    data["twin"]["scene"] = str(REPO / "config" / "twin-scene.yaml")
    dep = parse_deployment(data, tmp_path / "twin.yaml")
    sc = load_scenario(REPO / "scenarios" / "people" / "crossing.yaml")
    prepare(dep, tmp_path / "run", sc, say=lambda s: None)
    scene = yaml.safe_load((tmp_path / "run" / "twin.yaml").read_text())["twin"]
    assert "person" not in scene and len(scene["people"]) == 2
    for walker, walk in zip(scene["people"], sc.walkers, strict=True):
        assert len(walker["waypoints"]) == len(walk.walk) + 1
    cfg = TwinConfig.from_dict(scene)
    assert len(cfg.walkers) == 2 and cfg.robot.start_cell == sc.robot_cell


@pytest.mark.slow
def test_twin_crossing_keeps_both_people_in_their_slots():
    """scenarios/people/crossing.yaml: HOG, NMS, tracker and slots on rendered frames."""
    from stack.perception.camera import CameraConfig, CameraPeopleTracker
    from stack.perception.multi import PeoplePerception
    from twin.calibration import calibrate_twin
    from twin.scene import layout_of

    sc = load_scenario(REPO / "scenarios" / "people" / "crossing.yaml")
    grid = CellGrid()
    scene: dict = {"robot": {"start_cell": sc.robot_cell}}
    door = layout_of(TwinConfig.from_dict(scene)).door_center_m
    scene.update(scene_people(scene, sc, grid, door))
    with Twin(TwinConfig.from_dict(scene), seed=sc.seed) as tw:
        cal = calibrate_twin(tw)
        cam = CameraPeopleTracker(CameraConfig(max_people=2), grid, cal.homography)
        people = PeoplePerception(grid)
        tw.run(8.0)  # both are in the room, walking to the ends of column 1
        slot_of: dict[int, int] = {}
        switches = judged = 0
        while tw.time_s < 15.0:  # they pass through each other at 12.1 s
            tw.run(0.2)
            truth = [(p.pose.x_m, p.pose.y_m) for p in tw.ground_truth().people]
            frame = np.ascontiguousarray(tw.render_camera()[:, :, ::-1])
            state = cam.process_frame(frame, tw.time_s)
            for p in people.update(tw.time_s, state.people_m):
                if p.position_m is None or math.dist(*truth) < 0.5:
                    continue
                d = [math.dist(p.position_m, t) for t in truth]
                i = int(np.argmin(d))
                if d[i] > 0.5:
                    continue
                judged += 1
                if slot_of.setdefault(p.slot, i) != i:
                    switches += 1
                    slot_of[p.slot] = i
    assert switches == 0
    assert sorted(slot_of.values()) == [0, 1] and judged > 30


def test_the_truth_record_lists_every_walker_and_keeps_one_person_records_unchanged():
    from twin.twin import Twin, truth_record

    two = truth_record(Twin(two_walkers(), seed=0).ground_truth())
    assert len(two["people"]) == 2 and two["person"] == two["people"][0]["position"]
    one = truth_record(Twin(TwinConfig(), seed=0).ground_truth())
    assert "people" not in one  # the one-person trace keeps its layout
    assert set(one) == {"t", "robot", "robot_cell", "person", "person_cell", "person_velocity"}
