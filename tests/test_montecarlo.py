"""vigil montecarlo: random walks, statistics, the study's files, local and Ray workers."""

import json
import math

import numpy as np
import pytest

from stack.cells import ConfigError
from stack.planning.task import load_task
from vigil.cli import build_parser
from vigil.montecarlo import (
    StudyConfig,
    bootstrap_mean,
    episode_scenarios,
    plot_study,
    run_study,
    summarise,
    summary_markdown,
    wilson,
)
from vigil.run import REPO

TASK = REPO / "config" / "task-r1.yaml"


def test_same_seed_same_episodes_and_draws_stay_in_their_ranges():
    study = StudyConfig(p_fault=0.5)
    a = episode_scenarios(TASK, 20, seed=5, study=study)
    assert a == episode_scenarios(TASK, 20, seed=5, study=study)
    assert a != episode_scenarios(TASK, 20, seed=6, study=study)
    # episode k does not depend on how many episodes the study has
    assert episode_scenarios(TASK, 3, seed=5, study=study) == a[:3]
    task = load_task(TASK)
    for sc in a:
        assert sc.robot_cell == task.rest_cell and sc.steps == 0
        assert sc.walk[0].to == "door" and sc.walk[-1].to == "outside"
        targets = sc.walk[1:-2]
        assert 1 <= len(targets) <= 2
        for leg in sc.walk:
            assert 0.4 <= leg.speed_mps <= 1.4
        for leg in targets:
            assert task.grid.cell_at(*leg.to) is not None
        for f in sc.faults:
            assert f.kind in ("camera_off", "lidar_off") and 2.0 <= f.duration_s <= 8.0
    cells = {task.grid.cell_at(*leg.to) for sc in a for leg in sc.walk[1:-2]}
    assert 1 in cells and len(cells) > 2  # restricted and other cells are both drawn
    assert 0 < sum(bool(sc.faults) for sc in a) < 20


def test_wilson_interval_matches_known_values():
    lo, hi = wilson(5, 10)
    assert (round(lo, 3), round(hi, 3)) == (0.237, 0.763)
    lo, hi = wilson(0, 10)
    assert lo == 0.0 and round(hi, 3) == 0.278
    assert wilson(10, 10)[1] == pytest.approx(1.0)
    assert wilson(0, 0) == (None, None)


def test_bootstrap_resamples_whole_episodes():
    mean, lo, hi = bootstrap_mean([[1.0, 1.0, 1.0], [5.0]], seed=0)
    assert mean == 2.0
    # resampling episodes: the mean lies between the two episodes' means
    assert 1.0 <= lo < mean < hi <= 5.0
    assert bootstrap_mean([[], []]) == (None, None, None)
    assert bootstrap_mean([[2.0], [2.0]])[1:] == (2.0, 2.0)


def _episode(k, visits, guarded, delays, trips, fault=False):
    return {
        "episode": f"mc-{k:03d}", "title": "t", "seed": k, "steps": 10,
        "faults": [{"kind": "camera_off"}] if fault else [],
        "n_visits": visits, "guarded": guarded, "abandoned": 0, "delays_s": delays,
        "n_false_trips": trips, "timely_warnings": guarded, "late_warnings": 0,
        "miss_rate": 0.0, "sim_s": 30.0, "wall_s": 1.0,
    }  # fmt: skip


def test_summary_counts_and_intervals(tmp_path):
    eps = [
        _episode(0, 2, 2, [3.0, 5.0], 0),
        _episode(1, 1, 0, [], 1, fault=True),
        _episode(2, 0, 0, [], 0),
        {"episode": "mc-003", "title": "t", "seed": 3, "faults": [], "error": "boom"},
    ]
    s = summarise(eps)
    assert (s["episodes"], s["failed_episodes"], s["visits"], s["guarded"]) == (4, 1, 3, 2)
    assert s["guarded_rate"] == pytest.approx(2 / 3, abs=1e-3)
    lo, hi = s["guarded_rate_ci95"]
    assert lo < 2 / 3 < hi
    assert s["mean_delay_s"] == 4.0 and s["max_delay_s"] == 5.0
    assert s["false_trips"] == 1 and s["episodes_with_false_trip"] == 1
    assert s["false_trips_per_episode"] == pytest.approx(1 / 3, abs=1e-3)
    assert s["episodes_with_fault"] == 1
    assert s == summarise(eps)  # deterministic, bootstrap included
    md = summary_markdown(s, "study")
    assert "| guarded-visit rate | 67 % |" in md and "2 of 3 visits" in md
    png = plot_study(tmp_path / "s.png", eps, s, "study")
    assert png.stat().st_size > 1000
    assert "one_guard" not in s and "one guard" not in md  # one person a walk


