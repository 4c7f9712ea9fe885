"""``vigil montecarlo``: the whole guarding loop over many episodes, in-process.

``vigil montecarlo TASK --episodes N [--walks FILE]`` draws N random walks of the
task from a walk distribution (:mod:`vigil.walks`; ``config/walks.yaml`` by default);
``vigil montecarlo --scenarios DIR`` runs every scenario file of a folder instead (one
or several people, faults), each in a folder named after its file. Each episode runs
through the in-process loop (:func:`vigil.inprocess.run_inprocess`: the twin's
dm-control environment, the perception cores, the planner, navigation, speech) into
``OUT/episodes/<name>/`` with the raw records of a ``vigil run`` (``steps.jsonl``,
``trace.jsonl``, ``speech/speech_log.tsv``, ``params.yaml``) and is scored by the run
report's metric code (:mod:`vigil.report.metrics`). The camera is either the fitted
model of its pipeline (``perception="model"``, the default: no rendering, about 30
times faster) or rendered and read by HOG (``"rendered"``, the reference the model is
fitted to and checked against). Then:

- ``OUT/montecarlo.json``: the study's parameters, every episode's scenario and
  metrics, and the summary with 95 % confidence intervals (:mod:`vigil.study_stats`);
- ``OUT/montecarlo.md``: the summary table and the worst episodes by name;
- ``OUT/montecarlo.png``: per episode visits guarded / not guarded and false trips,
  and the delays' distribution.

Every draw comes from the episode's own generator (``SeedSequence(seed).spawn``): the
same ``seed`` gives the same episodes and, the loop being deterministic, the same
results, whatever the workers. Episodes run in parallel on local processes
(``concurrent.futures``) or on a Ray cluster (``ray="local"`` or an address;
``pip install .[ray]``). An episode that fails (or whose worker dies) is reported as
failed; the study goes on.
"""

from __future__ import annotations

