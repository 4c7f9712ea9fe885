"""The codec between domain records and typed messages (stack/ros_msgs.py, issue 14):
each writer's record comes back from its reader, absent values survive, and malformed
messages raise ValueError naming the field. Message classes only: no ROS graph."""

from __future__ import annotations

import math

import pytest

pytest.importorskip("vigil_interfaces.msg")

from stack import ros_msgs as rm  # noqa: E402
from stack.lockstep import Ack  # noqa: E402
from stack.perception.messages import camera_state_from_dict, tracks_from_dict  # noqa: E402
from stack.planning.agent import Observed  # noqa: E402

OBS = {
    "stamp_s": 12.5,
    "robot": "7",
    "person": "5",
    "velocity": "East 0.2-0.7",
    "person_position_m": [2.25, 1.5],
    "speed_mps": 0.4,
    "source": "camera",
    "hidden": {"3": 0.123, "8": 1.0},
    "frame_stamp_s": 12.4,
}


def test_observation_round_trip_and_the_planner_reads_it():
    back = rm.observation_from_msg(rm.observation_to_msg(OBS))
    assert back == OBS
    assert Observed.from_dict(back) == Observed.from_dict(OBS)
    none = {**OBS, "person": "No person", "person_position_m": None, "speed_mps": None}
    none["hidden"], none["frame_stamp_s"] = {}, None  # no camera frame
    assert rm.observation_from_msg(rm.observation_to_msg(none)) == none


def test_the_frame_stamp_reaches_the_step_record():
    """The camera frame's stamp crosses the wire into the planner's record (the run's
    camera-to-decision latency, vigil.report.latency)."""
    obs = Observed.from_dict(rm.observation_from_msg(rm.observation_to_msg(OBS)))
    assert obs.frame_stamp_s == pytest.approx(12.4)
    assert obs.to_dict()["frame_stamp_s"] == pytest.approx(12.4)
    assert "frame_stamp_s" not in Observed.from_dict({**OBS, "frame_stamp_s": None}).to_dict()
    assert Observed.from_dict({**OBS, "frame_stamp_s": "x"}).frame_stamp_s is None


def test_observation_people_slots_round_trip():
    people = [{"person": "5", "velocity": "Not moving"}, {"person": "Unseen", "velocity": "x"}]
    back = rm.observation_from_msg(rm.observation_to_msg({**OBS, "people": people}))
    assert back["people"] == people


def test_observation_people_positions_round_trip_and_reach_the_planner():
    people = [
        {"person": "5", "velocity": "Not moving", "position_m": [3.5, 0.75]},
        {"person": "No person", "velocity": "Not moving", "position_m": None},
    ]
    back = rm.observation_from_msg(rm.observation_to_msg({**OBS, "people": people}))
    assert back["people"] == people
    assert Observed.from_dict(back).people_positions_m == ((3.5, 0.75), None)
    msg = rm.observation_to_msg({**OBS, "people": people})
    msg.people_has_position = [True]  # one flag for two slots
    with pytest.raises(ValueError, match="position flags"):
        rm.observation_from_msg(msg)


def test_malformed_observation_names_the_field():
    msg = rm.observation_to_msg(OBS)
    msg.hidden_fractions = [0.5]
    with pytest.raises(ValueError, match="hidden"):
        rm.observation_from_msg(msg)
    msg = rm.observation_to_msg(OBS)
    msg.person_position.x = math.nan
    with pytest.raises(ValueError, match="person_position"):
        rm.observation_from_msg(msg)


def test_camera_round_trip_feeds_the_camera_state():
    d = {
        "stamp_s": 3.1,
        "status": "person",
        "position_m": [2.0, 1.0],
        "cell": 5,
        "direction": "East",
        "foot_px": [320.5, 200.0],
        "boxes": [[10, 12, 40, 80, 1.234]],
        "missed_frames": 1,
        "warning": None,
        "people_m": [[2.0, 1.0], [4.0, 0.5]],
    }
    back = rm.camera_from_msg(rm.camera_to_msg(d))
    assert back == d
    state = camera_state_from_dict(back, now_s=9.0)
    assert state.cell == 5 and state.people_m == ((2.0, 1.0), (4.0, 0.5))
    silent = {**d, "status": "unknown", "position_m": None, "cell": None, "foot_px": None}
    assert rm.camera_from_msg(rm.camera_to_msg(silent))["cell"] is None
    msg = rm.camera_to_msg(d)
    msg.boxes = [1.0, 2.0]
    with pytest.raises(ValueError, match="fives"):
        rm.camera_from_msg(msg)
    msg.boxes, msg.cell = [], -7
    with pytest.raises(ValueError, match="cell"):
        rm.camera_from_msg(msg)


def test_legs_round_trip_feeds_the_tracks():
    d = {
        "stamp_s": 10.0,
        "valid_beams": 300,
        "segments": 4,
        "on_obstacles": 1,
        "legs": [[2.0, 1.0], [2.1, 1.0]],
        "people": [[2.05, 1.0]],
        "tracks": [
            {"id": 1, "position_m": [2.05, 1.0], "velocity_mps": [0.5, 0.0], "speed_mps": 0.5,
             "speed_class": "0.2-0.7", "hits": 5, "age_s": 0.1, "confirmed": True},
        ],
    }  # fmt: skip
    back = rm.legs_from_msg(rm.legs_to_msg(d))
    assert back == d
    (track,) = tracks_from_dict(back, now_s=20.0)
    assert track.track_id == 1 and track.last_update_s == pytest.approx(19.9)
    msg = rm.legs_to_msg(d)
    msg.tracks[0].speed_mps = math.inf
    with pytest.raises(ValueError, match="speed"):
        rm.legs_from_msg(msg)


