"""Help text in one style (issue 14, item 10): every subcommand has a description, every
option a help line, and the options several commands share are spelled one way."""

from __future__ import annotations

import argparse

import pytest
from conftest import run_mousedom

from mousedom.cli import build_parser


def _subcommands(parser: argparse.ArgumentParser, prefix: str = ""):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield f"{prefix}{name}", sub
                yield from _subcommands(sub, f"{prefix}{name} ")


COMMANDS = dict(_subcommands(build_parser()))


def test_the_commands_are_all_there():
    want = {"run", "watch", "list", "record", "replay", "convert", "check-config", "umbmark",
            "calibrate", "calibrate cpi", "calibrate distance", "calibrate mounts",
            "calibrate scales"}  # fmt: skip
    assert want <= set(COMMANDS)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_and_option_explains_itself(name):
    parser = COMMANDS[name]
    assert parser.description, f"{name}: no description"
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        assert action.help and action.help != argparse.SUPPRESS or action.dest == "verbose", (
            f"{name} {action.option_strings or action.dest}: no help"
        )


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_shared_options_are_spelled_one_way(name):
    for action in COMMANDS[name]._actions:
        if "--config" in action.option_strings:
            assert action.option_strings == ["-c", "--config"] and action.metavar == "RIG.yaml"
            if action.default:  # a default is shown where there is one
                assert str(action.default) in action.help, action.help
        if "--output" in action.option_strings:
            assert action.option_strings == ["-o", "--output"], (name, action.option_strings)


@pytest.mark.parametrize("flag", ["-V", "--version"])
def test_version_flag(flag):
    from mousedom import __version__, core

    p = run_mousedom(flag)
    # and which core runs (docs/install.md)
    assert (
        p.returncode == 0 and p.stdout.strip() == f"mousedom {__version__} (core: {core.NAME})"
    ), p
