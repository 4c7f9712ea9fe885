"""Inputs cannot destroy data (issue 13): ``vigil run --out`` never deletes what vigil
did not create, and the CLI answers a bad path with one line and exit code 2."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from stack.cells import ConfigError
from vigil.run import RUN_MARK, fresh_run_dir

REPO = Path(__file__).resolve().parents[1]


def test_a_foreign_folder_is_refused_and_left_untouched(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    (home / "thesis.tex").write_text("years of work")
    # what used to make it a "run folder": a params.yaml or summary.json anywhere
    (home / "params.yaml").write_text("mine: true\n")
    (home / "summary.json").write_text("{}")
    with pytest.raises(ConfigError, match="did not make"):
        fresh_run_dir(home, "id")
    assert sorted(p.name for p in home.iterdir()) == ["params.yaml", "summary.json", "thesis.tex"]


def test_a_file_is_refused(tmp_path):
    f = tmp_path / "notes.txt"
    f.write_text("x")
    with pytest.raises(ConfigError, match="is a file"):
        fresh_run_dir(f, "id")
    assert f.read_text() == "x"


def test_an_earlier_run_is_kept_and_the_new_one_is_numbered(tmp_path):
    first = fresh_run_dir(tmp_path / "run", "a")
    assert first == tmp_path / "run"
    (first / "summary.json").write_text('{"steps": 20}')
    (first / "my-notes.md").write_text("added by the user")
    second = fresh_run_dir(tmp_path / "run", "b")
    third = fresh_run_dir(tmp_path / "run", "c")
    assert (second.name, third.name) == ("run-2", "run-3")
    assert (first / "my-notes.md").read_text() == "added by the user"
    assert json.loads((first / RUN_MARK).read_text())["run_id"] == "a"
    assert json.loads((third / RUN_MARK).read_text())["run_id"] == "c"


def test_an_empty_folder_is_used_as_it_is(tmp_path):
    (tmp_path / "empty").mkdir()
    assert fresh_run_dir(tmp_path / "empty", "x") == tmp_path / "empty"


def test_vigil_run_refuses_a_foreign_out_folder_with_one_line(tmp_path):
    (tmp_path / "params.yaml").write_text("precious: true\n")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "vigil.cli",
            "run",
            str(REPO / "scenarios" / "5.1.1.yaml"),
            "--out",
            str(tmp_path),
            "--observations",
            "table",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "did not make" in proc.stderr
    assert (tmp_path / "params.yaml").read_text() == "precious: true\n"


@pytest.mark.parametrize(
    "args",
    [
        ["calibrate", "--points", "{dir}", "-o", "{dir}/cal.yaml"],
        ["calibrate", "--points", "{dir}/bad.yaml", "-o", "{dir}/cal.yaml"],
        ["calibrate", "--twin", "{dir}", "-o", "{dir}/cal.yaml"],
        ["run", "{dir}"],
        ["run", "{scenario}", "--config", "{dir}"],
        ["launch", "{dir}"],
    ],
)
def test_cli_gives_one_line_errors_with_exit_code_2(tmp_path, args):
    (tmp_path / "bad.yaml").write_text("points: [[1, 2], {pixel: [nan, 1]}]\n")
    scenario = str(REPO / "scenarios" / "5.1.1.yaml")
    argv = [a.format(dir=tmp_path, scenario=scenario) for a in args]
    proc = subprocess.run(
        [sys.executable, "-m", "vigil.cli", *argv], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("vigil "), proc.stderr


def test_a_kill_fault_naming_an_unknown_node_is_refused():
    import yaml

    from vigil.scenario import KILLABLE, parse_scenario

    data = yaml.safe_load((REPO / "scenarios" / "5.1.2.yaml").read_text())
    data["task"] = str(REPO / "config" / "task-r1.yaml")
    data["faults"] = [{"kind": "kill", "node": "plannr", "after_step": 3}]
    with pytest.raises(ConfigError) as err:
        parse_scenario(data, None)
    assert err.value.key == "faults[0].node" and "plannr" in str(err.value)
    for node in KILLABLE:
        data["faults"] = [{"kind": "kill", "node": node, "after_step": 3}]
        assert parse_scenario(data, None).faults[0].node == node


@pytest.mark.parametrize("mode", ["w", "wb", "a", "ab"])
def test_a_file_the_program_writes_is_never_written_through_a_link(tmp_path, mode):
    """Issue 23: every file vigil creates or truncates is opened without following a
    symbolic link (stack.config.open_write, used by every writer: run folders, reports,
    policies, maps, logs). A link where a file is to be written, pointing at a user's
    file, is refused naming it, and the user's file is unchanged."""
    from stack.config import open_write, write_bytes, write_text

    precious = tmp_path / "thesis.tex"
    precious.write_text("years of work")
    link = tmp_path / "summary.json"
    link.symlink_to(precious)
    with pytest.raises(OSError, match="symbolic link"):
        open_write(link, mode)
    with pytest.raises(OSError, match="symbolic link"):
        write_text(link, "{}")
    with pytest.raises(OSError, match="symbolic link"):
        write_bytes(link, b"{}")
    assert precious.read_text() == "years of work"
    # a plain path: created, truncated, appended as asked
    plain = tmp_path / "log.txt"
    with open_write(plain, mode) as f:
        f.write(b"one\n" if "b" in mode else "one\n")
    with open_write(plain, mode) as f:
        f.write(b"two\n" if "b" in mode else "two\n")
    assert plain.read_text() == ("one\ntwo\n" if mode.startswith("a") else "two\n")
    with pytest.raises(ValueError, match="mode"):
        open_write(plain, "r+")


def test_the_report_is_not_written_through_a_link_in_the_run_folder(tmp_path):
    """The writers use it: a summary.json link planted in a run folder is refused."""
    from vigil.report.html import write_index

    precious = tmp_path / "notes.txt"
    precious.write_text("mine")
    (tmp_path / "index.html").symlink_to(precious)
    with pytest.raises(OSError, match="symbolic link"):
        write_index(tmp_path, "run", {})
    assert precious.read_text() == "mine"
