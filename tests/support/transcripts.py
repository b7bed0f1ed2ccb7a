"""The docs' transcripts: fenced blocks of ``$ command`` lines, each followed by what the
command prints, in README.md and docs/*.md; and the comparison of what a command printed with
what a transcript shows (numbers aside: times, counts and angles vary from run to run).

Every transcript is run by a test (tests/system/test_docs_transcripts.py keeps the list), so an
example's output is what the command prints, not what someone remembered.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass, field

from support.paths import ROOT

DOCS = ("README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")))
"""The documents whose transcripts are run."""
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")
ANSI = re.compile(r"\x1b\[[0-9;]*m")
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", flags=re.S | re.M)


@dataclass
class Step:
    """One command of a transcript and the lines shown after it."""

    words: list[str]
    background: bool
    shown: list[str] = field(default_factory=list)


@dataclass
class Transcript:
    """A fenced block with ``$ `` lines: where it is, the section it is in, its steps."""

    doc: str
    line: int
    section: str
    steps: list[Step]


def transcripts(doc: str) -> list[Transcript]:
    """Every transcript of ``doc`` (a path relative to the repository), in order."""
    text = (ROOT / doc).read_text(encoding="utf-8")
    found = []
    for block in FENCE.finditer(text):
        lines = block.group(1).splitlines()
        if not any(line.startswith("$ ") for line in lines):
            continue
        before = text[: block.start()]
        heading = re.findall(r"^##+ (.+)$", before, flags=re.M)
        steps: list[Step] = []
        for line in lines:
            if line.startswith("$ "):
                words = shlex.split(line[2:], comments=True)
                background = words[-1] == "&"
                steps.append(Step(words[:-1] if background else words, background))
            else:
                assert steps, f"{doc}:{before.count(chr(10)) + 1}: output before any command"
                steps[-1].shown.append(line)
        found.append(Transcript(doc, before.count("\n") + 1, heading[-1] if heading else "",
                                steps))
    return found


def section(doc: str, title: str) -> list[Transcript]:
    """The transcripts of ``doc`` under the heading ``title``."""
    found = [t for t in transcripts(doc) if t.section == title]
    assert found, f"{doc} lost its transcripts under '{title}'"
    return found


def normal(line: str) -> str:
    """A line with every number made ``#`` and every run of blanks one space."""
    return " ".join(NUMBER.sub("#", ANSI.sub("", line)).split())


def _pattern(line: str) -> re.Pattern[str]:
    """A shown line as a pattern over normal lines (``…``: anything)."""
    return re.compile(".*".join(re.escape(part) for part in normal(line).split("…")))


def _shown(shown: list[str]) -> list[str]:
    return [line for line in shown if re.search(r"\w", line)]  # not a table's border


def unprinted(shown: list[str], output: str) -> list[str]:
    """The lines shown that ``output`` lacks (numbers aside; ``…``: anything)."""
    lines = [normal(line) for line in output.splitlines()]
    return [line for line in _shown(shown)
            if not any(_pattern(line).fullmatch(out) for out in lines)]


def unshown(shown: list[str], output: str) -> list[str]:
    """The lines of ``output`` that no shown line stands for: with :func:`unprinted`, whether
    the transcript shows exactly what the command printed."""
    patterns = [_pattern(line) for line in _shown(shown)]
    return [line for line in output.splitlines() if line.strip()
            and not any(p.fullmatch(normal(line)) for p in patterns)]
