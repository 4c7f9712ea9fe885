"""The recorder's per-frame work inside the lock-step, before and after the report
became a package, and the report's own time after the run.

    MUJOCO_GL=egl .venv/bin/python bench/bench_report.py RUN_DIR [--task config/task-r1.yaml]

RUN_DIR is a run folder with ``camera_frames.bin`` (a run of this version). Before:
the recorder composed each video frame (camera beside the top view) and encoded it
with OpenCV's mp4v writer in its callback. After: it JPEG-encodes the camera frame
into ``camera_frames.bin``; the video is composed and encoded (H.264) by the report
after the nodes stop. Prints median and p90 per frame, and the report's wall time.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from stack.planning.task import load_task  # noqa: E402
from vigil.frames import FRAMES_FILE, FrameWriter, decode, read_frames  # noqa: E402
from vigil.report import write_report  # noqa: E402
from vigil.report.video import VideoComposer  # noqa: E402


def _stats(xs: list[float]) -> str:
    ms = np.asarray(xs) * 1000
    return f"median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms ({len(xs)} frames)"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir")
    ap.add_argument("--task", default=str(REPO / "config" / "task-r1.yaml"))
    ap.add_argument("--frames", type=int, default=300)
    args = ap.parse_args()
    run = Path(args.run_dir)
    task = load_task(args.task)
    trace = [json.loads(x) for x in (run / "trace.jsonl").read_text().splitlines()][: args.frames]
    jpegs = {round(t, 6): d for t, d in read_frames(run / FRAMES_FILE)}
    frames = [decode(jpegs.get(round(r["t"], 6), b"")) for r in trace]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # before: compose + mp4v inside the recorder's callback
        composer = VideoComposer(tmp / "x.mp4", task.grid, tuple(task.restricted_cells))
        composer.close()  # only its drawing is used; the writer is the old one
        writer = cv2.VideoWriter(
            str(tmp / "old.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (960, 360)
        )
        before = []
        for r, f in zip(trace, frames, strict=True):
            t0 = time.perf_counter()
            img = composer.render(
                r["t"], f, r.get("camera"), r.get("legs") or [], r.get("robot"), r.get("person")
            )
            writer.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            before.append(time.perf_counter() - t0)
        writer.release()
        # after: one JPEG into the frames file
        fw = FrameWriter(tmp / FRAMES_FILE)
        after = []
        for r, f in zip(trace, frames, strict=True):
            bgr = None if f is None else np.ascontiguousarray(f[:, :, ::-1])
            t0 = time.perf_counter()
            fw.add(r["t"], bgr)
            fw.flush()
            after.append(time.perf_counter() - t0)
        fw.close()
        print(f"recorder per frame, before (compose + mp4v): {_stats(before)}")
        print(f"recorder per frame, after (JPEG to {FRAMES_FILE}): {_stats(after)}")
        # the report after the run, on a copy of the run folder
        copy = tmp / "run"
        shutil.copytree(run, copy, ignore=shutil.ignore_patterns("*.wav", "camera.mp4"))
        t0 = time.perf_counter()
        write_report(copy, args.task)
        total = time.perf_counter() - t0
        n = sum(1 for _ in (copy / "trace.jsonl").open())
        mb = (copy / "camera.mp4").stat().st_size / 1e6
        print(f"report after the run: {total:.1f} s ({n} video frames, camera.mp4 {mb:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
