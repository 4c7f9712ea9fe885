"""The run report of a scenario (vigil.report) on small synthetic run folders."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from stack.cells import CellGrid
from stack.planning.model import build_model
from stack.planning.replay import TABLES
from stack.planning.task import load_task
from stack.vocabulary import ACTIONS, VELOCITIES
from vigil.report import RunRecordError, read_jsonl, true_velocity_label, write_report
from vigil.report.video import VideoComposer, video_codec

ROOT = Path(__file__).resolve().parents[1]
TASK = ROOT / "config" / "task-r1.yaml"
GRID = CellGrid()  # the thesis grid: 1 m x 1.5 m cells, south row 11 9 7 5 3 1 at y 0..1.5


def person_at(t: float) -> tuple[list[float] | None, list[float] | None]:
    """Walks east from cell 9 into cell 1 (arrives t=7), rests there, walks west from
    t=14 (leaves cell 1 at 14.5) and out of the region (gone from t=20)."""
    if t < 8:
        return [1.5 + 0.5 * t, 0.75], [0.5, 0.0]
    if t < 14:
        return [5.5, 0.75], [0.0, 0.0]
    if t < 20:
        return [5.5 - (t - 14), 0.75], [-1.0, 0.0]
    return None, None


def robot_at(t: float, leave_map: bool = False) -> list[float]:
    """At rest cell 7 until t=9, east to cell 1 (arrives t=12), back west from t=17 to 7
    (there at t=20). With ``leave_map`` it overshoots east out of the map at t=13."""
    if t <= 9:
        x = 2.5
    elif t <= 12:
        x = 2.5 + (t - 9)
    elif t <= 17:
        x = 6.5 if leave_map and 13 <= t <= 14 else 5.5
    elif t <= 20:
        x = 5.5 - (t - 17)
    else:
        x = 2.5
    return [x, 0.75, 0.0]


def make_trace(hardware: bool = False, leave_map: bool = False) -> list[dict]:
    out = []
    for k in range(0, 31):
        t = float(k)
        p, v = person_at(t)
        r = robot_at(t, leave_map)
        cam = {
            "status": "person" if p else "no person",
            "position_m": p,
            "cell": GRID.cell_at(*p) if p else None,
            "direction": "East",
            "boxes": [[100, 50, 60, 120, 1.2]] if p else [],
            "foot_px": [130, 170] if p else None,
        }
        out.append(
            {
                "t": t,
                "robot": None if hardware else r,
                "robot_cell": None if hardware else GRID.cell_at(r[0], r[1]),
                "person": None if hardware else p,
                "person_cell": None if hardware or p is None else GRID.cell_at(*p),
                "person_velocity": None if hardware else v,
                "odom": r,
                "camera": cam if k % 5 else None,
                "legs": [p] if p else [],
                "speech": "Please leave this area" if k == 12 else None,
            }
        )
    return out


# (stamp, action, observed robot, person, velocity) - step 12 has no observation
STEPS = [
    (2.0, "Do nothing", "7", "7", "East 0.2-0.7"),
    (5.0, "Do nothing", "7", "5", "East higher"),
    (8.0, "Do nothing", "7", "1", "Not moving"),
    (10.0, "East", "5", "1", "Not moving"),
    (11.0, "East", "3", "1", "Not moving"),
    (12.0, "East", "1", "1", "Not moving"),
    (14.0, "Do nothing", "1", "1", "Not moving"),
    (16.0, "Do nothing", "1", "5", "West higher"),
    (18.0, "West", "3", "9", "West higher"),
    (19.0, "West", "5", "11", "West higher"),
    (20.5, "West", "7", "No person", "Not moving"),
    (22.0, "Do nothing", None, None, None),
]
# the truth at each stamp (robot, person, velocity), worked out from robot_at / person_at
TRUTH = [
    ("7", "7", "East 0.2-0.7"),
    ("7", "3", "East 0.2-0.7"),
    ("7", "1", "Not moving"),
    ("5", "1", "Not moving"),
    ("3", "1", "Not moving"),
    ("1", "1", "Not moving"),
    ("1", "1", "West higher"),
    ("1", "5", "West higher"),
    ("3", "9", "West higher"),
    ("5", "11", "West higher"),
    ("7", "No person", "Not moving"),
    ("7", "No person", "Not moving"),
]
# table 4.1 by hand: rest cell 0, other -3, cell 1 guarded +30 / idle -10, move -0.2
HAND_REWARDS = [0, 0, 0, -3.2, -3.2, 29.8, 30, -10, -3.2, -3.2, -0.2, 0]


def belief_person(cell: str | None) -> dict:
    b = {str(c): 0.0 for c in range(1, 13)} | {"No person": 0.0}
    b[cell or "No person"] = 0.8
    b["9"] += 0.2
    return b


def make_steps(out_of_map_step: int | None = None) -> list[dict]:
    recs = []
    for n, (stamp, action, robot, person, vel) in enumerate(STEPS, start=1):
        if n == out_of_map_step:
            robot = "Out of the map"
        rec = {
            "step": n,
            "stamp_s": stamp,
            "action": action,
            "observation": None
            if robot is None
            else {"robot": robot, "person": person, "velocity": vel},
            "belief": None if robot is None else {"person": belief_person(person)},
            "values": [1.0, 2.0, 3.0, 4.0, 5.0],
            "nav": None if action == "Do nothing" else {"result": "succeeded", "cell": 1},
            "resumed": False,
        }
        if robot is None:
            rec["error"] = "observation timeout"
        recs.append(rec)
    return recs


def write_run(
    run: Path, steps: list[dict] | None = None, trace: list[dict] | None = None, wav: bool = True
) -> Path:
    run.mkdir(parents=True, exist_ok=True)
    steps = make_steps() if steps is None else steps
    trace = make_trace() if trace is None else trace
    (run / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    (run / "trace.jsonl").write_text("".join(json.dumps(r) + "\n" for r in trace))
    if wav:
        (run / "speech").mkdir(exist_ok=True)
        (run / "speech" / "0001.wav").write_bytes(b"RIFF")
    return run


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> tuple[Path, dict]:
    run = write_run(tmp_path_factory.mktemp("run") / "r1-sim")
    return run, write_report(run, TASK)


def test_true_velocity_label():
    assert true_velocity_label(None) == "Not moving"
    assert true_velocity_label([0.0, 0.0]) == "Not moving"
    assert true_velocity_label([0.03, -0.02]) == "Not moving"
    assert true_velocity_label([0.1, 0.0]) == "East 0-0.2"
    assert true_velocity_label([-0.5, 0.1]) == "West 0.2-0.7"
    assert true_velocity_label([0.3, -0.9]) == "South higher"
    assert true_velocity_label([0.0, 0.7]) == "North higher"
    assert true_velocity_label([0.0, 0.19]) == "North 0-0.2"
    for v in ([0.1, 0.0], [-2.0, 0.0], [0.0, 0.3], [0.0, -0.05]):
        assert true_velocity_label(v) in VELOCITIES


def test_step_table_rows_and_truth(report):
    run, summary = report
    with open(run / "steps.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["step"]) for r in rows] == list(range(1, 13))
    for r, (_stamp, action, robot, person, vel), truth in zip(rows, STEPS, TRUTH, strict=True):
        assert r["action"] == action
        assert (r["obs_robot"], r["obs_person"], r["obs_velocity"]) == (
            (robot, person, vel) if robot else ("-", "-", "-")
        )
        assert (r["true_robot"], r["true_person"], r["true_velocity"]) == truth
        assert r["reward_basis"] == "true"
    assert rows[-1]["error"] == "observation timeout"
    md = (run / "steps.md").read_text()
    assert "| 2 | 5.00 | Do nothing | 7 | 5 | East higher | 7 | 3 | East 0.2-0.7 |" in md
    assert "observation timeout" in md
    assert summary["steps"] == 12 and summary["step_errors"] == 1
    assert any("observation timeout" in w for w in summary["warnings"])
    assert summary["observation_agreement"]["person"] == {"same": 10, "compared": 11}
    assert (run / "positions.png").stat().st_size > 0
    assert (run / "belief.png").stat().st_size > 0


def test_reward_matches_hand_computation(report):
    run, summary = report
    task = load_task(TASK)
    R = build_model(task).reward_table()
    # the same from the model's table, indexed by hand: [robot, person, direction, action]
    dir_of = {"Not moving": 4, "East": 2, "West": 3}
    for (_s, action, *_), (rob, per, vel), hand in zip(STEPS, TRUTH, HAND_REWARDS, strict=True):
        p = 12 if per == "No person" else int(per) - 1
        d = dir_of[vel.split()[0] if vel != "Not moving" else vel]
        assert R[int(rob) - 1, p, d, ACTIONS.index(action)] == pytest.approx(hand)
    total = sum(r * task.discount**n for n, r in enumerate(HAND_REWARDS))
    assert summary["total_discounted_reward"] == pytest.approx(total, abs=1e-6)
    assert summary["total_reward"] == pytest.approx(sum(HAND_REWARDS), abs=1e-6)
    assert summary["reward_basis"] == "true"
    with open(run / "steps.csv", newline="") as f:
        last = list(csv.DictReader(f))[-1]
    assert float(last["cumulative_discounted_reward"]) == pytest.approx(total, abs=1e-4)


def test_visit_delay_rest_and_warnings(report):
    _run, s = report
    (visit,) = s["visits"]
    assert visit["cell"] == 1
    assert visit["person_arrival_t"] == 7.0 and visit["person_left_t"] == 15.0
    assert visit["robot_arrival_t"] == 12.0 and visit["delay_s"] == 5.0
    assert s["robot_reached_every_visit"] is True
    assert s["left_map"] is False and s["left_map_first_t"] is None
    assert s["person_last_in_region_t"] == 19.0
    assert s["returned_to_rest"] is True and s["returned_to_rest_t"] == 20.0
    assert s["warning_in_restricted"] is True
    assert s["warnings_spoken"][0]["robot_cell"] == 1
    assert s["wav_files"] == ["speech/0001.wav"]
    assert s["trace"]["records"] == 31
    assert s["trace"]["camera_status"]["missing"] == 7  # every 5th record has no camera
    assert s["nav_results"] == {"succeeded": 6}
    assert s["ground_truth"] is True


def test_robot_already_there_gives_zero_delay_and_late_robot_none(tmp_path):
    trace = make_trace()
    for rec in trace:  # the robot waits in cell 1 from the start, never returns to 7
        rec["robot"] = [5.5, 0.75, 0.0]
        rec["robot_cell"] = 1
    s = write_report(write_run(tmp_path / "early", trace=trace), TASK, plots=False)
    assert s["visits"][0]["robot_arrival_t"] == 7.0 and s["visits"][0]["delay_s"] == 0.0
    assert s["visits"][0]["guarded"] is True
    assert s["returned_to_rest"] is False
    trace = make_trace()
    for rec in trace:  # the robot never moves
        rec["robot"], rec["robot_cell"] = [2.5, 0.75, 0.0], 7
    s = write_report(write_run(tmp_path / "never", trace=trace), TASK, plots=False)
    assert s["visits"][0]["robot_arrival_t"] is None and s["visits"][0]["delay_s"] is None
    assert s["visits"][0]["guarded"] is False and s["robot_reached_every_visit"] is False
    assert s["warning_in_restricted"] is False


def test_left_map_from_trace_and_from_observation(tmp_path):
    s = write_report(write_run(tmp_path / "a", trace=make_trace(leave_map=True)), TASK, plots=False)
    assert s["left_map"] is True and s["left_map_first_t"] == 13.0
    run = write_run(tmp_path / "b", steps=make_steps(out_of_map_step=4))
    s = write_report(run, TASK, plots=False)
    assert s["left_map"] is True and s["left_map_observed_steps"] == [4]
    assert s["left_map_first_t"] is None


def test_hardware_mode_uses_observed_rewards_and_odometry(tmp_path):
    s = write_report(write_run(tmp_path / "hw", trace=make_trace(hardware=True)), TASK, plots=False)
    assert s["ground_truth"] is False and s["events_source"] == "odometry and camera"
    assert s["reward_basis"] == "observed" and s["steps_without_reward"] == 1
    assert s["total_discounted_reward"] == s["total_discounted_reward_observed"]
    assert s["returned_to_rest"] is True
    md = (tmp_path / "hw" / "steps.md").read_text()
    assert "reward from observation" in md


def test_malformed_lines(tmp_path):
    run = write_run(tmp_path / "bad")
    lines = (run / "steps.jsonl").read_text().splitlines(keepends=True)
    (run / "steps.jsonl").write_text("".join(lines[:2]) + "{not json\n" + "".join(lines[2:]))
    with pytest.raises(RunRecordError, match=r"steps\.jsonl:3: not valid JSON"):
        write_report(run, TASK, plots=False)
    (run / "steps.jsonl").write_text("".join(lines[:2]) + '{"step": 3, "action": "East"}\n')
    with pytest.raises(ValueError, match=r"steps\.jsonl:3: missing key\(s\) \['stamp_s'\]"):
        write_report(run, TASK, plots=False)
    bad_label = json.loads(lines[0]) | {"action": "Jump"}
    (run / "steps.jsonl").write_text(json.dumps(bad_label) + "\n")
    with pytest.raises(RunRecordError, match=r"steps\.jsonl:1: unknown action 'Jump'"):
        write_report(run, TASK, plots=False)
    (run / "steps.jsonl").write_text("".join(lines))
    trace = (run / "trace.jsonl").read_text()
    (run / "trace.jsonl").write_text(trace + "[1, 2]\n")
    with pytest.raises(RunRecordError, match=r"trace\.jsonl:32: expected a JSON object"):
        write_report(run, TASK, plots=False)
    # a truncated last line (node killed mid-write) is skipped with a warning
    (run / "trace.jsonl").write_text(trace + '{"t": 31.0, "rob')
    s = write_report(run, TASK, plots=False)
    assert s["trace"]["records"] == 31
    assert any("trace.jsonl:32: skipped a truncated last line" in w for w in s["warnings"])
    warnings: list[str] = []
    assert len(read_jsonl(run / "trace.jsonl", ("t",), warnings)) == 31 and warnings
    with pytest.raises(RunRecordError):
        read_jsonl(run / "trace.jsonl")  # no warnings list: raise


def test_empty_run_reports_warnings(tmp_path):
    run = tmp_path / "empty"
    run.mkdir()
    with pytest.raises(RunRecordError, match="neither steps.jsonl nor trace.jsonl"):
        write_report(run, TASK)
    (run / "steps.jsonl").write_text("")
    s = write_report(run, TASK)
    assert s["steps"] == 0 and s["total_discounted_reward"] == 0.0 and s["visits"] == []
    assert s["warnings"] == ["trace.jsonl is missing: no ground truth or events"]
    assert "No decision steps" in (run / "steps.md").read_text()
    assert (run / "belief.png").exists() and (run / "positions.png").exists()


def test_deterministic_and_thesis_table(tmp_path):
    run = write_run(tmp_path / "det")
    table = TABLES["5.1"]
    s1 = write_report(run, TASK, table)
    first = {n: (run / n).read_bytes() for n in ("steps.md", "steps.csv", "summary.json")}
    s2 = write_report(run, TASK, table)
    assert s1 == s2
    for n, data in first.items():
        assert (run / n).read_bytes() == data, n
    assert json.loads(first["summary.json"]) == s1
    md = first["steps.md"].decode()
    assert "## Thesis table 5.1" in md
    same = sum(a == t.action for (_s, a, *_), t in zip(STEPS, table.steps, strict=True))
    assert s1["thesis"] == {"table": "5.1", "thesis_steps": 12, "same_action": same, "compared": 12}


def test_video_composer_writes_h264(tmp_path):
    import imageio_ffmpeg

    path = tmp_path / "video" / "run.mp4"
    trace = make_trace()
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, (400, 640, 3), dtype=np.uint8)
    n = 20
    with VideoComposer(path, GRID, (1,), room_bounds_m=(-0.5, -0.5, 6.5, 3.5)) as video:
        for k in range(n):
            rec = trace[k]
            video.add(
                rec["t"],
                None if k == 3 else frame,
                rec["camera"],
                rec["legs"],
                rec["robot"],
                rec["person"],
                belief_person(str(rec["person_cell"] or "No person")),
            )
        assert video.frames == n
        small = video.render(0.0, frame[:100, :300], None, [], None, None)
        assert small.shape == (video.height, video.width, 3)
    video.close()  # twice is fine
    assert video_codec(path) == "h264"
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert tuple(meta["size"]) == (960, 360)
    assert sum(1 for _ in reader) == n


EPOCH_S = 1_795_812_190.0  # a real-time run's stamps: the system clock, epoch seconds


def write_run_on_clock(run: Path, origin_s: float) -> Path:
    """The synthetic run with every stamp ``origin_s`` later (0: the simulated clock),
    a speech log and the camera frames of every other trace record."""
    from vigil.frames import FRAMES_FILE, FrameWriter

    steps, trace = make_steps(), make_trace()
    for rec in steps:
        rec["stamp_s"] += origin_s
        if rec["observation"] is not None:
            rec["observation"]["frame_stamp_s"] = rec["stamp_s"] - 0.25
    for rec in trace:
        rec["t"] += origin_s
    write_run(run, steps, trace)
    (run / "speech" / "speech_log.tsv").write_text(
        "time_s\tvoice\tduration_s\twav\tframe_stamp_s\ttext\n"
        f"{origin_s + 12.0:.3f}\ten\t2.000\t0001.wav\t{origin_s + 11.75:.3f}\tPlease leave\n"
    )
    frames = FrameWriter(run / FRAMES_FILE)
    for rec in trace[::2]:
        frames.add(rec["t"], np.full((48, 64, 3), 90, np.uint8))
    frames.close()
    return run


def test_a_wall_clock_run_reports_seconds_since_its_start_as_lock_step_does(tmp_path, monkeypatch):
    """Issue 25: a real-time run's stamps are epoch seconds; its report (summary,
    tables, latency, the video's overlay) reads as the same run on the simulated clock,
    whose times start at 0, and its raw records stay as they were."""
    from vigil.report.video import VideoComposer as Composer

    shown: dict[str, list[tuple[float, bool]]] = {}
    add = Composer.add

    def spy(self, t_s, frame_rgb, *args, **kwargs):
        shown.setdefault(self.path.parent.parent.name, []).append((t_s, frame_rgb is not None))
        return add(self, t_s, frame_rgb, *args, **kwargs)

    monkeypatch.setattr(Composer, "add", spy)
    sim = write_run_on_clock(tmp_path / "sim" / "run", 0.0)  # one name: one title
    wall = write_run_on_clock(tmp_path / "wall" / "run", EPOCH_S)
    raw = {n: (wall / n).read_bytes() for n in ("steps.jsonl", "trace.jsonl", "camera_frames.bin")}
    s_sim = write_report(sim, TASK, plots=False)
    s_wall = write_report(wall, TASK, plots=False)

    (visit,) = s_wall["visits"]
    assert visit["person_arrival_t"] == 7.0 and visit["robot_arrival_t"] == 12.0
    assert s_wall["warnings_spoken"][0]["t"] == 12.0
    assert s_wall["trace"]["start_t"] == 0.0 and s_wall["events_until_t"] == 22.0
    assert s_wall["latency"]["frame_to_warning_s"]["max_s"] == 0.25
    assert s_wall.pop("time_origin_s") == EPOCH_S and "time_origin_s" not in s_sim
    assert s_wall == s_sim
    for name in ("steps.md", "steps.csv"):
        assert (wall / name).read_bytes() == (sim / name).read_bytes(), name
    # the video's overlay and progress time, and every frame found beside its record
    assert shown["wall"] == shown["sim"]
    assert [t for t, _ in shown["wall"]] == [float(k) for k in range(31)]
    assert [found for _, found in shown["wall"]] == [k % 2 == 0 for k in range(31)]
    for name, data in raw.items():  # the records are the run's, never rewritten
        assert (wall / name).read_bytes() == data, name
