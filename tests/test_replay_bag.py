"""``vigil replay-bag``: reading a run's bag by lock-step tick, comparing step tables, and
(slow, ROS) re-playing a recorded twin run into its planner."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from rosbags.rosbag2 import Reader

import stack.topics as topic
from vigil.bag import BagWriter, typestore
from vigil.cli import main
from vigil.replay_bag import (
    ReplayError,
    compare_steps,
    comparison_markdown,
    find_bag,
    read_recording,
    read_steps,
    replay_params,
    restart_note,
)

REPO = Path(__file__).resolve().parents[1]
STORE = typestore()
CLOCK = "rosgraph_msgs/msg/Clock"
STRING = "std_msgs/msg/String"


def _clock(t_ns: int) -> bytes:
    Time = STORE.types["builtin_interfaces/msg/Time"]
    msg = STORE.types[CLOCK](clock=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9))
    return bytes(STORE.serialize_cdr(msg, CLOCK))


def _string(text: str) -> bytes:
    return bytes(STORE.serialize_cdr(STORE.types[STRING](data=text), STRING))


def _bag(path: Path, entries: list[tuple[str, int, bytes]]) -> Path:
    w = BagWriter(path, STORE)
    w.add_topic(topic.LOCKSTEP_TICK, CLOCK)
    w.add_topic(topic.PERSON, STRING)
    for name, t_ns, cdr in entries:
        w.write(name, t_ns, cdr)
    w.close()
    return path


def test_the_recording_is_split_by_lock_step_tick(tmp_path):
    bag = _bag(
        tmp_path / "bag",
        [
            (topic.PERSON, 0, _string("before")),
            (topic.LOCKSTEP_TICK, 1, _clock(0)),
            (topic.PERSON, 2, _string("a")),
            (topic.PERSON, 3, _string("b")),
            (topic.LOCKSTEP_TICK, 1_500_000_000, _clock(1_500_000_000)),
            (topic.PERSON, 1_500_000_001, _string("c")),
        ],
    )
    rec = read_recording(bag)
    assert [t.t_ns for t in rec.ticks] == [0, 1_500_000_000]
    texts = [[STORE.deserialize_cdr(cdr, STRING).data for _, cdr in t.messages] for t in rec.ticks]
    assert texts == [["a", "b"], ["c"]]
    assert [STORE.deserialize_cdr(c, STRING).data for _, c in rec.before] == ["before"]
    assert rec.types[topic.PERSON] == STRING and rec.count(topic.PERSON) == 4


def test_a_bag_without_ticks_or_a_run_without_a_bag_is_refused(tmp_path):
    with pytest.raises(ReplayError, match="no such run folder"):
        find_bag(tmp_path / "nowhere")
    (tmp_path / "run").mkdir()
    with pytest.raises(ReplayError, match="has no bag"):
        find_bag(tmp_path / "run")
    bag = _bag(tmp_path / "run" / "bag", [(topic.PERSON, 5, _string("x"))])
    assert find_bag(tmp_path / "run") == bag
    with pytest.raises(ReplayError, match="without lock-step"):
        read_recording(bag)
    (bag / "metadata.yaml").unlink()
    with pytest.raises(ReplayError, match="not closed"):
        find_bag(tmp_path / "run")


def test_a_corrupt_bag_is_named(tmp_path, capsys):
    bag = _bag(tmp_path / "run" / "bag", [(topic.LOCKSTEP_TICK, 1, _clock(0))])
    (mcap,) = bag.glob("*.mcap")
    mcap.write_bytes(mcap.read_bytes()[:40])  # truncated
    with pytest.raises(ReplayError, match="cannot be read"):
        read_recording(bag)
    steps = tmp_path / "run" / "steps.jsonl"  # a run with steps: the bag is what fails
    steps.write_text(json.dumps(_step(1, "Do nothing", "No person", 1.0)) + "\n")
    assert main(["replay-bag", str(tmp_path / "run")]) == 2
    assert "cannot be read" in capsys.readouterr().err
    assert not (tmp_path / "run" / "replay").exists()  # nothing written for a bad run


def test_a_step_record_cut_off_mid_write_is_dropped_and_a_bad_one_before_it_named(tmp_path):
    good = json.dumps(_step(1, "Do nothing", "No person", 1.0))
    path = tmp_path / "steps.jsonl"
    path.write_text(good + "\n" + good[:20] + "\n")
    assert len(read_steps(path)) == 1
    path.write_text(good[:20] + "\n" + good + "\n")
    with pytest.raises(ReplayError, match="line 1: not JSON"):
        read_steps(path)


def _step(n: int, action: str, person: str, t: float) -> dict:
    obs = {"robot": "7", "person": person, "velocity": "Not moving"}
    return {"step": n, "stamp_s": t, "action": action, "observation": obs, "belief": {"p": 0.5}}


def test_step_tables_are_compared_step_by_step():
    run = [_step(1, "South", "No person", 3.8), _step(2, "Do nothing", "9", 6.3)]
    same = compare_steps(run, [dict(r) for r in run])
    assert same.matches and "all 2 steps match" in comparison_markdown(same)
    other = [run[0], _step(2, "Do nothing", "No person", 6.3)]
    diff = compare_steps(run, other)
    assert not diff.matches and diff.rows[1][3] == "observation"
    assert "**mismatch** (observation)" in comparison_markdown(diff)
    short = compare_steps(run, run[:1])
    assert not short.matches and short.rows[1][3] == "not replayed"
    later = compare_steps(run, [run[0], {**run[1], "stamp_s": 6.35}])
    assert later.rows[1][3] == "time"


def test_a_restarted_planner_is_noted():
    run = [_step(1, "South", "No person", 3.8), _step(2, "Do nothing", "9", 6.3)]
    assert restart_note(run) == ""
    run[1]["resumed"] = True
    assert "resumed at step 2" in restart_note(run)


def test_replay_params_follow_a_moved_run_folder(tmp_path):
    old = "/somewhere/else/run"
    doc = {
        "observations": {"ros__parameters": {"config_file": f"{old}/stack.yaml", "lockstep": 1}},
        "planner": {
            "ros__parameters": {
                "task_file": "/repo/config/task-r1.yaml",
                "steps_file": f"{old}/steps.jsonl",
                "state_file": f"{old}/planner_state.json",
            }
        },
    }
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(ReplayError, match="no params.yaml"):
        replay_params(run, tmp_path / "out")
    (run / "params.yaml").write_text(yaml.safe_dump(doc))
    p = replay_params(run, tmp_path / "out")
    assert p["observations"]["config_file"] == f"{run.resolve()}/stack.yaml"
    assert p["planner"]["task_file"] == "/repo/config/task-r1.yaml"
    assert p["planner"]["steps_file"] == str(tmp_path / "out" / "steps.jsonl")
    assert p["observations"]["lockstep"] is True and p["planner"]["lockstep"] is True
    (run / "params.yaml").write_text(yaml.safe_dump({"planner": doc["planner"]}))
    with pytest.raises(ReplayError, match="observations"):
        replay_params(run, tmp_path / "out")


@pytest.mark.ros
def test_the_player_refuses_a_recorded_type_the_nodes_do_not_read(ros):
    import rclpy
    from rostest import spin_until
    from std_msgs.msg import Int32

    from vigil.node_bag_player import BagPlayer

    name = "/replay_bag_test/person"  # a topic of this test's own
    reader = rclpy.create_node("replayed_reader")  # stands in for a replayed node
    reader.create_subscription(Int32, name, lambda _m: None, 10)
    player = BagPlayer("test-run", ("replayed_reader",))
    ros.add_node(reader)
    ros.add_node(player)
    assert spin_until(ros, lambda: player.get_subscriptions_info_by_topic(name), 10.0)
    with pytest.raises(ReplayError, match="std_msgs/msg/String but node replayed_reader reads"):
        player.add_input(name, STRING)
    player.add_input(name, "std_msgs/msg/Int32")  # the type the node reads: a publisher
    assert spin_until(ros, lambda: player.own_matched().get(name) == 1, 10.0)
    player.destroy_node()
    reader.destroy_node()


# -- the whole replay ---------------------------------------------------------------------
SHORT = {
    "name": "replay",
    "title": "a person walks from cell 10 to the restricted cell 1",
    "task": str(REPO / "config" / "task-r1.yaml"),
    "seed": 3,
    "steps": 4,
    "robot_cell": 7,
    "belief": {"person": 10, "direction": "not moving"},
    "person": {
        "start": 10,
        "walk": [
            {"to": 10, "speed_mps": 0.8, "pause_s": 1.0},
            {"to": 5, "speed_mps": 0.8},
            {"to": 1, "speed_mps": 0.8, "pause_s": 30.0},
        ],
    },
}


def _tamper(src: Path, dst: Path, drop: str, after_ns: int) -> int:
    """A copy of the bag without ``drop``'s messages after ``after_ns``; how many went."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    dropped = 0
    with Reader(src) as reader, Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {
            c.id: w.add_connection(c.topic, c.msgtype, typestore=STORE) for c in reader.connections
        }
        for conn, t_ns, raw in reader.messages():
            if conn.topic == drop and t_ns > after_ns:
                dropped += 1
                continue
            w.write(conns[conn.id], t_ns, raw)
    return dropped


