"""``vigil montecarlo TASK --episodes N``: the whole guarding loop over randomised walks.

Each episode is a random scenario (:func:`random_scenario`) run through the in-process
loop (:func:`vigil.inprocess.run_inprocess`: the twin's dm-control environment, the
perception cores, the planner, navigation, speech) into ``OUT/episodes/NNN/`` and
scored by the run report's metric code (:mod:`vigil.report.metrics`: one definition of
a visit, a guarded visit, a delay, a false trip). Then:

- ``OUT/montecarlo.json``: the study's parameters, every episode's scenario and
  metrics, and the summary with 95 % confidence intervals;
- ``OUT/montecarlo.md``: the summary table;
- ``OUT/montecarlo.png``: per episode visits guarded / not guarded and false trips,
  and the delays' distribution.

A walk: the person enters through the door, goes to one or two targets (a restricted
cell with probability ``p_restricted``, else another cell; a random point in the cell)
at speeds drawn from 0.4-1.4 m/s, pauses there, and leaves. With probability
``p_fault`` the episode also has one camera or lidar outage. Every draw comes from the
episode's own generator (``SeedSequence(seed).spawn``): the same ``seed`` gives the same
episodes and, the loop being deterministic, the same results, whatever the workers.

Episodes run in parallel on local processes (``concurrent.futures``), or on a Ray
cluster (``ray="local"`` or an address; ``pip install .[ray]``).

Confidence intervals: the guarded-visit rate and the share of episodes with a false
trip are binomial (Wilson score interval); the mean delay and the false trips per
episode are bootstrapped over episodes (2000 resamples, seeded), because visits of
one episode are not independent.

Just over 500 lines because the study is one unit: drawing episodes, running them on
processes or Ray, and summarising them with their intervals and figure share the
episode record's layout, which reads best in one place.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stack.cells import ConfigError
from stack.planning.task import Task, load_task
from vigil.scenario import Fault, Leg, Scenario

Z95 = 1.959963984540054
BOOTSTRAP = 2000


@dataclass(frozen=True)
class StudyConfig:
    """The randomisation of a study.

    Attributes:
        speed_mps: (low, high) walking speeds.
        pause_s: (low, high) pause at a restricted target [s].
        other_pause_s: (low, high) pause at another target [s].
        targets: (fewest, most) targets per walk.
        p_restricted: probability that a target is a restricted cell.
        p_fault: probability of one sensor outage in an episode.
        outage_s: (low, high) outage length [s]; it starts within ``outage_at_s``.
        outage_at_s: (low, high) outage start [s].
        tail_s: the episode runs this long after the person has left.
        max_sim_s: no episode runs longer (simulated seconds).
    """

    speed_mps: tuple[float, float] = (0.4, 1.4)
    pause_s: tuple[float, float] = (2.0, 8.0)
    other_pause_s: tuple[float, float] = (0.0, 3.0)
    targets: tuple[int, int] = (1, 2)
    p_restricted: float = 0.6
    p_fault: float = 0.25
    outage_s: tuple[float, float] = (2.0, 8.0)
    outage_at_s: tuple[float, float] = (3.0, 15.0)
    tail_s: float = 5.0
    max_sim_s: float = 60.0

    def __post_init__(self) -> None:
        pairs = ("speed_mps", "pause_s", "other_pause_s", "outage_s", "outage_at_s")
        for name in pairs:
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise ConfigError(name, (lo, hi), "must be finite with 0 <= low <= high")
        lo, hi = self.speed_mps
        if lo < 0.1 or hi > 1.4:
            raise ConfigError("speed_mps", self.speed_mps, "must lie in [0.1, 1.4] m/s")
        if not 1 <= self.targets[0] <= self.targets[1]:
            raise ConfigError("targets", self.targets, "must be 1 <= fewest <= most")
        for name in ("p_restricted", "p_fault"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(name, getattr(self, name), "must be a probability in [0, 1]")
        if not self.tail_s >= 0 or not self.max_sim_s > 0:
            raise ConfigError("tail_s/max_sim_s", (self.tail_s, self.max_sim_s), ">= 0 and > 0")


def _uniform(rng: np.random.Generator, bounds: tuple[float, float], nd: int = 2) -> float:
    return round(float(rng.uniform(bounds[0], bounds[1])), nd)


def random_scenario(
    task_path: Path, task: Task, rng: np.random.Generator, index: int, study: StudyConfig
) -> Scenario:
    """One random walk (and maybe a fault) as a scenario; every draw from ``rng``.

    The robot starts at the task's rest cell; the planner believes nobody is there.
    """
    grid = task.grid
    restricted = list(task.restricted_cells)
    others = [c for c in grid.cells if c not in restricted and c != task.rest_cell]
    walk = [Leg("door", _uniform(rng, study.speed_mps))]
    kinds = []
    for _ in range(int(rng.integers(study.targets[0], study.targets[1] + 1))):
        to_restricted = bool(rng.random() < study.p_restricted)
        cells = restricted if to_restricted else others
        cell = int(cells[int(rng.integers(len(cells)))])
        x0, y0, x1, y1 = grid.bounds(cell)
        u, v = rng.uniform(0.25, 0.75, 2)  # keep inside the cell, off its borders
        point = (round(x0 + u * (x1 - x0), 2), round(y0 + v * (y1 - y0), 2))
        pause = _uniform(rng, study.pause_s if to_restricted else study.other_pause_s)
        walk.append(Leg(point, _uniform(rng, study.speed_mps), pause))
        kinds.append(f"{'R' if to_restricted else 'o'}{cell}")
    speed = _uniform(rng, study.speed_mps)
    walk += [Leg("door", speed), Leg("outside", speed)]
    faults: list[Fault] = []
    if rng.random() < study.p_fault:
        kind = "camera_off" if rng.random() < 0.5 else "lidar_off"
        at, dur = _uniform(rng, study.outage_at_s), _uniform(rng, study.outage_s)
        faults.append(Fault(kind, at_s=at, duration_s=dur))
        kinds.append(f"{kind.split('_')[0]}-{dur:g}s")
    return Scenario(
        name=f"mc-{index:03d}",
        title=f"random walk {index}: " + " ".join(kinds),
        task=Path(task_path).resolve(),
        seed=int(rng.integers(0, 2**31 - 1)),
        steps=0,  # until the episode ends
        robot_cell=task.rest_cell,
        belief_person=None,
        belief_direction="not moving",
        start="outside",
        walk=tuple(walk),
        faults=tuple(faults),
    )


def episode_scenarios(task_path: Path, n: int, seed: int, study: StudyConfig) -> list[Scenario]:
    """The study's ``n`` scenarios: episode k draws from ``SeedSequence(seed).spawn(n)[k]``."""
    task = load_task(task_path)
    seqs = np.random.SeedSequence(seed).spawn(n)
    return [
        random_scenario(task_path, task, np.random.default_rng(s), k, study)
        for k, s in enumerate(seqs)
    ]