import json
import math
import os
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from stack.cells import ConfigError
from stack.config import read_text_capped, write_text
from stack.planning.task import load_task
from stack.planning.threads import ENV_VARS
from vigil.run_folder import fresh_run_dir
from vigil.scenario import Scenario
from vigil.study_stats import (  # noqa: F401 - the study's statistics, re-exported
    bootstrap_mean,
    plot_study,
    summarise,
    summary_markdown,
    wilson,
    worst_episodes,
)
from vigil.walks import StudyConfig, random_scenario


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
    max_steps: int | None = 0,
):
    """One episode through the in-process loop; the metrics that matter (JSON-ready).

    Runs in a worker process (local or Ray): only picklable arguments and results.
    ``max_steps``: 0 runs until the episode ends; None keeps the scenario's own.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    from vigil.inprocess import run_inprocess

    t0 = time.monotonic()
    summary = run_inprocess(
        scenario,
        out_dir,
        config_path=config_path,
        max_steps=max_steps,
        max_sim_s=study.max_sim_s,
        tail_s=study.tail_s,
        plots=False,
        video=False,
        say=lambda _s: None,
        perception=perception,
        perception_model=perception_model,
    )
    record = {
        "episode": scenario.name,
        "title": scenario.title,
        "task": Path(scenario.task).stem,
        "seed": scenario.seed,
        "faults": [asdict(f) for f in scenario.faults],
        "steps": summary["steps"],
        **metric_fields(summary),
        "sim_s": summary["inprocess"]["sim_s"],
        "wall_s": round(time.monotonic() - t0, 2),
    }
    # the record beside the episode's raw files: a study stopped half-way keeps it
    write_text(Path(out_dir) / "episode.json", json.dumps(record, sort_keys=True) + "\n")
    return record


def metric_fields(summary: dict[str, Any]) -> dict[str, Any]:
    """An episode record's metrics, from its report's summary (``metrics``; with several
    walkers, their visits and trips from ``people``, :mod:`vigil.report.people`)."""
    m = summary["metrics"]
    out = {
        "n_visits": m["n_visits"],
        "guarded": m["guarded"],
        "reachable": m.get("reachable", 0),
        "guarded_reachable": m.get("guarded_reachable", 0),
        "robot_first": m.get("robot_first", 0),
        "abandoned": m["abandoned"],
        "delays_s": [v["delay_s"] for v in m["visits"] if v["delay_s"] is not None],
        "visits": [{k: v.get(k) for k in VISIT_KEYS} for v in m["visits"]],
        "n_false_trips": m["n_false_trips"],
        "n_needless_trips": m.get("n_needless_trips", 0),
        "timely_warnings": m["timely_warnings"],
        "late_warnings": m["late_warnings"],
        "approach_warnings": m.get("approach_warnings", 0),
        "warning_leads_s": [
            v["warning_lead_s"] for v in m["visits"] if v.get("warning_lead_s") is not None
        ],
        "miss_rate": m["miss_rate"],
    }
    people = summary.get("people")
    if people:  # every walker's visits (the one-person fields count the first's)
        visits: list[dict[str, Any]] = [
            {**{k: v.get(k) for k in VISIT_KEYS}, "person": p["person"]}
            for p in people["per_person"]
            for v in p["visits"]
        ]
        out.update(
            {k: people[k] for k in ("n_visits", "guarded", "reachable", "guarded_reachable")},
            robot_first=people["robot_first"],
            one_guard=people.get("one_guard"),
            abandoned=sum(p["abandoned"] for p in people["per_person"]),
            delays_s=[v["delay_s"] for v in visits if v["delay_s"] is not None],
            visits=visits,
            n_false_trips=people["n_false_trips"],
            n_needless_trips=people["n_needless_trips"],
            **{k: people[k] for k in ("timely_warnings", "late_warnings", "approach_warnings")},
            warning_leads_s=[
                v["warning_lead_s"] for v in visits if v["warning_lead_s"] is not None
            ],
        )
    return out


VISIT_KEYS = (
    "cell",
    "person_arrival_t",
    "person_duration_s",
    "guarded",
    "reachable",
    "robot_first",
    "delay_s",
    "warning_lead_s",
)


# -- the study ----------------------------------------------------------------------------------


def _local_map(jobs, workers: int):
    """(index, result) as episodes finish, on ``workers`` local processes."""
    if workers <= 1:  # here (run_inprocess keeps to one BLAS thread, as the workers do)
        for k, args in jobs:
            yield k, _guarded(args)
        return
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")  # no GL state inherited through fork
    jobs_by_k = dict(jobs)
    # one BLAS thread per worker: the workers are the parallelism (two workers of two
    # OpenBLAS threads each on two cores wait on each other: a decision took 2x longer)
    # (the pool starts its processes as jobs are submitted: the variables hold till then)
    saved = {k: os.environ.get(k) for k in ENV_VARS}
    os.environ.update(dict.fromkeys(ENV_VARS, "1"))
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        try:
            futures = {pool.submit(_guarded, args): k for k, args in jobs}
        finally:
            for name, value in saved.items():
                if value is None:
                    os.environ.pop(name, None)
                else:
                    os.environ[name] = value
        for fut in as_completed(futures):
            k = futures[fut]
            try:
                yield k, fut.result()
            except Exception as err:  # noqa: BLE001 - a worker that died: that episode failed
                sc = jobs_by_k[k][0]
                yield k, {"episode": sc.name, "title": sc.title, "seed": sc.seed,
                          "faults": [asdict(f) for f in sc.faults],
                          "error": f"worker died: {type(err).__name__}: {err}"}  # fmt: skip


# Ray's workers render with EGL like the local ones (the twin's calibration renders)
RAY_ENV = {"MUJOCO_GL": "egl", "PYOPENGL_PLATFORM": "egl", **dict.fromkeys(ENV_VARS, "1")}
RAY_OBJECT_STORE = 100 * 2**20  # a local instance: episodes pass small records, not arrays


def _ray_map(jobs, address: str, workers: int):
    """(index, result) as episodes finish, as Ray tasks (``address``: "local" starts a
    local instance with ``workers`` CPUs, no dashboard and a small object store; else the
    cluster's address). Workers import the project (an installed or editable checkout on
    every node, docs/CLUSTER.md); their output is not forwarded. A task whose worker or
    node died (after Ray's retries) is reported as a failed episode."""
    try:
        import ray
    except ImportError as err:
        raise ConfigError("--ray", address, "Ray is not installed: pip install .[ray]") from err
    import logging

    started = not ray.is_initialized()
    if started:
        # ERROR: not Ray's start-up lines (the instance, token authentication) on every study
        quiet = dict(log_to_driver=False, logging_level=logging.ERROR)
        if address == "local":
            ray.init(num_cpus=max(1, workers), include_dashboard=False,
                     object_store_memory=RAY_OBJECT_STORE, runtime_env={"env_vars": RAY_ENV},
                     **quiet)  # fmt: skip
        else:
            try:
                ray.init(address=address, runtime_env={"env_vars": RAY_ENV}, **quiet)
            except ConnectionError as err:  # no cluster there, or it wants the token
                raise ConfigError("--ray", address, f"{err} (is it a `ray start` address? "
                                  "token authentication: RAY_AUTH_MODE=token, "
                                  "docs/CLUSTER.md)") from err  # fmt: skip
    try:
        remote = ray.remote(num_cpus=1)(_guarded)
        refs = {remote.remote(args): k for k, args in jobs}
        jobs_by_k = dict(jobs)
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            k = refs[done[0]]
            try:
                rec = ray.get(done[0])
            except ray.exceptions.RayError as err:  # a worker or node died, or no vigil there
                sc, why = jobs_by_k[k][0], (str(err).strip().splitlines() or [""])[-1]
                rec = {"episode": sc.name, "title": sc.title, "seed": sc.seed,
                       "faults": [asdict(f) for f in sc.faults],
                       "error": f"Ray: {type(err).__name__}: {why}"}  # fmt: skip
            yield k, rec
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
    task_path: str | Path | None,
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
    scenarios: Sequence[Scenario] | None = None,
) -> dict[str, Any]:
    """Run the study and write its JSON, Markdown and figure; returns the JSON record.

    Args:
        task_path: the task file (its grid, restricted cells and rest cell); None with
            ``scenarios``.
        episodes: how many random walks (ignored with ``scenarios``).
        out: the study's folder, episodes in ``out/episodes`` (a used one is kept: ``-2``).
        seed: the study's seed (same seed, same episodes, same results).
        workers: local worker processes (or Ray CPUs with ``ray="local"``).
        ray: None (local processes), "local" or a Ray cluster address.
        config_path: the deployment file (default ``config/twin.yaml``).
        study: the walk distribution (and the episodes' time bounds).
        say: progress, about a line a second, with the time left.
        perception: ``"model"`` (the camera pipeline's fitted model: no rendering) or
            ``"rendered"`` (EGL and HOG, the fidelity reference).
        perception_model: the model file (default ``config/perception-model.yaml``).
        scenarios: run these (each names its own task, steps and faults; episode
            folders named after them) instead of random walks.

    Raises:
        ConfigError: bad arguments (named).
    """
    if workers < 1:
        raise ConfigError("--workers", workers, "must be >= 1")
    study = study or StudyConfig()
    if scenarios is None:
        if episodes < 1:
            raise ConfigError("--episodes", episodes, "must be >= 1")
        if task_path is None or not Path(task_path).exists():
            raise ConfigError("TASK", str(task_path), "file not found")
        task_path = Path(task_path).resolve()
        scenarios = episode_scenarios(task_path, episodes, seed, study)
        names = [f"{k:03d}" for k in range(len(scenarios))]
        max_steps: int | None = 0  # random walks run until the episode ends
        what = f"{len(scenarios)} episodes of {task_path.name}, seed {seed}"
    else:
        if not scenarios:
            raise ConfigError("--scenarios", [], "no scenario files")
        names = [sc.name for sc in scenarios]
        if len(set(names)) != len(names):
            raise ConfigError("--scenarios", names, "two scenarios with the same name")
        max_steps = None  # each scenario's own steps
        what = f"{len(scenarios)} scenarios"
    if perception not in ("model", "rendered"):
        raise ConfigError("--perception", perception, "must be model or rendered")
    model_file = None
    if perception == "model":
        from stack.perception.model import PerceptionModel
        from vigil.inprocess import DEFAULT_PERCEPTION_MODEL

        model_file = str(Path(perception_model or DEFAULT_PERCEPTION_MODEL).resolve())
        PerceptionModel.load(model_file)  # a bad file is refused before any episode runs
    out = fresh_run_dir(Path(out).resolve(), uuid.uuid4().hex[:12])  # never mixed with a used one
    (out / "episodes").mkdir(parents=True, exist_ok=True)
    from vigil.system import policy_for

    for task in sorted({str(Path(sc.task).resolve()) for sc in scenarios}):
        if load_task(task).people == 1:  # several people: the online planner, no policy
            policy_for(Path(task), say)  # solved once here, not by every worker at once
    cfg = None if config_path is None else str(Path(config_path).resolve())
    jobs = [
        (k, (sc, str(out / "episodes" / name), cfg, study, perception, model_file, max_steps))
        for k, (sc, name) in enumerate(zip(scenarios, names, strict=True))
    ]
    where = f"Ray ({ray})" if ray else f"{workers} local process(es)"
    say(f"[montecarlo] {what}, perception {perception}, on {where}")
    t0 = time.monotonic()
    results: list[dict[str, Any] | None] = [None] * len(jobs)
    stream = _ray_map(jobs, ray, workers) if ray else _local_map(jobs, workers)
    last_say = -math.inf
    for n, (k, rec) in enumerate(stream, start=1):
        results[k] = rec
        now = time.monotonic()
        if now - last_say >= 1.0 or n == len(jobs) or "error" in rec:
            left = (now - t0) / n * (len(jobs) - n)
            say(f"[montecarlo] {n}/{len(jobs)} {_line(rec)} ({now - t0:.0f} s, "
                f"about {_duration(left)} left)")  # fmt: skip
            last_say = now
    eps = [r for r in results if r is not None]
    record = {
        "task": None if task_path is None else str(task_path),
        "tasks": sorted({e.get("task", "") for e in eps}),
        "seed": seed,
        "study": asdict(study),
        "workers": workers,
        "ray": ray,
        "perception": perception,
        "perception_model": model_file,
        "out": str(out),
        "wall_s": round(time.monotonic() - t0, 1),
        "episodes": eps,
    }
    source = what if task_path is None else f"{Path(task_path).stem}, {what.split(' of ')[0]}"
    record["title"] = f"Monte Carlo: {source}" + (f", seed {seed}" if task_path is not None else "")
    _write_study(out, record)
    sim_s, wall_s = record["summary"]["sim_s"], record["wall_s"]
    say(f"[montecarlo] {sim_s:.0f} s simulated in {wall_s:.0f} s wall")
    say(f"[montecarlo] {out}/montecarlo.md, montecarlo.json, montecarlo.png")
    return record


