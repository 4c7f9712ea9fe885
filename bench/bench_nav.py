"""Navigation and speech benchmark: A* per plan, follower step, cell-to-cell move, speech.

Run from the repository root:

    .venv/bin/python bench/bench_nav.py            # full
    .venv/bin/python bench/bench_nav.py --repeats 3

Prints a Markdown table (the figures that go into docs/BENCHMARKS.md). The cell-to-cell
move time is simulated time on the kinematic base model (stack/nav/base_model.py) until
the MuJoCo twin lands. pyastar2d, when installed, is timed on the same grids for
comparison (it allows corner cutting and prices diagonals at 1, so its paths differ).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stack.cells import CellGrid  # noqa: E402
from stack.nav.astar import astar_grid  # noqa: E402
from stack.nav.base_model import KinematicBase  # noqa: E402
from stack.nav.config import FollowerConfig, SpeechConfig  # noqa: E402
from stack.nav.follower import PathFollower, Pose2D  # noqa: E402
from stack.nav.occupancy import OCCUPIED, OccupancyMap, inflate  # noqa: E402
from stack.nav.speech import forget_said, synthesize  # noqa: E402


def room_map(rng: np.random.Generator) -> OccupancyMap:
    """A 12 m x 8 m room at 5 cm (240 x 160 cells): walls, an inner wall with a door,
    and a few tables; the 6 m x 3 m cell region sits inside it."""
    m = OccupancyMap.empty(12.0, 8.0, 0.05, (-3.0, -2.5))
    d = m.data.copy()
    d[[0, -1], :] = OCCUPIED
    d[:, [0, -1]] = OCCUPIED
    d[:, 200] = OCCUPIED  # an inner wall 10 m east of the west wall...
    d[60:80, 200] = 0  # ...with a 1 m door
    for _ in range(6):  # tables: 0.8 m x 0.6 m
        r, c = rng.integers(10, 140), rng.integers(10, 180)
        if not (45 <= r <= 125 and 55 <= c <= 185):  # keep the cell region clear
            d[r : r + 12, c : c + 16] = OCCUPIED
    return m.with_data(d)


def large_map(rng: np.random.Generator, n: int = 1000) -> np.ndarray:
    """n x n blocked grid: border, 300 random wall segments of 1..n/10 cells."""
    g = np.zeros((n, n), dtype=bool)
    g[[0, -1], :] = g[:, [0, -1]] = True
    for _ in range(300):
        r, c = rng.integers(0, n, size=2)
        length = rng.integers(1, n // 10)
        if rng.random() < 0.5:
            g[r : r + length, c : c + 2] = True
        else:
            g[r : r + 2, c : c + length] = True
    g[1:4, 1:4] = g[-4:-1, -4:-1] = False
    return g


def time_ms(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), out


def corner_cuts(blocked: np.ndarray, cells: np.ndarray) -> int:
    n = 0
    for (r, c), (r2, c2) in zip(cells[:-1], cells[1:], strict=True):
        if r != r2 and c != c2 and (blocked[r, c2] or blocked[r2, c]):
            n += 1
    return n


def bench_astar(rows, name, blocked, start, goal, repeats):
    ms, path = time_ms(lambda: astar_grid(blocked, start, goal), repeats)
    rows.append((f"A* (ours) {name}", f"{ms:.1f} ms/plan", f"cost {path.cost_cells:.1f} cells"))
    try:
        import pyastar2d  # noqa: PLC0415 - optional comparison only
    except ImportError:
        return
    w = np.where(blocked, np.inf, 1.0).astype(np.float32)
    ms2, p2 = time_ms(lambda: pyastar2d.astar_path(w, start, goal, allow_diagonal=True), repeats)
    steps = np.abs(np.diff(p2, axis=0)).sum(axis=1)
    cost = float((steps == 1).sum() + math.sqrt(2) * (steps == 2).sum())
    rows.append(
        (
            f"pyastar2d {name}",
            f"{ms2:.1f} ms/plan",
            f"cost {cost:.1f} cells, {corner_cuts(blocked, p2)} corner cuts",
        )
    )


def bench_move(rows, grid: CellGrid, occ: OccupancyMap):
    cfg = FollowerConfig()
    follower = PathFollower(cfg, occ)
    dt = 0.05
    for a, b in ((7, 5), (7, 8), (12, 1)):
        base = KinematicBase(Pose2D(*grid.center(a)))
        dist_m = math.dist(grid.center(a), grid.center(b))
        follower.start(grid.center(b), 0.0)
        t, steps, wall = 0.0, 0, 0.0
        while True:
            t0 = time.perf_counter()
            st = follower.step(base.pose, t, t)
            wall += time.perf_counter() - t0
            steps += 1
            if st.result is not None:
                break
            base.step(st.cmd, dt)
            t += dt
        rows.append(
            (
                f"move cell {a} -> {b} (kinematic base, {dist_m:.2f} m)",
                f"{t:.2f} s simulated",
                f"{st.result.value}; follower {wall / steps * 1e3:.2f} ms/step",
            )
        )


def bench_speech(rows, repeats):
    """espeak-ng's synthesis (the process's kept audio forgotten before each call) and
    a repeated warning (its audio kept: what a node does from the second warning on)."""

    def fresh(cfg, path):
        forget_said()
        return synthesize(cfg.warning, path, cfg)

    with tempfile.TemporaryDirectory() as tmp:
        for voice in ("en", "pt"):
            cfg = SpeechConfig(voice=voice)
            path = Path(tmp) / "w.wav"
            ms, utt = time_ms(lambda cfg=cfg, path=path: fresh(cfg, path), repeats)
            kept_ms, _ = time_ms(
                lambda cfg=cfg, path=path: synthesize(cfg.warning, path, cfg), repeats
            )
            rows.append(
                (
                    f"espeak-ng synthesis ({voice}, {len(cfg.warning.split())} words)",
                    f"{ms:.1f} ms",
                    f"{utt.duration_s:.2f} s of audio; said again (kept): {kept_ms:.1f} ms",
                )
            )


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="timings per figure (median)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rows: list[tuple[str, str, str]] = []

    grid = CellGrid()
    occ = room_map(rng)
    blocked = inflate(occ, FollowerConfig().inflation_radius_m)
    ms, _ = time_ms(lambda: inflate(occ, 0.35), args.repeats)
    rows.append(("inflate room map 240x160", f"{ms:.2f} ms", "EDT, radius 0.35 m"))
    a, b = occ.world_to_cell(-2.5, -2.0), occ.world_to_cell(8.5, 5.0)
    bench_astar(rows, "room 240x160 corner to corner", blocked, a, b, args.repeats)
    a, b = occ.world_to_cell(*grid.center(12)), occ.world_to_cell(*grid.center(1))
    bench_astar(rows, "room 240x160 cell 12 -> 1", blocked, a, b, args.repeats)
    a, b = occ.world_to_cell(*grid.center(7)), occ.world_to_cell(*grid.center(5))
    bench_astar(rows, "room 240x160 cell 7 -> 5", blocked, a, b, args.repeats)
    big = large_map(rng)
    bench_astar(
        rows, "1000x1000 corner to corner", big, (1, 1), (998, 998), max(1, args.repeats // 2)
    )
    bench_move(rows, grid, occ)
    bench_speech(rows, args.repeats)

    print(
        f"# bench_nav  python {platform.python_version()}  {platform.machine()}  seed {args.seed}"
    )
    print("| what | time | notes |\n|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} |")


if __name__ == "__main__":
    main()