@pytest.mark.slow
@pytest.mark.ros
def test_replay_bag_reproduces_the_step_table_and_a_tampered_bag_does_not(tmp_path, capsys):
    from vigil.run import run_scenario

    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(SHORT))
    run = tmp_path / "run"
    run_scenario(path, out=run, say=lambda s: None)
    steps = [json.loads(line) for line in (run / "steps.jsonl").read_text().splitlines()]
    assert len(steps) == SHORT["steps"]
    # the person is seen in some step: the replay has something to reproduce
    assert any(s["observation"]["person"] != "No person" for s in steps), steps

    assert main(["replay-bag", str(run), "--out", str(tmp_path / "replay")]) == 0
    out = capsys.readouterr().out
    assert out.count("| match |") == SHORT["steps"], out
    replayed = [json.loads(line) for line in (tmp_path / "replay" / "steps.jsonl").open()]
    assert [s["action"] for s in replayed] == [s["action"] for s in steps]
    assert [s["observation"] for s in replayed] == [s["observation"] for s in steps]

    # the camera's person messages dropped after the first step: the person is not seen
    tampered = tmp_path / "tampered"  # a copy of the run folder: its paths follow it
    shutil.copytree(run, tampered, ignore=shutil.ignore_patterns("bag", "replay*", "*.mp4"))
    after_ns = int(steps[0]["stamp_s"] * 1e9)
    assert _tamper(run / "bag", tampered / "bag", topic.PERSON, after_ns) > 0
    assert main(["replay-bag", str(tampered), "--out", str(tmp_path / "replay-t")]) == 1
    out = capsys.readouterr().out
    assert "**mismatch**" in out and "| 1 |" in out
    assert "| 1 | " in out and out.split("| 1 |")[1].split("\n")[0].rstrip().endswith("match |")
