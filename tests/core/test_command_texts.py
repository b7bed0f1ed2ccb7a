"""A command's texts come from its handler's docstring (``kinesphere.cliargs.command``): the
first paragraph is its line in the list of commands, the rest heads its ``--help``."""

from __future__ import annotations

import argparse
from collections.abc import Iterator

from kinesphere.cli import build_parser
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
