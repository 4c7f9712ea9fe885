"""The report package end to end on a small synthetic run folder: the new observation
vocabulary, the speech log, the frames file, the H.264 video, index.html, and the
recorder's independence from the report."""

from __future__ import annotations

import ast
import csv
import json
from pathlib import Path

import numpy as np
import pytest

from stack.cells import CellGrid
from vigil.frames import FrameFileError, FrameWriter, decode, read_frames
from vigil.report import RunRecordError, write_report
from vigil.report.records import hidden_cells, read_speech_log
from vigil.report.video import video_codec

ROOT = Path(__file__).resolve().parents[1]
TASK = ROOT / "config" / "task-r1.yaml"
GRID = CellGrid()


def person_xy(t: float) -> list[float] | None:
    """In cell 3 until 4 s, in cell 1 from 4 s to 12 s, then in cell 4; gone from 16 s."""
    if t < 4:
        return [4.5, 0.75]
    if t < 12:
        return [5.5, 0.75]
    if t < 16:
        return [4.5, 2.25]
    return None


def robot_xy(t: float) -> list[float]:
    """At 5 until 6 s, in cell 3 until 8 s, in cell 1 from 8 s."""
    return [3.5 if t < 6 else (4.5 if t < 8 else 5.5), 0.75, 0.0]


def make_run(run: Path, frames: bool = True) -> Path:
    run.mkdir(parents=True)
    trace = []
    for k in range(0, 201):
        t = k / 10
        p = person_xy(t)
        trace.append(
            {
                "t": t,
                "robot": robot_xy(t),
                "robot_cell": None,
                "person": p,
                "person_cell": None,
                "person_velocity": [0.0, 0.0] if p else None,
                "odom": robot_xy(t),
                "camera": {"status": "person" if p else "no person", "cell": None},
                "legs": [],
                "speech": ["w1", "w2"] if k == 90 else None,  # two in one record
            }
        )
    (run / "trace.jsonl").write_text("".join(json.dumps(r) + "\n" for r in trace))
    obs = [  # (stamp, person label, extra keys)
        (2.0, "3", {"source": "camera"}),
        (5.0, "1", {"source": "fused", "hidden": {"1": 0.4}}),
        (7.0, "Unseen", {"source": "none", "hidden": [[1, 1.0], [3, 1.0]]}),
        (9.0, "No person", {"source": "none"}),  # a miss
        (11.0, "3", {"source": "laser", "future_key": [1, 2]}),  # wrong cell
        (14.0, "4", {"source": "camera"}),
        (18.0, "No person", {}),
    ]
    steps = []
    for n, (stamp, person, extra) in enumerate(obs, start=1):
        robot = str(GRID.cell_at(*robot_xy(stamp)[:2]))
        steps.append(
            {
                "step": n,
                "stamp_s": stamp,
                "action": "Do nothing",
                "observation": {"robot": robot, "person": person, "velocity": "Not moving"} | extra,
                "belief": None,
                "values": [],
                "nav": None,
                "resumed": False,
                "trigger": "person in 1" if n == 2 else "step",
            }
        )
    (run / "steps.jsonl").write_text("".join(json.dumps(s) + "\n" for s in steps))
    (run / "speech").mkdir()
    (run / "speech" / "speech_log.tsv").write_text(
        "time_s\tvoice\tduration_s\twav\ttext\n"
        "8.500\ten\t3.453\tutterance_0001.wav\tPlease leave.\n"
        "12.000\ten\t3.453\tutterance_0002.wav\tPlease leave.\n"
        "15.500\ten\t3.453\tutterance_0003.wav\tPlease leave.\n"
    )
    if frames:
        rng = np.random.default_rng(1)
        img = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
        w = FrameWriter(run / "camera_frames.bin")
        for r in trace:
            w.add(r["t"], None if r["t"] == 1.0 else img)
        w.close()
    return run


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    run = make_run(tmp_path_factory.mktemp("pkg") / "run")
    return run, write_report(run, TASK)


def test_metrics_in_summary(report):
    _run, s = report
    m = s["metrics"]
    (v,) = m["visits"]
    assert (v["cell"], v["person_arrival_t"], v["person_left_t"]) == (1, 4.0, 12.0)
    assert v["guarded"] and v["delay_s"] == 4.0 and not v["abandoned"]
    # the speech log is the source: 8.5 and 12.0 timely, 15.5 late (3.5 s after)
    assert m["speech_source"] == "speech log"
    assert [w["timely"] for w in m["warnings"]] == [True, True, False]
    assert (m["timely_warnings"], m["late_warnings"]) == (2, 1)
    assert len(s["warnings_spoken"]) == 3 and s["warning_in_restricted"] is True
    assert m["steps_with_person"] == 6 and m["misses"] == 1
    assert m["unseen_steps"] == 1 and m["wrong_cell_steps"] == 1
    assert m["sources"] == {"camera": 2, "fused": 1, "laser": 1, "none": 2}
    assert s["robot_reached_every_visit"] is True
    # events end at the last decision (18 s): the trace's tail is not counted
    assert s["events_until_t"] == 18.0