def _write_study(out: Path, record: dict[str, Any]) -> None:
    """The study's summary, worst episodes, ``montecarlo.json``, ``.md`` and ``.png``."""
    eps = record["episodes"]
    record["summary"] = summary = summarise(eps, record["seed"])
    record["worst"] = [e["episode"] for e in worst_episodes(eps)]
    write_text(out / "montecarlo.json", json.dumps(record, indent=2, sort_keys=True) + "\n")
    text = summary_markdown(summary, record["title"]) + _worst_markdown(eps)
    write_text(out / "montecarlo.md", text)
    plot_study(out / "montecarlo.png", eps, summary, record["title"])


def _episode_task(folder: Path) -> Path:
    """The task file an episode ran (its planner's ``task_file`` in ``params.yaml``)."""
    import yaml

    params = yaml.safe_load(read_text_capped(folder / "params.yaml")) or {}
    return Path(params["planner"]["ros__parameters"]["task_file"])


def rescore_study(out: str | Path, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Score a finished study again with today's metric code: every episode's report
    is written anew from its raw records (``steps.jsonl``, ``trace.jsonl``, the speech
    log; no plots), its ``episode.json`` and the study's summary and files with it. For
    when a metric's definition changed after the study ran; the runs are not repeated.

    Raises:
        ConfigError: ``out`` holds no ``montecarlo.json``.
    """
    from vigil.report import write_report

    out = Path(out)
    try:
        record = json.loads(read_text_capped(out / "montecarlo.json", 256 * 2**20))
    except (OSError, ValueError) as exc:
        raise ConfigError("--rescore", str(out), f"is not a study folder: {exc}") from None
    record.setdefault("title", f"Monte Carlo: {out.name}")
    folders = {}  # episode name -> its folder (random walks: 000, ...; scenarios: their names)
    for f in sorted((out / "episodes").glob("*/episode.json")):
        folders[json.loads(read_text_capped(f)).get("episode")] = f.parent
    t0, last = time.monotonic(), -math.inf
    eps = record["episodes"]
    for n, ep in enumerate(eps, start=1):
        if "error" in ep or ep["episode"] not in folders:
            continue
        folder = folders[ep["episode"]]
        summary = write_report(folder, _episode_task(folder), plots=False, video=False)
        ep.update(metric_fields(summary))
        write_text(folder / "episode.json", json.dumps(ep, sort_keys=True) + "\n")
        if time.monotonic() - last >= 1.0 or n == len(eps):
            say(f"[montecarlo] rescored {n}/{len(eps)}")
            last = time.monotonic()
    record["rescored_s"] = round(time.monotonic() - t0, 1)
    _write_study(out, record)
    say(f"[montecarlo] {out}/montecarlo.md, montecarlo.json, montecarlo.png (rescored)")
    return record


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min"


def _worst_markdown(eps: Sequence[dict[str, Any]]) -> str:
    worst = worst_episodes(eps)
    if not worst:
        return ""
    lines = ["", "Worst episodes (their folders are `episodes/<name>`):", ""]
    for e in worst:
        lines.append(f"- {_line(e)}")
    return "\n".join(lines) + "\n"


def _line(rec: dict[str, Any]) -> str:
    if "error" in rec:
        return f"{rec['episode']}: failed: {rec['error']}"
    d = rec["delays_s"]
    delay = f", delay {max(d):.1f} s" if d else ""
    needless = rec.get("n_needless_trips", 0)
    return (
        f"{rec['episode']} ({rec['title'].split(': ', 1)[-1]}): {rec['guarded']}/{rec['n_visits']} "
        f"visits guarded{delay}, {rec['n_false_trips']} false / {needless} needless trips, "
        f"{rec['sim_s']:.0f} s simulated in {rec['wall_s']:.1f} s"
    )


def load_scenario_folder(folder: str | Path) -> list[Scenario]:
    """Every scenario file (``*.yaml``) of ``folder``, in name order, each named after its
    file; a bad one is refused naming the file and the key, before anything runs."""
    from dataclasses import replace

    from vigil.scenario import load_scenario

    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError("--scenarios", str(folder), "is not a folder")
    files = sorted(folder.glob("*.yaml"))
    if not files:
        raise ConfigError("--scenarios", str(folder), "holds no *.yaml scenario files")
    out = []
    for f in files:
        try:
            out.append(replace(load_scenario(f), name=f.stem))
        except ConfigError as err:
            raise ConfigError(f"{f}: {err.key}", err.value, err.rule) from None
        except (ValueError, OSError) as err:
            raise ConfigError(str(f), f.name, " ".join(str(err).split())) from None
    return out