def test_several_people_are_also_scored_against_what_one_guard_could_guard():
    eps = [
        {**_episode(0, 2, 1, [1.0], 0), "reachable": 2, "guarded_reachable": 1, "one_guard": 1},
        {**_episode(1, 2, 1, [2.0], 0), "reachable": 2, "guarded_reachable": 1, "one_guard": 2},
    ]
    s = summarise(eps)
    assert (s["reachable"], s["guarded_reachable"], s["one_guard"]) == (4, 2, 3)
    assert s["guarded_reachable_rate"] == 0.5
    assert s["guarded_one_guard_rate"] == pytest.approx(2 / 3, abs=1e-3)
    md = summary_markdown(s, "study")
    assert "| of what one guard could guard | 67 % |" in md and "of the 3 reachable" in md


def test_bad_study_settings_are_named(tmp_path):
    with pytest.raises(ConfigError, match="speed_mps"):
        StudyConfig(speed_mps=(0.4, 2.5))
    with pytest.raises(ConfigError, match="p_fault"):
        StudyConfig(p_fault=1.5)
    with pytest.raises(ConfigError, match="targets"):
        StudyConfig(targets=(2, 1))
    with pytest.raises(ConfigError, match="pause_s"):
        StudyConfig(pause_s=(math.nan, 1.0))
    with pytest.raises(ConfigError, match="--episodes"):
        run_study(TASK, 0, tmp_path)
    with pytest.raises(ConfigError, match="TASK"):
        run_study(tmp_path / "missing.yaml", 1, tmp_path)


def test_cli_parses_the_montecarlo_command():
    args = build_parser().parse_args(
        ["montecarlo", str(TASK), "--episodes", "3", "--workers", "2", "--ray", "local"]
    )
    assert (args.episodes, args.workers, args.ray) == (3, 2, "local")
    assert args.func.__name__ == "cmd_montecarlo"


def _strip(record):
    return [{k: v for k, v in e.items() if k != "wall_s"} for e in record["episodes"]]


def _timeless(summary):
    return {k: v for k, v in summary.items() if k != "wall_s_per_episode"}


SHORT = StudyConfig(max_sim_s=4.0, p_fault=0.5)


@pytest.mark.slow
def test_same_seed_same_results_whatever_the_workers(tmp_path):
    a = run_study(TASK, 2, tmp_path / "a", seed=3, workers=2, study=SHORT, say=lambda _s: None)
    b = run_study(TASK, 2, tmp_path / "b", seed=3, workers=1, study=SHORT, say=lambda _s: None)
    assert _strip(a) == _strip(b) and _timeless(a["summary"]) == _timeless(b["summary"])
    for k in range(2):
        for name in ("steps.jsonl", "trace.jsonl"):
            fa = tmp_path / "a" / "episodes" / f"{k:03d}" / name
            assert fa.read_text() == (tmp_path / "b" / "episodes" / f"{k:03d}" / name).read_text()
    saved = json.loads((tmp_path / "a" / "montecarlo.json").read_text())
    assert saved["summary"] == a["summary"] and (tmp_path / "a" / "montecarlo.png").exists()
    assert a["summary"]["sim_s"] == pytest.approx(8.0, abs=0.1)


@pytest.mark.slow
def test_a_study_into_a_used_folder_goes_beside_it_and_a_foreign_folder_is_refused(tmp_path):
    """vigil run's folder rule: a second study with the same --out goes to <out>-2 and
    leaves the first's files as they were (before, its episodes appended to the first's
    speech logs); a non-empty folder vigil did not make is refused before anything runs."""
    kw = dict(seed=3, workers=1, study=SHORT, say=lambda _s: None)
    first = run_study(TASK, 1, tmp_path / "s", **kw)
    files = {p: p.read_bytes() for p in (tmp_path / "s").rglob("*") if p.is_file()}
    again = run_study(TASK, 1, tmp_path / "s", **kw)
    assert first["out"] == str(tmp_path / "s") and again["out"] == str(tmp_path / "s-2")
    assert {p: p.read_bytes() for p in (tmp_path / "s").rglob("*") if p.is_file()} == files
    assert _strip(first) == _strip(again)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(ConfigError, match="non-empty folder that vigil did not make"):
        run_study(TASK, 1, mine, **kw)
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]


