"""A command's texts come from its handler's docstring (``kinesphere.cliargs.command``): the
first paragraph is its line in the list of commands, the rest heads its ``--help``."""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import pytest

from kinesphere.cli import build_parser, commands
from kinesphere.cliargs import command, handler_texts


def _documented(args: argparse.Namespace) -> int:
    """move one robot
    somewhere

    Put one Command on the robot's
    key and wait.

    Then say what it did.
    """
    return 0


def _one_line(args: argparse.Namespace) -> int:
    """list the robots"""
    return 0


def _undocumented(args: argparse.Namespace) -> int:
    return 0


def test_the_first_paragraph_is_the_help_and_the_rest_the_description() -> None:
    assert handler_texts(_documented) == (
        "move one robot somewhere", "Put one Command on the robot's key and wait.\n\n"
        "Then say what it did.")
    assert handler_texts(_one_line) == ("list the robots", None)
    assert handler_texts(_undocumented) == ("", None)


def test_texts_given_at_registration_win_over_the_docstring() -> None:
    sub = argparse.ArgumentParser(prog="k").add_subparsers()
    given = command(sub, "given", _documented, help="laid out by hand", description="As is.")
    read = command(sub, "read", _documented)
    assert (given.description, read.description) == ("As is.", handler_texts(_documented)[1])
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert helps == {"given": "laid out by hand", "read": "move one robot somewhere"}


def _listed(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str | None]]:
    """(prog, help line) of every sub-command below ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                yield f"{parser.prog} {choice.dest}", choice.help
            for child in dict.fromkeys(action.choices.values()):
                yield from _listed(child)


def test_every_installed_command_has_a_help_line() -> None:
    listed = dict(_listed(build_parser()))
    assert len(listed) > 30
    assert [prog for prog, text in listed.items() if not text] == []


def _laid_out(parser: argparse.ArgumentParser) -> set[str]:
    """The lines of a parser's description, epilog and group descriptions that start with a
    space: laid out by hand (an example, a row of a table)."""
    texts = [parser.description, parser.epilog,
             *(g.description for g in parser._action_groups)]
    return {line.rstrip() for text in texts if text
            for line in text.splitlines() if line[:1].isspace()}


def test_help_wraps_sentences_and_keeps_lines_laid_out_by_hand(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """At 80 columns a line of any command's ``--help`` is longer only when it is a line laid
    out by hand, kept as written (argparse's raw formatter printed the gamepad's description
    and the Zenoh group's as single lines of 340 and 180 characters)."""
    monkeypatch.setenv("COLUMNS", "80")
    parsers = commands(build_parser())
    parsers.update({f"ros2 {k}": p for k, p in commands(parsers["ros2"]).items()})
    for name, parser in parsers.items():
        kept = _laid_out(parser)
        for line in parser.format_help().splitlines():
            assert len(line) <= 80 or line.rstrip() in kept, (name, line)
    gamepad = parsers["gamepad"].format_help()
    assert "\n  W A S D     left stick: drive the base      Z / C   turn the base left / right\n" \
        in gamepad, "the key table as written"
    assert "\n  kinesphere send baxter-1 limb_11 distal_11 left-high 3\n" in \
        parsers["send"].format_help(), "the example as written"