def run_episode(
    scenario: Scenario,
    out_dir: str,
    config_path: str | None,
    study: StudyConfig,
    perception: str = "model",
    perception_model: str | None = None,
):
    """One episode through the in-process loop; the metrics that matter (JSON-ready).

    Runs in a worker process (local or Ray): only picklable arguments and results.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    from vigil.inprocess import run_inprocess

    t0 = time.monotonic()
    summary = run_inprocess(
        scenario,
        out_dir,
        config_path=config_path,
        max_steps=0,
        max_sim_s=study.max_sim_s,
        tail_s=study.tail_s,
        plots=False,
        video=False,
        say=lambda _s: None,
        perception=perception,
        perception_model=perception_model,
    )
    m = summary["metrics"]
    return {
        "episode": scenario.name,
        "title": scenario.title,
        "seed": scenario.seed,
        "faults": [asdict(f) for f in scenario.faults],
        "steps": summary["steps"],
        "n_visits": m["n_visits"],
        "guarded": m["guarded"],
        "reachable": m.get("reachable", 0),
        "guarded_reachable": m.get("guarded_reachable", 0),
        "abandoned": m["abandoned"],
        "delays_s": [v["delay_s"] for v in m["visits"] if v["delay_s"] is not None],
        "n_false_trips": m["n_false_trips"],
        "timely_warnings": m["timely_warnings"],
        "late_warnings": m["late_warnings"],
        "miss_rate": m["miss_rate"],
        "sim_s": summary["inprocess"]["sim_s"],
        "wall_s": round(time.monotonic() - t0, 2),
    }


# -- statistics -------------------------------------------------------------------------------


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float | None, float | None]:
    """The Wilson score interval of a binomial proportion (None, None when n == 0)."""
    if n <= 0:
        return None, None
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_mean(
    groups: Sequence[Sequence[float]], seed: int = 0, n: int = BOOTSTRAP
) -> tuple[float | None, float | None, float | None]:
    """Mean of all values and its 95 % percentile interval, resampling whole groups
    (episodes) with replacement. (None, None, None) without values."""
    flat = [v for g in groups for v in g]
    if not flat:
        return None, None, None
    rng = np.random.default_rng(seed)
    sums = np.array([sum(g) for g in groups], float)
    counts = np.array([len(g) for g in groups], float)
    idx = rng.integers(0, len(groups), size=(n, len(groups)))
    s, c = sums[idx].sum(axis=1), counts[idx].sum(axis=1)
    means = s[c > 0] / c[c > 0]
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(np.mean(flat)), float(lo), float(hi)


def summarise(episodes: Sequence[dict[str, Any]], seed: int = 0) -> dict[str, Any]:
    """The study's summary (deterministic for the same episodes)."""
    ok = [e for e in episodes if "error" not in e]
    visits = sum(e["n_visits"] for e in ok)
    guarded = sum(e["guarded"] for e in ok)
    reachable = sum(e.get("reachable", 0) for e in ok)
    guarded_reachable = sum(e.get("guarded_reachable", 0) for e in ok)
    q_lo, q_hi = wilson(guarded_reachable, reachable)
    with_trip = sum(e["n_false_trips"] > 0 for e in ok)
    d_mean, d_lo, d_hi = bootstrap_mean([e["delays_s"] for e in ok], seed)
    t_mean, t_lo, t_hi = bootstrap_mean([[e["n_false_trips"]] for e in ok], seed + 1)
    r_lo, r_hi = wilson(guarded, visits)
    e_lo, e_hi = wilson(with_trip, len(ok))

    def r(x: float | None, nd: int = 3) -> float | None:
        return None if x is None else round(x, nd)

    return {
        "episodes": len(episodes),
        "failed_episodes": len(episodes) - len(ok),
        "visits": visits,
        "guarded": guarded,
        "abandoned": sum(e["abandoned"] for e in ok),
        "guarded_rate": r(guarded / visits) if visits else None,
        "guarded_rate_ci95": [r(r_lo), r(r_hi)],
        "reachable": reachable,
        "guarded_reachable": guarded_reachable,
        "guarded_reachable_rate": r(guarded_reachable / reachable) if reachable else None,
        "guarded_reachable_rate_ci95": [r(q_lo), r(q_hi)],
        "mean_delay_s": r(d_mean, 2),
        "mean_delay_ci95_s": [r(d_lo, 2), r(d_hi, 2)],
        "max_delay_s": r(max((d for e in ok for d in e["delays_s"]), default=None), 2),
        "false_trips": sum(e["n_false_trips"] for e in ok),
        "false_trips_per_episode": r(t_mean),
        "false_trips_per_episode_ci95": [r(t_lo), r(t_hi)],
        "episodes_with_false_trip": with_trip,
        "episodes_with_false_trip_ci95": [r(e_lo), r(e_hi)],
        "episodes_with_fault": sum(bool(e["faults"]) for e in episodes),
        "timely_warnings": sum(e["timely_warnings"] for e in ok),
        "late_warnings": sum(e["late_warnings"] for e in ok),
        "sim_s": round(sum(e.get("sim_s", 0.0) for e in ok), 1),
    }