@pytest.mark.slow
def test_a_local_ray_instance_gives_the_same_results(tmp_path):
    pytest.importorskip("ray")  # `make test` installs it (.[dev,ray]): skipped only without
    from tests.test_perception_model import truth_model

    model = truth_model().save(tmp_path / "perception-model.yaml")  # not the shipped fit
    kw = dict(seed=9, workers=2, study=SHORT, say=lambda _s: None, perception_model=model)
    local = run_study(TASK, 4, tmp_path / "l", **kw)
    ray = run_study(TASK, 4, tmp_path / "r", ray="local", **kw)
    assert not [e["error"] for e in ray["episodes"] if "error" in e]
    assert _strip(ray) == _strip(local)
    assert _timeless(ray["summary"]) == _timeless(local["summary"])
    assert ray["summary"]["sim_s"] == pytest.approx(16.0, abs=0.2)
    assert (ray["ray"], local["ray"]) == ("local", None) and np.isfinite(ray["wall_s"])


def test_the_walks_file_draws_every_behaviour_as_it_says():
    from vigil.walks import DEFAULT_WALKS, load_walks

    study = load_walks(DEFAULT_WALKS)
    task = load_task(TASK)
    grid, restricted = task.grid, set(task.restricted_cells)
    eps = episode_scenarios(TASK, 200, seed=11, study=study)
    assert eps == episode_scenarios(TASK, 200, seed=11, study=study)
    seen = set()
    for sc in eps:
        kind = sc.title.split(": ", 1)[1].replace("runner ", "").replace("slow ", "").split()[0]
        seen.add(kind)
        targets = [grid.cell_at(*leg.to) for leg in sc.walk[1:-2]]
        assert None not in targets
        if kind == "decoy":  # stops by a restricted cell and turns away: never inside
            assert not restricted & set(targets)
            x0, y0, x1, y1 = grid.bounds(task.restricted_cells[0])
            bx, by = sc.walk[1].to
            gap = math.hypot(max(x0 - bx, 0, bx - x1), max(y0 - by, 0, by - y1))
            assert gap == pytest.approx(study.border_gap_m, abs=1e-6)
        if kind == "hesitate":
            assert targets[0] not in restricted and targets[1] in restricted
        if kind in ("direct", "wander", "two_visits", "hesitate"):
            assert targets[-1] in restricted
        if kind == "pass_by":
            assert not restricted & set(targets)
        speeds = [leg.speed_mps for leg in sc.walk]
        if sc.title.split(": ", 1)[1].startswith("runner"):
            assert min(speeds) >= 1.6 and max(speeds) <= 2.0
        elif sc.title.split(": ", 1)[1].startswith("slow"):
            assert max(speeds) <= 0.4
        else:
            assert 0.4 <= min(speeds) and max(speeds) <= 1.4
    assert seen == {"direct", "wander", "hesitate", "two_visits", "decoy", "pass_by"}


def test_a_bad_walks_file_is_refused_naming_the_file_and_key(tmp_path):
    from vigil.walks import load_walks

    cases = {
        "speed_mps: [0.4, 3.0]\n": "speed_mps",
        "behaviours: {direct: 1, sprint: 1}\n": "behaviours.sprint",
        "behaviours: {direct: -1}\n": "behaviours.direct",
        "pause_s: 5\n": "pause_s",
        "paws_s: [1, 2]\n": "paws_s",
        "runner_share: 0.7\nslow_share: 0.6\n": "runner_share",
        "max_sim_s: .inf\n": "max_sim_s",
        "- a list\n": "mapping",
    }
    for k, (text, key) in enumerate(cases.items()):
        f = tmp_path / f"w{k}.yaml"
        f.write_text(text)
        with pytest.raises(ConfigError, match=key) as info:
            load_walks(f)
        assert str(f) in str(info.value)


def test_a_scenario_folder_names_episodes_after_files_and_refuses_a_bad_file(tmp_path):
    from vigil.montecarlo import load_scenario_folder

    guard = REPO / "scenarios" / "guard"
    scs = load_scenario_folder(guard)
    assert [sc.name for sc in scs] == sorted(f.stem for f in guard.glob("*.yaml"))
    text = (guard / "border-1.yaml").read_text().replace("../../config", str(REPO / "config"))
    (tmp_path / "a.yaml").write_text(text)
    (tmp_path / "b.yaml").write_text(text.replace("seed: 11", "seed: -4"))
    with pytest.raises(ConfigError, match="b.yaml"):
        load_scenario_folder(tmp_path)
    with pytest.raises(ConfigError, match="no"):
        load_scenario_folder(tmp_path / "a.yaml")


