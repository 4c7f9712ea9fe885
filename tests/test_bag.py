"""The run's rosbag2 bag: the pure writer (fast) and a short twin run's bag (slow, ROS)."""

from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader

from vigil.bag import BagError, BagWriter, RateLimit, fresh_path, typestore

STORE = typestore()


def _tf(parent: str, child: str, sec: int):
    T = STORE.types
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=0), frame_id=parent
    )
    vec = T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=0.0)
    rot = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    tr = T["geometry_msgs/msg/Transform"](translation=vec, rotation=rot)
    ts = T["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=tr)
    return T["tf2_msgs/msg/TFMessage"](transforms=[ts])


def test_bag_round_trips_cdr_messages_with_their_schemas(tmp_path):
    bag = BagWriter(tmp_path / "bag", STORE)
    bag.add_topic("/tf", "tf2_msgs/msg/TFMessage")
    bag.add_topic("/observations", "std_msgs/msg/String")
    for sec in (1, 2, 3):
        cdr = STORE.serialize_cdr(_tf("odom", "base_link", sec), "tf2_msgs/msg/TFMessage")
        bag.write("/tf", sec * 10**9, cdr)
    text = STORE.types["std_msgs/msg/String"](data='{"robot": 3}')
    bag.write("/observations", 2 * 10**9, STORE.serialize_cdr(text, "std_msgs/msg/String"))
    bag.close()
    bag.close()  # twice: harmless
    assert (tmp_path / "bag" / "metadata.yaml").exists()
    with Reader(tmp_path / "bag") as reader:
        assert reader.message_count == 4
        got = [
            (c.topic, t, STORE.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()
        ]
        defs = {c.topic: c.msgdef.data for c in reader.connections}
    tfs = [m for topic, _, m in got if topic == "/tf"]
    assert [m.transforms[0].header.stamp.sec for m in tfs] == [1, 2, 3]
    assert tfs[0].transforms[0].child_frame_id == "base_link"
    assert [m.data for topic, _, m in got if topic == "/observations"] == ['{"robot": 3}']
    assert "TransformStamped" in defs["/tf"]  # the schema travels with the bag


def test_project_interfaces_are_registered():
    for name in ("Belief", "BeliefVariable", "PersonObservation", "Decision", "Warning"):
        assert f"vigil_interfaces/msg/{name}" in STORE.fielddefs


def test_an_existing_bag_is_never_overwritten(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="already exists"):
        BagWriter(tmp_path / "bag", STORE)
    assert (tmp_path / "bag" / "keep.txt").read_text() == "mine"
    assert fresh_path(tmp_path) == tmp_path / "bag_1"


def test_unknown_type_and_undeclared_topic_are_named(tmp_path):
    bag = BagWriter(tmp_path / "bag", STORE)
    with pytest.raises(BagError, match="nope/msg/Nothing"):
        bag.add_topic("/x", "nope/msg/Nothing")
    with pytest.raises(BagError, match="/y"):
        bag.write("/y", 0, b"")
    bag.close()


def test_rate_limit_keeps_one_message_per_period():
    limit = RateLimit(10**9)
    times = [0, 2 * 10**8, 10**9, 15 * 10**8, 21 * 10**8, 25 * 10**8]
    assert [t for t in times if limit.admit(t)] == [0, 10**9, 21 * 10**8]
    every = RateLimit(0)
    assert all(every.admit(t) for t in (5, 5, 6))
    with pytest.raises(ValueError, match=">= 0"):
        RateLimit(-1)


@pytest.mark.slow
@pytest.mark.ros
def test_a_twin_run_writes_a_readable_bag(tmp_path):
    import yaml

    from vigil.run import run_scenario

    repo = Path(__file__).resolve().parents[1]
    scenario = yaml.safe_load((repo / "scenarios" / "5.1.2.yaml").read_text())
    scenario.update(name="bag", task=str(repo / "config" / "task-r1.yaml"), steps=3)
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(scenario))
    run_scenario(path, out=tmp_path / "run", say=lambda s: None)
    bag = tmp_path / "run" / "bag"
    assert (bag / "metadata.yaml").exists(), "the bag was not closed cleanly"
    frames: set[tuple[str, str]] = set()
    counts: dict[str, int] = {}
    decisions = []
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, _, raw in reader.messages():
            if conn.topic == "/planner/step":
                decisions.append(STORE.deserialize_cdr(raw, conn.msgtype))
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == "/tf":
                msg = STORE.deserialize_cdr(raw, conn.msgtype)
                frames |= {(t.header.frame_id, t.child_frame_id) for t in msg.transforms}
    assert ("odom", "base_link") in frames
    assert counts.get("/scan", 0) > 0 and counts.get("/observations", 0) > 0, counts
    # camera frames at one per simulated second at most, not the camera's full rate
    assert 0 < counts.get("/camera/image_raw", 0) < counts["/scan"], counts
    # issue 14: typed messages for observations, belief, decisions and navigation; no
    # std_msgs/String at all (docs/INTERFACES.md allows two, each with a reason)
    expect = {
        "/observations": "vigil_interfaces/msg/PersonObservation",
        "/perception/person": "vigil_interfaces/msg/CameraPerson",
        "/perception/legs": "vigil_interfaces/msg/LegTracks",
        "/planner/belief": "vigil_interfaces/msg/Belief",
        "/planner/step": "vigil_interfaces/msg/Decision",
        "/nav/action": "vigil_interfaces/msg/NavGoal",
        "/nav/result": "vigil_interfaces/msg/NavResult",
        "/twin/truth": "vigil_interfaces/msg/TwinTruth",
    }
    assert {t: types.get(t) for t in expect} == expect
    assert [t for t, ty in types.items() if ty == "std_msgs/msg/String"] == []
    # each decision says which goal its action went out as: the step's number
    assert decisions and [d.goal_id for d in decisions] == [d.step for d in decisions]


def test_a_discarded_bag_removes_only_the_folder_it_made(tmp_path):
    store = STORE
    own = BagWriter(tmp_path / "own", store, reserve_bytes=4096)
    own.add_topic("/x", "std_msgs/msg/Empty")
    own.discard()
    assert not (tmp_path / "own").exists() and not list(tmp_path.glob(".own*"))
    swapped = BagWriter(tmp_path / "bag", store)
    (tmp_path / "bag").rename(tmp_path / "moved")
    (tmp_path / "bag").mkdir()  # another folder under the bag's name: not the writer's
    (tmp_path / "bag" / "keep.txt").write_text("the user's")
    swapped.discard()
    assert (tmp_path / "bag" / "keep.txt").read_text() == "the user's"
