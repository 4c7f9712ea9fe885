"""docs/HARDWARE.md's bring-up checklist runs as written: every ``vigil ...`` line of its
shell blocks is accepted by vigil's own argument parser, and every file a command names
exists in the repository, is written by an earlier step of the checklist, or is one of
the placeholders the doc declares."""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest
import yaml

from vigil.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "HARDWARE.md"
FILE_SUFFIXES = (".yaml", ".yml", ".npz", ".pomdp", ".pomdpx", ".policy")
CHECKLIST = {"calibrate", "launch", "status", "arm", "disarm"}  # what the bring-up needs


def shell_lines(text: str) -> list[list[str]]:
    """The words of every command line in the ```sh blocks (comments dropped)."""
    blocks = re.findall(r"^ *```sh\n(.*?)^ *```", text, re.M | re.S)
    lines = [shlex.split(line, comments=True) for b in blocks for line in b.splitlines()]
    return [w for w in lines if w]


def placeholders(text: str) -> set[str]:
    """The names in the doc's ``Placeholders:`` sentence (not those in its brackets)."""
    found = re.search(r"Placeholders:(.*?)\.\s", text, re.S)
    assert found, "docs/HARDWARE.md declares no placeholders"
    return set(re.findall(r"`([^`]+)`", re.sub(r"\([^)]*\)", "", found.group(1))))


def parse_vigil(argv: list[str]) -> argparse.Namespace:
    """``vigil ARGV`` through vigil's parser; AssertionError with argparse's message."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            return build_parser().parse_args(argv)
        except SystemExit:
            pass
    raise AssertionError(f"`vigil {shlex.join(argv)}` is refused: {err.getvalue().strip()}")


def outputs(args: argparse.Namespace) -> set[str]:
    return {str(v) for k, v in vars(args).items() if k in ("output", "out") and v}


def named_files(args: argparse.Namespace) -> set[str]:
    """The files a parsed command reads (its arguments that are file names)."""
    return {
        v
        for k, v in vars(args).items()
        if isinstance(v, str) and v.endswith(FILE_SUFFIXES) and k not in ("output", "out")
    }


TEXT = DOC.read_text()
LINES = shell_lines(TEXT)
VIGIL = [w[1:] for w in LINES if w[0] == "vigil"]


def test_the_checklist_has_the_bring_up_commands():
    assert CHECKLIST <= {argv[0] for argv in VIGIL}, VIGIL
    assert placeholders(TEXT) >= {"clicked.yaml", "PID", "$AXIS_URL"}


@pytest.mark.parametrize("argv", VIGIL, ids=[" ".join(a) for a in VIGIL])
def test_every_vigil_command_is_accepted_and_names_files_that_exist(argv):
    args = parse_vigil(argv)
    written = {o for a in VIGIL if a[0] == "calibrate" for o in outputs(parse_vigil(a))}
    for name in named_files(args):
        assert (REPO / name).is_file() or name in placeholders(TEXT) or name in written, (
            f"`vigil {shlex.join(argv)}`: {name} is neither in the repository, nor written "
            "by a step, nor a declared placeholder"
        )


def test_the_calibration_step_writes_the_file_the_deployment_reads():
    (calibrate,) = [a for a in VIGIL if a[0] == "calibrate"]
    (written,) = outputs(parse_vigil(calibrate))
    deployment = yaml.safe_load((REPO / "config" / "hardware.yaml").read_text())
    read = (REPO / "config" / deployment["perception"]["calibration"]).resolve()
    assert (REPO / written).resolve() == read


def test_the_other_command_lines_name_existing_files_and_declared_placeholders():
    declared = placeholders(TEXT)
    others = [w for w in LINES if w[0] != "vigil"]
    assert others, "no node or kill line found"
    for words in others:
        for word in words:
            for var in re.findall(r"\$\w+", word):
                assert var in declared, f"{shlex.join(words)}: {var} is not a declared placeholder"
            if word.startswith("config_file:="):
                assert (REPO / word.split(":=", 1)[1]).is_file(), shlex.join(words)
        if words[0] == "kill":
            assert words[-1] in declared, shlex.join(words)


@pytest.mark.parametrize(
    "line, why",
    [
        ("vigil arm config/hardware.yaml --wiat 4", "unrecognized arguments: --wiat"),
        ("vigil statuss config/hardware.yaml", "invalid choice: 'statuss'"),
        ("vigil calibrate -o runs/cal.yaml", "one of the arguments --twin --points"),
    ],
)
def test_the_check_refuses_what_vigil_would_refuse(line, why):
    with pytest.raises(AssertionError, match=re.escape(why)):
        parse_vigil(shell_lines(f"```sh\n{line}\n```\n")[0][1:])


def test_the_check_catches_a_file_that_does_not_exist():
    args = parse_vigil(["launch", "config/hardwear.yaml"])
    assert named_files(args) == {"config/hardwear.yaml"}
    assert not (REPO / "config" / "hardwear.yaml").exists()