def test_worst_episodes_put_failures_and_missed_visits_first():
    from vigil.montecarlo import worst_episodes

    def ep(name, **kw):
        base = {"episode": name, "reachable": 1, "guarded_reachable": 1, "n_false_trips": 0,
                "n_needless_trips": 0, "late_warnings": 0, "delays_s": [1.0]}  # fmt: skip
        return {**base, **kw}

    eps = [ep("fine"), ep("slow", delays_s=[7.0]), ep("missed", guarded_reachable=0),
           {"episode": "broken", "error": "x"}, ep("trip", n_needless_trips=1)]  # fmt: skip
    assert [e["episode"] for e in worst_episodes(eps, 4)] == ["broken", "missed", "trip", "slow"]


def test_two_studies_of_the_same_walks_are_compared_visit_by_visit():
    from vigil.study_stats import compare_studies, comparison_markdown

    def ep(name, guarded, seed=1):
        visits = [{"cell": 1, "person_arrival_t": 4.0 + k, "guarded": g} for k, g in
                  enumerate(guarded)]  # fmt: skip
        return {"episode": name, "seed": seed, "visits": visits, "n_visits": len(visits),
                "guarded": sum(guarded), "delays_s": [], "n_false_trips": 0, "abandoned": 0,
                "timely_warnings": 0, "late_warnings": 0, "faults": []}  # fmt: skip

    a = [ep("000", [True, False]), ep("001", [True])]
    b = [ep("000", [True, True]), ep("001", [True])]
    ra = {"episodes": a, "summary": summarise(a)}
    rb = {"episodes": b, "summary": summarise(b)}
    c = compare_studies(ra, rb, ("rendered", "model"))
    assert (c["visits_matched"], c["guarded_in_both"], c["guarded_only_model"]) == (3, 2, 1)
    assert c["agreement"] == round(2 / 3, 3) and c["differing_visits"] == ["000 cell 1 at 5.0 s"]
    assert "agrees on 67 % of visits" in comparison_markdown(c)
    with pytest.raises(ValueError, match="same episodes"):
        compare_studies(ra, {"episodes": [ep("000", [True], seed=2), b[1]], "summary": {}})


def test_a_bad_perception_model_or_mode_is_refused_before_anything_runs(tmp_path):
    bad = tmp_path / "model.yaml"
    bad.write_text("format: vigil-perception-model/1\nfeatures: [bias]\n")
    with pytest.raises(ConfigError, match="model.yaml"):
        run_study(TASK, 1, tmp_path / "out", perception_model=bad, say=lambda _s: None)
    with pytest.raises(ConfigError, match="--perception"):
        run_study(TASK, 1, tmp_path / "out", perception="drawn", say=lambda _s: None)
    assert not (tmp_path / "out").exists()


def test_the_shipped_perception_model_loads_and_says_where_it_came_from():
    from stack.perception.model import PerceptionModel
    from vigil.inprocess import DEFAULT_PERCEPTION_MODEL

    m = PerceptionModel.load(DEFAULT_PERCEPTION_MODEL)
    assert m.meta["date"] and m.meta["command"].startswith("vigil fit-perception")
    assert m.meta["frames"] > 1000 and 0.0 < m.error_rho < 1.0


@pytest.mark.slow
def test_rescoring_a_study_gives_its_figures_again_and_follows_a_changed_metric(tmp_path):
    """`vigil montecarlo --rescore DIR`: the episodes' reports are written again from
    their raw records; unchanged metric code gives the same summary, and an episode
    whose record was altered (as an older metric would have left it) is corrected."""
    from vigil.montecarlo import rescore_study

    out = tmp_path / "s"
    a = run_study(TASK, 2, out, seed=3, workers=1, study=SHORT, say=lambda _s: None)
    saved = json.loads((out / "montecarlo.json").read_text())
    saved["episodes"][0]["late_warnings"] += 7  # what a different metric had said
    (out / "montecarlo.json").write_text(json.dumps(saved))
    again = rescore_study(out, say=lambda _s: None)
    assert _timeless(again["summary"]) == _timeless(a["summary"])
    assert again["episodes"][0]["late_warnings"] == a["episodes"][0]["late_warnings"]
    record = json.loads((out / "episodes" / "000" / "episode.json").read_text())
    assert record["late_warnings"] == a["episodes"][0]["late_warnings"]
    with pytest.raises(ConfigError, match="not a study folder"):
        rescore_study(tmp_path / "nothing", say=lambda _s: None)