def _ci(v: Sequence[float | None], fmt: str) -> str:
    return "-" if v[0] is None else f"[{fmt.format(v[0])}, {fmt.format(v[1])}]"


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def _pct_ci(v: Sequence[float | None] | None) -> str:
    return "-" if not v or v[0] is None else f"[{_pct(v[0])}, {_pct(v[1])}]"


def summary_markdown(s: dict[str, Any], title: str) -> str:
    """The summary as a Markdown table."""
    rate = "-" if s["guarded_rate"] is None else f"{100 * s['guarded_rate']:.0f} %"
    rate_ci = "-" if s["guarded_rate_ci95"][0] is None else (
        f"[{100 * s['guarded_rate_ci95'][0]:.0f} %, {100 * s['guarded_rate_ci95'][1]:.0f} %]"
    )  # fmt: skip
    delay = "-" if s["mean_delay_s"] is None else f"{s['mean_delay_s']:.1f} s"
    trips_ep = f"{s['episodes_with_false_trip']} / {s['episodes'] - s['failed_episodes']}"
    lines = [
        f"### {title}",
        "",
        "| metric | value | 95 % CI | basis |",
        "|---|---|---|---|",
        f"| guarded-visit rate | {rate} | {rate_ci} | {s['guarded']} of {s['visits']} "
        "visits (Wilson) |",
        f"| reachable visits guarded | {_pct(s.get('guarded_reachable_rate'))} | "
        f"{_pct_ci(s.get('guarded_reachable_rate_ci95'))} | {s.get('guarded_reachable')} of "
        f"{s.get('reachable')} visits an ideal guard at 0.5 m/s could reach (Wilson) |",
        f"| mean delay | {delay} | {_ci(s['mean_delay_ci95_s'], '{:.1f} s')} | guarded "
        f"visits, bootstrap over episodes; max {s['max_delay_s']} s |",
        f"| false trips per episode | {s['false_trips_per_episode']} | "
        f"{_ci(s['false_trips_per_episode_ci95'], '{:.2f}')} | {s['false_trips']} trips "
        "(bootstrap) |",
        f"| episodes with a false trip | {trips_ep} | "
        f"{_ci(s['episodes_with_false_trip_ci95'], '{:.2f}')} | Wilson |",
        f"| visits abandoned | {s['abandoned']} | | |",
        f"| warnings timely / late | {s['timely_warnings']} / {s['late_warnings']} | | |",
        f"| episodes with a sensor outage | {s['episodes_with_fault']} | | |",
        f"| failed episodes | {s['failed_episodes']} | | |",
        "",
    ]
    return "\n".join(lines)


