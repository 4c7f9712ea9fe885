"""Run the quick benchmarks of bench/ and write a summary of where their figures went.

    .venv/bin/python bench/run_all.py [--out runs/bench] [--list]     # make bench

The quick ones are those that take under a minute or so with their default arguments
(measured 2026-11-26 on the 2-core machine at load 1-3, whole script about 60 s):

    bench_pomdp_reader.py                              ~3 s    the .pomdp reader
    bench_nav.py                                       ~3 s    A*, follower, speech
    bench_nav_twin.py                                  ~12 s   cell-to-cell moves in the twin
    bench_twin.py                                      ~40 s   render, lidar, physics, HOG
    bench_solve_cpu.py RockSample_4_4.pomdp Tiger.pomdp --repeats 2   ~6 s

(bench_solve_cpu.py takes no default files; these are the ones docs/BENCHMARKS.md
quotes.) The benchmarks of ``../shared/pomdp/`` files are skipped, saying so, when that
folder is missing. Each benchmark runs in its own process with this interpreter, from
the repository root, with ``MUJOCO_GL=egl`` unless set; its output (the figures: every
one of them prints its table to stdout) goes to ``OUT/<name>.txt``. A progress line is
printed every second. ``OUT/summary.md`` lists what ran, how long it took, where its
figures are and which section of docs/BENCHMARKS.md to compare them with, and the long
benchmarks that were not run, with their commands. Exit status 1 when a benchmark
failed or timed out, else 0.
"""

from __future__ import annotations

import argparse
import os
import platform
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED_POMDP = REPO.parent / "shared" / "pomdp"
TIMEOUT_S = 600.0  # a quick benchmark that takes ten minutes is broken, not slow


@dataclass(frozen=True)
class Bench:
    script: str
    args: tuple[str, ...]
    section: str  # the section of docs/BENCHMARKS.md with the figures to compare
    needs_shared: bool = False

    @property
    def name(self) -> str:
        return Path(self.script).stem

    def command(self) -> list[str]:
        return [sys.executable, str(REPO / "bench" / self.script), *self.args]


QUICK = (
    Bench("bench_pomdp_reader.py", (), "The `.pomdp` reader", needs_shared=True),
    Bench("bench_nav.py", (), "Navigation and speech"),
    Bench("bench_nav_twin.py", (), "Navigation and speech (twin rows)"),
    Bench("bench_twin.py", (), "Digital twin"),
    Bench(
        "bench_solve_cpu.py",
        ("RockSample_4_4.pomdp", "Tiger.pomdp", "--repeats", "2"),
        "Solving the benchmark files (Tiger, RockSample_4_4)",
        needs_shared=True,
    ),
)

# Not run: (command, why, how long; durations as docs/BENCHMARKS.md and its log give them)
LONG = (
    (
        "bench/bench_intent_bound.py runs/mc-r2-goal",
        "how early goal inference could send a guard with no latency (needs an r2 study)",
        "~7 s for 1,000 walks, after a 1,000-walk r2 study (~5 min)",
    ),
    (
        "bench/bench_perception_walks.py",
        "scripted walks through all 12 cells, rendered",
        "263-425 s under load; `--quick` 25-70 s",
    ),
    (
        "bench/bench_perception.py --repeat 3 --walk-s 40",
        "HOG at 640 x 400 and 1280 x 800 in eleven settings, leg detection, a 40 s walk",
        "minutes (not timed in the notes)",
    ),
    ("bench/bench_visibility.py", "99 rendered frames searched by HOG", "~5 min under load"),
    ("bench/bench_people.py --seeds 50", "two people: crossings and twin frames", "~10 min"),
    (
        "bench/bench_planning.py --iterations 200 --pomdp-time 5",
        "Perseus on the task models, belief-update latency, the shared files",
        "minutes (200 Perseus iterations took 18 s on r1 and 33 s on r2)",
    ),
    (
        "bench/bench_solver.py --limits 10 60 --episodes 1000",
        "solve-pomdp on every shared file at each limit, then simulated",
        "over 9 min (8 files x (10 + 60) s) plus the simulations",
    ),
    (
        "bench/bench_system.py scenarios/5.2.2.yaml",
        "the main scenario through ROS in the lock-step twin",
        "161 s at load 3-4 (21 Nov); longer since",
    ),
    (
        "bench/bench_inprocess.py",
        "the in-process loop against the ROS run",
        "~3 min (105 s + 80 s at load 11-12)",
    ),
    (
        "bench/bench_montecarlo_speed.py --episodes 20 --rendered 2",
        "one Monte-Carlo worker's speed, perception model and rendered",
        "~2 min (20 model episodes, 2 rendered)",
    ),
    (
        "bench/bench_fidelity.py --episodes 100",
        "the perception model against the rendered camera on the same walks",
        "~1.5 h rendered on 2 workers (about 100 s an episode at load 6-9)",
    ),
    (
        "bench/bench_decision.py --episodes 30",
        "the planner's decision time, anticipation layer included, on r1, r2, two people",
        "~1 min",
    ),
    (
        "bench/bench_online.py run --planner NAME --episodes 200",
        "two people: online planner and baselines (then `bench_online.py report`)",
        "12 s (greedy) to 22 min (single) per planner",
    ),
    ("bench/bench_report.py RUN", "the recorder's work per frame", "needs a run folder"),
    ("bench/bench_bag.py RUN", "a run's bag, uncompressed and zstd", "needs a run folder"),
    (
        "bench/bench_chaos.py --kills 20",
        "chaos soak: 20 random node kills in a twin run; the base stops, files read back",
        "~10-20 min",
    ),
    (
        "bench/bench_chaos.py --realtime --kills 24 --steps 80",
        "chaos soak at real time with the velocity gate among the victims",
        "~6 min",
    ),
    (
        "bench/bench_hosts.py scenarios/guard",
        "the guarding set across three hosts (network namespaces; run as root)",
        "~16 min",
    ),
    (
        "bench/repeat_under_load.py",
        "the twin repeatability test beside CPU hogs (loads the machine on purpose)",
        "the length of that test",
    ),
)


