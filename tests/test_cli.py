"""The command line's habits (issue 14): every subcommand explains itself and every
option says what it is for and its default."""

import argparse

import pytest

from vigil.cli import build_parser


def _commands(parser: argparse.ArgumentParser, path=()):
    """(path, parser) of every leaf subcommand."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    seen = set()
    for name, sub in subs[0].choices.items():
        if id(sub) in seen:  # an alias
            continue
        seen.add(id(sub))
        yield from _commands(sub, (*path, name))


COMMANDS = list(_commands(build_parser()))


def test_there_are_commands_to_check():
    names = {" ".join(p) for p, _ in COMMANDS}
    assert {"run", "evaluate", "replay-report", "security keystore"} <= names


@pytest.mark.parametrize("path, parser", COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_every_option_has_help_and_shows_its_default(path, parser):
    assert parser.description, f"vigil {' '.join(path)} has no description"
    text = parser.format_help()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help, f"vigil {' '.join(path)}: {action.dest} has no help"
        if action.option_strings and action.default not in (None, False, argparse.SUPPRESS):
            assert (
                f"(default: {action.default})" in text.replace("\n", " ").replace("  ", " ")
                or "default" in action.help
            ), f"vigil {' '.join(path)}: {action.dest}"


def test_main_is_an_alias_of_replay_report():
    a = build_parser().parse_args(["main", "--out", "x"])
    b = build_parser().parse_args(["replay-report", "--out", "x"])
    assert a.func is b.func and a.out == b.out == "x"