def plot_study(path: Path, episodes: Sequence[dict[str, Any]], s: dict[str, Any], title: str):
    """Per episode: visits guarded / not guarded, false trips, outages (left); the
    delays with their mean and 95 % interval (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    ok = [e for e in episodes if "error" not in e]
    x = np.arange(len(ok))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    g = np.array([e["guarded"] for e in ok])
    v = np.array([e["n_visits"] for e in ok])
    a1.bar(x - 0.2, g, 0.4, color="g", label="visits guarded")
    a1.bar(x - 0.2, v - g, 0.4, bottom=g, color="r", label="visits not guarded")
    a1.bar(x + 0.2, [e["n_false_trips"] for e in ok], 0.4, color="m", label="false trips")
    labels = [
        e["episode"].split("-")[-1] + ("\n" + e["faults"][0]["kind"][0] if e["faults"] else "")
        for e in ok
    ]
    a1.set_xticks(x, labels, fontsize=7)
    a1.set_xlabel("episode (c / l: camera / lidar outage)")
    a1.set_ylabel("count")
    a1.yaxis.set_major_locator(MaxNLocator(integer=True))
    a1.legend(fontsize=7)
    a1.grid(alpha=0.2, axis="y")
    delays = [d for e in ok for d in e["delays_s"]]
    if delays:
        a2.hist(delays, bins=min(12, max(3, len(delays))), color="steelblue")
        if s["mean_delay_s"] is not None:
            a2.axvline(s["mean_delay_s"], color="k", label=f"mean {s['mean_delay_s']:.1f} s")
            lo, hi = s["mean_delay_ci95_s"]
            a2.axvspan(lo, hi, color="k", alpha=0.15, label="95 % CI of the mean")
        a2.legend(fontsize=7)
    a2.set_xlabel("delay: robot in the cell after the person entered [s]")
    a2.set_ylabel("visits")
    rate = s["guarded_rate"]
    fig.suptitle(
        f"{title}: guarded {s['guarded']}/{s['visits']}"
        + (f" ({100 * rate:.0f} %)" if rate is not None else "")
        + f", false trips {s['false_trips']} in {len(ok)} episodes",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)
    return path


# -- the study ----------------------------------------------------------------------------------


def _local_map(jobs, workers: int):
    """(index, result) as episodes finish, on ``workers`` local processes."""
    if workers <= 1:
        for k, args in jobs:
            yield k, _guarded(args)
        return
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")  # no GL state inherited through fork
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        futures = {pool.submit(_guarded, args): k for k, args in jobs}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()


def _ray_map(jobs, address: str, workers: int):
    """(index, result) as episodes finish, as Ray tasks (``address``: "local" starts a
    local instance with ``workers`` CPUs; else the cluster's address)."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError("--ray", address, "Ray is not installed: pip install .[ray]") from err
    started = not ray.is_initialized()
    if started:
        if address == "local":
            ray.init(num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1)(_guarded)
        refs = {remote.remote(args): k for k, args in jobs}
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield refs[done[0]], ray.get(done[0])
    finally:
        if started:
            ray.shutdown()


def _guarded(args) -> dict[str, Any]:
    """run_episode, with a failure returned as a record (one bad episode never ends a study)."""
    scenario = args[0]
    try:
        return run_episode(*args)
    except Exception as err:  # noqa: BLE001 - reported per episode in the summary
        return {"episode": scenario.name, "title": scenario.title, "seed": scenario.seed,
                "faults": [asdict(f) for f in scenario.faults],
                "error": f"{type(err).__name__}: {err}"}  # fmt: skip


def run_study(
    task_path: str | Path,
    episodes: int,
    out: str | Path,
    seed: int = 0,
    workers: int = 1,
    ray: str | None = None,
    config_path: str | Path | None = None,
    study: StudyConfig | None = None,
    say: Callable[[str], None] = print,
    perception: str = "model",
    perception_model: str | Path | None = None,
) -> dict[str, Any]:
    """Run the study and write its JSON, Markdown and figure; returns the JSON record.

    Args:
        task_path: the task file (its grid, restricted cells and rest cell).
        episodes: how many episodes.
        out: the study's folder (episodes in ``out/episodes``).
        seed: the study's seed (same seed, same episodes, same results).
        workers: local worker processes (or Ray CPUs with ``ray="local"``).
        ray: None (local processes), "local" or a Ray cluster address.
        config_path: the deployment file (default ``config/twin.yaml``).
        study: the randomisation.
        say: progress, one line per finished episode.
        perception: ``"model"`` (the camera pipeline's fitted model: no rendering) or
            ``"rendered"`` (EGL and HOG, the fidelity reference).
        perception_model: the model file (default ``config/perception-model.yaml``).

    Raises:
        ConfigError: bad arguments (named).
    """
    if episodes < 1:
        raise ConfigError("--episodes", episodes, "must be >= 1")
    if workers < 1:
        raise ConfigError("--workers", workers, "must be >= 1")
    task_path = Path(task_path).resolve()
    if not task_path.exists():
        raise ConfigError("TASK", str(task_path), "file not found")
    study = study or StudyConfig()
    out = Path(out).resolve()
    (out / "episodes").mkdir(parents=True, exist_ok=True)
    from vigil.system import policy_for

    policy_for(task_path, say)  # solved once here, not by every worker at the same time
    scenarios = episode_scenarios(task_path, episodes, seed, study)
    cfg = None if config_path is None else str(Path(config_path).resolve())
    model_file = None
    if perception == "model":
        from stack.perception.model import PerceptionModel
        from vigil.inprocess import DEFAULT_PERCEPTION_MODEL

        model_file = str(Path(perception_model or DEFAULT_PERCEPTION_MODEL).resolve())
        PerceptionModel.load(model_file)  # a bad file is refused before any episode runs
    jobs = [
        (k, (sc, str(out / "episodes" / f"{k:03d}"), cfg, study, perception, model_file))
        for k, sc in enumerate(scenarios)
    ]
    where = f"Ray ({ray})" if ray else f"{workers} local process(es)"
    say(f"[montecarlo] {episodes} episodes of {task_path.name}, seed {seed}, on {where}")
    t0 = time.monotonic()
    results: list[dict[str, Any] | None] = [None] * episodes
    stream = _ray_map(jobs, ray, workers) if ray else _local_map(jobs, workers)
    for n, (k, rec) in enumerate(stream, start=1):
        results[k] = rec
        say(f"[montecarlo] {n}/{episodes} {_line(rec)} ({time.monotonic() - t0:.0f} s)")
    eps = [r for r in results if r is not None]
    summary = summarise(eps, seed)
    record = {
        "task": str(task_path),
        "seed": seed,
        "study": asdict(study),
        "workers": workers,
        "ray": ray,
        "perception": perception,
        "perception_model": model_file,
        "wall_s": round(time.monotonic() - t0, 1),
        "summary": summary,
        "episodes": eps,
    }
    (out / "montecarlo.json").write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    title = f"Monte Carlo: {task_path.stem}, {episodes} episodes, seed {seed}"
    (out / "montecarlo.md").write_text(summary_markdown(summary, title))
    plot_study(out / "montecarlo.png", eps, summary, title)
    say(f"[montecarlo] {out}/montecarlo.md, montecarlo.json, montecarlo.png")
    return record


def _line(rec: dict[str, Any]) -> str:
    if "error" in rec:
        return f"{rec['episode']}: failed: {rec['error']}"
    d = rec["delays_s"]
    delay = f", delay {max(d):.1f} s" if d else ""
    return (
        f"{rec['episode']} ({rec['title'].split(': ', 1)[-1]}): {rec['guarded']}/{rec['n_visits']} "
        f"visits guarded{delay}, {rec['n_false_trips']} false trips, {rec['sim_s']:.0f} s "
        f"simulated in {rec['wall_s']:.0f} s"
    )