@dataclass
class Outcome:
    bench: Bench
    status: str  # "ok", "failed (exit N)", "timed out", "skipped: why"
    seconds: float
    output: Path | None


def _last_line(path: Path, width: int = 70) -> str:
    try:
        with path.open("rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - 4096))
            lines = f.read().decode(errors="replace").strip().splitlines()
    except OSError:
        return ""
    line = lines[-1].strip() if lines else ""
    return line if len(line) <= width else line[: width - 3] + "..."


def _stop(proc: subprocess.Popen) -> None:
    """Stop a benchmark's process group: SIGTERM, then SIGKILL after 10 s."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    except ProcessLookupError:
        pass


def run_one(bench: Bench, index: int, total: int, out_dir: Path, t0: float) -> Outcome:
    """Run one benchmark, a progress line a second, its output into out_dir."""
    if bench.needs_shared and not SHARED_POMDP.is_dir():
        print(f"[bench {time.monotonic() - t0:5.0f} s] {index}/{total} {bench.name}: skipped")
        return Outcome(bench, f"skipped: {SHARED_POMDP} not present", 0.0, None)
    out = out_dir / f"{bench.name}.txt"
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    env.setdefault("PYOPENGL_PLATFORM", "egl")
    start = time.monotonic()
    with out.open("w") as f:
        f.write("$ " + " ".join(bench.command()[1:]) + "\n")
        f.flush()
        proc = subprocess.Popen(
            bench.command(),
            cwd=REPO,
            env=env,
            stdout=f,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group: a timeout stops its children
        )
        status = ""
        try:
            while not status:
                try:
                    code = proc.wait(timeout=1.0)
                    status = "ok" if code == 0 else f"failed (exit {code})"
                except subprocess.TimeoutExpired:
                    now = time.monotonic()
                    if now - start > TIMEOUT_S:
                        _stop(proc)
                        status = f"timed out after {TIMEOUT_S:.0f} s"
                        break
                    print(
                        f"[bench {now - t0:5.0f} s] {index}/{total} {bench.name}"
                        f" {now - start:4.0f} s  {_last_line(out)}",
                        flush=True,
                    )
        except KeyboardInterrupt:  # Ctrl-C: its own session did not get it
            _stop(proc)
            raise
    seconds = time.monotonic() - start
    print(f"[bench {time.monotonic() - t0:5.0f} s] {index}/{total} {bench.name}: {status}")
    return Outcome(bench, status, seconds, out)


def _git_commit() -> str:
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def summary(outcomes: list[Outcome], started: str, seconds: float) -> str:
    """The summary in Markdown: what ran, where its figures are, what did not run."""
    try:
        load = "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except OSError:
        load = "unknown"
    lines = [
        "# make bench: the quick benchmarks",
        "",
        f"Started {started}, {seconds:.0f} s in all; commit {_git_commit()}; "
        f"{platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}; "
        f"load average at the end {load}.",
        "",
        "Each benchmark's figures are in its output file; compare them with the section "
        "of docs/BENCHMARKS.md named (wall-clock figures move with the machine's load).",
        "",
        "| benchmark | status | seconds | figures in | docs/BENCHMARKS.md section |",
        "|---|---|---:|---|---|",
    ]
    for o in outcomes:
        where = "-"
        if o.output is not None:
            where = str(o.output.relative_to(REPO) if o.output.is_relative_to(REPO) else o.output)
        lines.append(
            f"| `{' '.join(['bench/' + o.bench.script, *o.bench.args])}` | {o.status} "
            f"| {o.seconds:.1f} | {where} | {o.bench.section} |"
        )
    lines += [
        "",
        "## Not run by `make bench`",
        "",
        "Long, or needing a run folder; run them one at a time with "
        "`MUJOCO_GL=egl .venv/bin/python COMMAND` (figures on stdout):",
        "",
        "| command | what | how long |",
        "|---|---|---|",
    ]
    lines += [f"| `{cmd}` | {what} | {how_long} |" for cmd, what, how_long in LONG]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "bench", help="output folder")
    ap.add_argument("--list", action="store_true", help="print what would run and what not")
    args = ap.parse_args(argv)
    if args.list:
        for b in QUICK:
            print("run  ", " ".join(["bench/" + b.script, *b.args]))
        for cmd, _, how_long in LONG:
            print("skip ", cmd, f"({how_long})")
        return 0
    out_dir = args.out.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    t0 = time.monotonic()
    print(f"[bench] {len(QUICK)} quick benchmarks, output in {out_dir}", flush=True)
    outcomes = [run_one(b, i, len(QUICK), out_dir, t0) for i, b in enumerate(QUICK, 1)]
    text = summary(outcomes, started, time.monotonic() - t0)
    (out_dir / "summary.md").write_text(text)
    print()
    print(text, end="")
    print(f"\n[bench] summary: {out_dir / 'summary.md'}")
    return 1 if any(o.status.startswith(("failed", "timed")) for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