def test_step_table_shows_source_hidden_and_outcome(report):
    run, _ = report
    with open(run / "steps.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["outcome"] for r in rows] == [
        "seen", "seen", "unseen", "miss", "wrong cell", "seen", "absent",
    ]  # fmt: skip
    assert rows[1]["hidden"] == "1 (40%)" and rows[2]["hidden"] == "1, 3"
    assert rows[1]["source"] == "fused" and rows[1]["trigger"] == "person in 1"
    md = (run / "steps.md").read_text()
    assert "## Guarding metrics" in md and "| Unseen |" in md


def test_video_is_h264_and_index_links_everything(report):
    run, s = report
    assert "camera.mp4" in s["files"] and video_codec(run / "camera.mp4") == "h264"
    assert not (run / "camera.part.mp4").exists()
    html = (run / "index.html").read_text()
    for name in ("steps.md", "steps.csv", "summary.json", "camera.mp4", "timeline.png"):
        assert f'href="{name}"' in html and (run / name).stat().st_size > 0, name
    assert "<video" in html and "Guarding metrics" in html
    # the step table itself, a miss marked
    assert "<h2>Step table</h2>" in html and html.count('<tr class="bad">') == 2


def test_no_frames_leaves_an_existing_video_alone(tmp_path):
    run = make_run(tmp_path / "old", frames=False)
    (run / "camera.mp4").write_bytes(b"from an older recorder")
    s = write_report(run, TASK, plots=False)
    assert "camera.mp4" not in s["files"]
    assert (run / "camera.mp4").read_bytes() == b"from an older recorder"


def test_trace_speech_list_counts_every_warning_without_a_log(tmp_path):
    run = make_run(tmp_path / "nolog", frames=False)
    (run / "speech" / "speech_log.tsv").unlink()
    s = write_report(run, TASK, plots=False, video=False)
    assert s["metrics"]["speech_source"] == "trace"
    assert [w["t"] for w in s["warnings_spoken"]] == [9.0, 9.0]


def test_unknown_labels_still_rejected(tmp_path):
    run = make_run(tmp_path / "bad", frames=False)
    lines = (run / "steps.jsonl").read_text().splitlines()
    rec = json.loads(lines[0])
    rec["observation"]["person"] = "Somebody"
    (run / "steps.jsonl").write_text(json.dumps(rec) + "\n")
    with pytest.raises(RunRecordError, match=r"steps\.jsonl:1: observation person 'Somebody'"):
        write_report(run, TASK, plots=False, video=False)


def test_speech_log_errors_name_the_line(tmp_path):
    p = tmp_path / "speech_log.tsv"
    p.write_text("time_s\tvoice\tduration_s\twav\ttext\n1.0\ten\t2.0\ta.wav\thi\nsoon\ten\n")
    with pytest.raises(RunRecordError, match=r"speech_log\.tsv:3"):
        read_speech_log(p)
    p.write_text("time_s\tvoice\tduration_s\twav\ttext\n1.0\ten\t2.0\ta.wav\thi\n2.0\ten")
    warnings: list[str] = []
    assert [u.t for u in read_speech_log(p, warnings)] == [1.0] and warnings


def test_hidden_cells_forms():
    assert hidden_cells({"3": 0.4, "1": 1}) == {1: 1.0, 3: 0.4}
    assert hidden_cells([[3, 0.5]]) == {3: 0.5}
    assert hidden_cells([2, 4]) == {2: 1.0, 4: 1.0}
    assert hidden_cells("junk") == {} and hidden_cells(None) == {}


def test_frames_file_round_trip_and_truncation(tmp_path):
    path = tmp_path / "f.bin"
    img = np.zeros((40, 60, 3), np.uint8)
    img[:, :30] = (0, 0, 255)  # BGR red on the left
    w = FrameWriter(path)
    w.add(0.1, img)
    w.add(0.2, None)
    w.close()
    w.close()
    got = list(read_frames(path))
    assert [t for t, _ in got] == [0.1, 0.2] and got[1][1] == b""
    rgb = decode(got[0][1])
    assert rgb.shape == (40, 60, 3) and rgb[20, 10, 0] > 200 and rgb[20, 10, 2] < 50
    assert decode(b"") is None
    whole = path.read_bytes()
    path.write_bytes(whole[:-5])  # killed mid-write: the last entry goes
    assert [t for t, _ in read_frames(path)] == [0.1]
    path.write_bytes(whole + b"\x00" * 3)  # a header cut short
    assert len(list(read_frames(path))) == 2
    (tmp_path / "g.bin").write_bytes(b"not frames")
    with pytest.raises(FrameFileError, match="not a frames file"):
        list(read_frames(tmp_path / "g.bin"))
    with pytest.raises(ValueError, match="quality"):
        FrameWriter(tmp_path / "h.bin", quality=0)


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_recorder_imports_nothing_of_the_report():
    for module in ("node_recorder.py", "frames.py"):
        names = _imports(ROOT / "vigil" / module)
        assert not {n for n in names if n.startswith(("vigil.report", "vigil.run_report"))}, module
        assert not {n for n in names if "matplotlib" in n or "imageio" in n}, module
