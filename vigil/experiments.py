"""``vigil experiments DIR --out OUT``: run a set of scenarios and tabulate the
guarding metrics (docs/EXPERIMENTS.md, "Metrics") per scenario and in total.

Each ``DIR/*.yaml`` scenario runs through the whole ROS stack in the twin
(:func:`vigil.run.run_scenario`) into ``OUT/<file stem>/``, one after the other
(each takes both cores for about three minutes). The progress is the runs' own: one
line per decision step, prefixed with the scenario. Then:

- ``OUT/experiments.md``: the metric table (one row per scenario and the totals);
- ``OUT/experiments.json``: per scenario its seed, task, wall time, load and metrics;
- ``OUT/experiments.png``: the set at a glance (:func:`vigil.report.figures.plot_set`);
- with ``docs``: the table and the figure in a marked section of that Markdown file
  (``<!-- experiments:LABEL -->`` ... ``<!-- /experiments:LABEL -->``), replaced on
  every run, appended at the end the first time.

``report_only`` recomputes the reports of run folders already in ``OUT`` (the report
works from the recorded data alone) instead of running the scenarios again.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from stack.cells import ConfigError
from stack.config import read_bytes_capped, read_text_capped, write_bytes, write_text
from vigil.report import write_report
from vigil.report.metrics import set_totals
from vigil.report.tables import set_markdown
from vigil.scenario import load_scenario

STOPPING_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")  # vigil.ending kinds: they stop the set
Runner = Callable[..., dict]


def scenario_files(source: str | Path) -> list[Path]:
    """The scenario files of a folder (``*.yaml``, sorted) or the one file given.

    Raises:
        ConfigError: no such file or folder, or a folder without scenarios.
    """
    source = Path(source)
    if source.is_file():
        return [source]
    if not source.is_dir():
        raise ConfigError("scenarios", str(source), "no such file or folder")
    files = sorted(source.glob("*.yaml"))
    if not files:
        raise ConfigError("scenarios", str(source), "holds no *.yaml scenario")
    return files


def _load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "-"


def run_set(
    source: str | Path,
    out: str | Path,
    *,
    config: str | Path | None = None,
    seed: int | None = None,
    report_only: bool = False,
    only: Sequence[str] = (),
    runner: Runner | None = None,
    say: Callable[[str], None] = print,
    realtime: bool = False,
) -> dict[str, Any]:
    """Run (or re-report) every scenario; write the set's table, JSON and figure.

    Args:
        source: a folder of scenario files, or one file.
        out: the set's folder; each scenario's run folder is ``out/<stem>``.
        config: the deployment file (default ``config/twin.yaml``).
        seed: overrides every scenario's seed.
        report_only: recompute the reports of existing run folders, run nothing.
        only: run these file stems only (default: all).
        runner: :func:`vigil.run.run_scenario` or a stand-in with its signature.
        realtime: each run with the twin on the wall clock (``vigil run --realtime``);
            each entry then carries the run's ``realtime`` stats.

    Returns:
        The set's record (what ``experiments.json`` holds).

    Raises:
        ConfigError: a bad scenario folder or file (before anything runs).
    """
    files = scenario_files(source)
    if only:
        unknown = sorted(set(only) - {f.stem for f in files})
        if unknown:
            raise ConfigError("--only", unknown, f"not among {[f.stem for f in files]}")
        files = [f for f in files if f.stem in only]
    scenarios = [load_scenario(f) for f in files]  # all checked before the first run
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if runner is None:
        from vigil.run import run_scenario as runner
    entries: list[dict[str, Any]] = []
    for k, (path, sc) in enumerate(zip(files, scenarios, strict=True), start=1):
        if seed is not None:
            sc = replace(sc, seed=seed)
        run_dir = out / path.stem
        entry: dict[str, Any] = {
            "scenario": path.stem,
            "name": sc.name,
            "title": sc.title,
            "file": str(path),
            "task": sc.task.name,
            "seed": sc.seed,
            "robot_cell": sc.robot_cell,
            "steps": sc.steps,
            "load_before": _load(),
        }
        say(f"[experiments] {k}/{len(files)} {path.stem}: {sc.title} (seed {sc.seed})")
        t0 = time.monotonic()
        error = ""
        summary: dict | None = None
        try:
            if report_only:
                if not (run_dir / "steps.jsonl").exists():
                    raise ConfigError("--report-only", str(run_dir), "holds no run")
                summary = write_report(run_dir, sc.task, say=say)
            else:

                def prefixed(line: str, name: str = path.stem) -> None:
                    if not line.startswith("[launch] started"):
                        say(f"[{name}] {line}")

                extra = {"realtime": True} if realtime else {}
                summary = runner(path, config, run_dir, sc.seed, say=prefixed, **extra)
        except Exception as exc:  # noqa: BLE001 - one failed scenario must not stop the set
            if getattr(getattr(exc, "ending", None), "kind", "") in STOPPING_SIGNALS:
                raise  # Ctrl-C or SIGTERM during a run stops the set, not only the run
            error = f"{type(exc).__name__}: {exc}"
            say(f"[experiments] {path.stem} failed: {error}")
            if (run_dir / "summary.json").exists():
                summary = json.loads(read_text_capped(run_dir / "summary.json"))
        entry["wall_s"] = round(time.monotonic() - t0, 1)
        entry["load_after"] = _load()
        if report_only:  # the run's own figures, not the report's
            entry["wall_s"] = _run_wall_s(run_dir)
            entry["load_before"] = entry["load_after"] = "-"
        entry["error"] = error
        entry["metrics"] = _brief(summary.get("metrics")) if summary else None
        if summary and "realtime" in summary:  # how well the real-time twin kept up
            entry["realtime"] = summary["realtime"]
        entries.append(entry)
        write_set(out, entries, say=None)
    record = write_set(out, entries, say=say)
    return record


def _run_wall_s(run_dir: Path) -> float | None:
    try:
        return float(json.loads(read_text_capped(run_dir / "run.json"))["wall_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _brief(metrics: dict | None) -> dict | None:
    if metrics is None:
        return None
    return {k: v for k, v in metrics.items() if k not in ("warnings",)}


def write_set(
    out: str | Path, entries: Sequence[dict[str, Any]], say: Callable[[str], None] | None = print
) -> dict[str, Any]:
    """``experiments.md``, ``experiments.json`` and ``experiments.png`` of the set."""
    from vigil.report.figures import plot_set

    out = Path(out)
    rows = [(e["scenario"], e["metrics"], e["error"]) for e in entries]
    ok = [e["metrics"] for e in entries if e["metrics"] is not None]
    record = {"scenarios": list(entries), "totals": set_totals(ok)}
    write_text(out / "experiments.json", json.dumps(record, indent=2, sort_keys=True) + "\n")
    plot_set(
        out / "experiments.png",
        [(n, m) for n, m, _ in rows],
        title=f"{len(entries)} scenarios from {out}",
    )
    write_text(out / "experiments.md", set_section(entries, "experiments.png"))
    if say is not None:
        say(f"[experiments] wrote {out}/experiments.md, experiments.json, experiments.png")
    return record


def set_section(entries: Sequence[dict[str, Any]], figure: str) -> str:
    """The table, the runs' seeds, wall times and load, and the figure, as Markdown."""
    rows = [(e["scenario"], e["metrics"], e["error"]) for e in entries]
    lines = [set_markdown(rows), ""]
    runs = ", ".join(
        f"{e['scenario']} seed {e['seed']} "
        + ("-" if e["wall_s"] is None else f"{e['wall_s']:.0f} s")
        + f" (load {e['load_before']})"
        for e in entries
    )
    lines.append(f"Runs (seed, wall time, load average 1/5/15 min before the run): {runs}.")
    lines.append("")
    lines.append(f"![the scenario set]({figure})")
    return "\n".join(lines) + "\n"