def test_navigation_goal_result_and_progress():
    assert rm.nav_goal_from_msg(rm.nav_goal_to_msg(4, "East", 1.0)) == (4, "East")
    with pytest.raises(ValueError, match="goal id"):
        rm.nav_goal_from_msg(rm.nav_goal_to_msg(0, "East", 1.0))
    result = {"goal_id": 4, "result": "succeeded", "error_code": 0, "error_name": "NONE",
              "message": "in the target cell", "action": "East", "from_cell": 7,
              "target_cell": 6, "cell": None}  # fmt: skip
    assert rm.nav_result_from_msg(rm.nav_result_to_msg(result)) == result
    progress = {"goal_id": 4, "state": "following", "distance_remaining_m": None,
                "replans": 2, "message": "", "cell": 7}  # fmt: skip
    assert rm.nav_progress_from_msg(rm.nav_progress_to_msg(progress)) == progress


def test_belief_and_decision_round_trip():
    belief = {"robot": {"7": 1.0}, "person": {"5": 0.75, "No person": 0.25}}
    assert rm.belief_from_msg(rm.belief_to_msg(belief, 3, 1.0)) == belief
    msg = rm.belief_to_msg(belief, 3, 1.0)
    msg.variables[1].probabilities = [0.5, math.nan]
    with pytest.raises(ValueError, match="person"):
        rm.belief_from_msg(msg)
    record = {
        "step": 3, "action": "East", "belief": belief, "values": [1.5, 2.0], "note": None,
        "observation": {"robot": "7", "person": "5", "velocity": "Not moving",
                        "hidden": {"3": 0.5}},
        "stamp_s": 14.25, "trigger": "step", "resumed": False, "goal_id": 3,
        "nav": {"goal_id": 3, "result": "succeeded", "error_code": 0, "error_name": "NONE",
                "message": "", "action": "East", "from_cell": 7, "target_cell": 6, "cell": 6},
    }  # fmt: skip
    assert rm.decision_from_msg(rm.decision_to_msg(record)) == record
    timeout = {**record, "nav": {"result": "timeout"}, "observation": None, "depth": 2}
    back = rm.decision_from_msg(rm.decision_to_msg(timeout))
    assert back["nav"]["result"] == "timeout" and back["nav"]["goal_id"] == 0
    assert back["observation"] is None and back["depth"] == 2


def test_speech_truth_and_ack():
    done = {"request_id": -2, "kind": "failed", "text": "hi", "voice": None, "wav": None,
            "duration_s": None, "error": "no espeak"}  # fmt: skip
    assert rm.speech_done_from_msg(rm.speech_done_to_msg(done, 1.0)) == done
    w = rm.warning_to_msg("Please leave", 1, None, 2.0)
    assert w.person_cell == -1 and w.text == "Please leave"
    truth = {"t": 1.25, "robot": [1.0, 2.0, 0.5], "robot_cell": 7, "person": [2.0, 1.0],
             "person_cell": None, "person_velocity": [0.5, 0.0],
             "people": [{"position": [2.0, 1.0], "cell": None, "velocity": [0.5, 0.0]},
                        {"position": [3.0, 1.0], "cell": 4, "velocity": [0.0, 0.0]}]}  # fmt: skip
    assert rm.truth_from_msg(rm.truth_to_msg(truth)) == truth
    nobody = {k: v for k, v in truth.items() if k != "people"}
    nobody.update(person=None, person_cell=None, person_velocity=None)
    assert rm.truth_from_msg(rm.truth_to_msg(nobody)) == nobody
    ack = Ack("planner", "1-ab", {"/a": 2}, {"/b": 1}, {"/b": 3}, run="r1")
    msg = rm.ack_to_msg(ack.node, ack.incarnation, ack.run, ack.recv, ack.sent, ack.matched)
    assert Ack.from_dict(rm.ack_from_msg(msg)) == ack
    msg.recv_counts = []
    with pytest.raises(ValueError, match="recv"):
        rm.ack_from_msg(msg)


def test_stamps_round_to_the_nanosecond():
    t = rm.stamp(2.9999999999)
    assert (t.sec, t.nanosec) == (3, 0)
    assert rm.stamp_s(rm.stamp(12.345678)) == pytest.approx(12.345678, abs=1e-9)
    assert rm.stamp(math.nan).sec == 0


def test_diagnostics_carry_level_message_and_values():
    from builtin_interfaces.msg import Time

    values = {"armed": True, "reason": "not armed", "max_linear_mps": 0.3, "frames": 12}
    msg = rm.diagnostics_to_msg("velocity_gate", "", "warn", "not armed", values, Time(sec=3))
    (status,) = msg.status
    assert status.name == "velocity_gate" and msg.header.stamp.sec == 3
    back = rm.diagnostics_from_msg(msg)["velocity_gate"]
    assert back == {"level": 1, "message": "not armed", **values}
    with pytest.raises(KeyError):
        rm.diagnostics_to_msg("x", "", "fine", "", {}, Time())


def test_a_diagnostic_value_nested_too_deep_is_read_back_as_text():
    from builtin_interfaces.msg import Time

    deep = "[" * 100_000 + "]" * 100_000  # json.loads raises RecursionError on it
    msg = rm.diagnostics_to_msg("peer", "", "ok", "", {"x": "text"}, Time())
    msg.status[0].values[0].value = deep
    assert rm.diagnostics_from_msg(msg)["peer"]["x"] == deep