def test_a_two_person_task_draws_a_walk_per_person_the_second_setting_off_later():
    from vigil.walks import DEFAULT_WALKS, load_walks

    study = load_walks(DEFAULT_WALKS)
    task2 = REPO / "config" / "task-r2-n2.yaml"
    eps = episode_scenarios(task2, 30, seed=3, study=study)
    assert eps == episode_scenarios(task2, 30, seed=3, study=study)
    grid = load_task(task2).grid
    for sc in eps:
        assert len(sc.walkers) == 2 and sc.title.count(" | ") == 1
        second = sc.others[0]
        # waits outside, then walks in like anybody: door, cells of the grid, out
        wait = second.walk[0]
        assert wait.to == "outside" and 0.0 <= wait.pause_s <= 10.0
        assert second.walk[1].to == "door" and second.walk[-1].to == "outside"
        assert all(grid.cell_at(*leg.to) is not None for leg in second.walk[2:-2])
    assert len({sc.others[0].walk[0].pause_s for sc in eps}) > 20  # drawn, not fixed
    # one walker by the walks file's say, and a one-person task keeps its walks
    one = episode_scenarios(task2, 5, seed=3, study=load_walks(DEFAULT_WALKS, people=1))
    assert all(not sc.others for sc in one)
    r1 = episode_scenarios(TASK, 5, seed=3, study=study)
    assert all(not sc.others for sc in r1)
    with pytest.raises(ConfigError, match="people"):
        StudyConfig(people=9)


def test_a_several_people_episode_counts_every_walkers_visits():
    from vigil.montecarlo import metric_fields

    def visit(cell, guarded, delay):
        return {"cell": cell, "person_arrival_t": 3.0, "person_duration_s": 4.0,
                "guarded": guarded, "reachable": True, "robot_first": False,
                "delay_s": delay, "warning_lead_s": None}  # fmt: skip

    first = {"n_visits": 1, "guarded": 1, "reachable": 1, "guarded_reachable": 1,
             "robot_first": 0, "abandoned": 0, "visits": [visit(1, True, 1.0)],
             "n_false_trips": 0, "n_needless_trips": 0, "timely_warnings": 1,
             "late_warnings": 0, "miss_rate": 0.0}  # fmt: skip
    summary = {"metrics": first}
    assert metric_fields(summary)["n_visits"] == 1
    summary["people"] = {
        "per_person": [
            {"person": 1, "visits": [visit(1, True, 1.0)], "abandoned": 0},
            {"person": 2, "visits": [visit(12, False, None)], "abandoned": 1},
        ],
        "n_visits": 2, "guarded": 1, "reachable": 2, "guarded_reachable": 1,
        "robot_first": 0, "n_false_trips": 0, "n_needless_trips": 1,
        "timely_warnings": 2, "late_warnings": 0, "approach_warnings": 1,
    }  # fmt: skip
    m = metric_fields(summary)
    assert (m["n_visits"], m["guarded"], m["reachable"], m["abandoned"]) == (2, 1, 2, 1)
    assert [(v["person"], v["cell"]) for v in m["visits"]] == [(1, 1), (2, 12)]
    assert m["delays_s"] == [1.0] and m["n_needless_trips"] == 1
    assert (m["timely_warnings"], m["approach_warnings"]) == (2, 1)  # every walker's


@pytest.mark.slow
def test_a_study_of_the_two_person_task_runs_and_counts_each_walkers_visits(tmp_path):
    """Two walkers an episode, the online planner (no policy to solve first), the
    visits of both in the study's records."""
    from vigil.walks import DEFAULT_WALKS, load_walks

    study = load_walks(DEFAULT_WALKS, max_sim_s=40.0)
    task2 = REPO / "config" / "task-r2-n2.yaml"
    r = run_study(task2, 3, tmp_path / "n2", seed=4, study=study, say=lambda _s: None)
    assert r["summary"]["failed_episodes"] == 0
    visits = [v for ep in r["episodes"] for v in ep["visits"]]
    assert visits and all(v["person"] in (1, 2) for v in visits)
    steps = (tmp_path / "n2" / "episodes" / "000" / "steps.jsonl").read_text().splitlines()
    assert all(len(json.loads(x)["observation"]["people"]) == 2 for x in steps)
