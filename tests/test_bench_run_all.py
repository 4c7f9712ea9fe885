"""bench/run_all.py (`make bench`): every benchmark of bench/ is either run or listed as
skipped with its command, and the summary says where each one's figures went."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TOOLS = {"run_all.py", "gen_rocksample.py", "factored_policy.py"}  # not benchmarks


def _run_all():
    spec = importlib.util.spec_from_file_location("bench_run_all", REPO / "bench" / "run_all.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_every_bench_script_is_run_or_listed_as_skipped():
    ra = _run_all()
    run = {b.script for b in ra.QUICK}
    skipped = {cmd.split()[0].removeprefix("bench/") for cmd, _, _ in ra.LONG}
    scripts = {p.name for p in (REPO / "bench").glob("*.py")} - TOOLS
    assert not run & skipped
    assert scripts == run | skipped, f"not in run_all.py: {sorted(scripts - run - skipped)}"
    assert all((REPO / "bench" / s).is_file() for s in run | skipped)


def test_the_summary_names_each_output_and_the_skipped_commands(tmp_path):
    ra = _run_all()
    out = tmp_path / "bench_nav.txt"
    outcomes = [
        ra.Outcome(ra.QUICK[1], "ok", 2.5, out),
        ra.Outcome(ra.QUICK[0], "skipped: no files", 0.0, None),
    ]
    text = ra.summary(outcomes, "2026-11-26 00:00:00 UTC", 3.0)
    assert str(out) in text and "| ok | 2.5 |" in text and "skipped: no files" in text
    for cmd, _, _ in ra.LONG:
        assert f"`{cmd}`" in text