def marker(label: str) -> tuple[str, str]:
    """The begin and end comments of a marked section."""
    return f"<!-- experiments:{label} -->", f"<!-- /experiments:{label} -->"


def update_marked_section(text: str, label: str, body: str, heading: str = "") -> str:
    """``text`` with the section marked ``label`` replaced by ``body`` (appended at the
    end, under ``heading``, when there is no such section yet).

    Raises:
        ValueError: a begin marker without its end marker, or markers out of order.
    """
    begin, end = marker(label)
    b, e = text.find(begin), text.find(end)
    if b < 0 and e < 0:
        head = f"\n{heading}\n\n" if heading else "\n"
        return text.rstrip("\n") + "\n" + head + f"{begin}\n{body.rstrip()}\n{end}\n"
    if b < 0 or e < 0 or e < b:
        raise ValueError(f"the section markers {begin!r} / {end!r} are broken in the file")
    return text[: b + len(begin)] + "\n" + body.rstrip() + "\n" + text[e:]


def write_docs(doc: str | Path, out: str | Path, label: str, heading: str = "") -> Path:
    """Put the set's table and figure (``out/experiments.json``, ``.png``) into the
    marked section ``label`` of the Markdown file ``doc``; the figure is copied beside
    it as ``experiments/<label>.png``.

    Raises:
        ConfigError: ``doc`` does not exist or ``out`` holds no set.
    """
    doc, out = Path(doc), Path(out)
    if not doc.exists():
        raise ConfigError("--docs", str(doc), "no such file")
    if not (out / "experiments.json").exists():
        raise ConfigError("--out", str(out), "holds no experiments.json")
    entries = json.loads(read_text_capped(out / "experiments.json"))["scenarios"]
    figure = doc.parent / "experiments" / f"{label}.png"
    figure.parent.mkdir(parents=True, exist_ok=True)
    write_bytes(figure, read_bytes_capped(out / "experiments.png"))  # never through a link
    body = set_section(entries, figure.relative_to(doc.parent).as_posix())
    write_text(doc, update_marked_section(read_text_capped(doc), label, body, heading))
    return doc
