"""Every relative link in the repository's Markdown reaches a file (and, for ``#fragment``, a
heading of it, by GitHub's slug rule), and every repository path, ``kinesphere`` command and
``make`` target the docs and the ``--help`` texts name exists: a newcomer who follows them never
lands on nothing. (That the README's tour runs as written is tests/system/test_system_hub.py.)

A *repository path* is a word that starts with one of the repository's top-level folders or
files (``robots/...``, ``deploy/router.json5``, ``README.md``); ``<name>``, ``{platform}`` and
``*`` in it match any name. Under ``kinesphere/`` only ``.py`` files count: the default key
prefix is ``kinesphere`` too (``kinesphere/robot/*/command`` is a key, not a file).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import re
import shlex
import unicodedata
from collections.abc import Iterator
from pathlib import Path

import pytest

from kinesphere.cli import build_parser, commands
from support.names import MISSING, resolve
from support.paths import ROOT

TOP_DIRS = ("kinesphere", "platforms", "robots", "services", "clients", "deploy", "tests",
            "bench", "docs", ".ci")
TOP_FILES = ("README.md", "Makefile", "pyproject.toml", "constraints.txt")
"""The repository's top level (the brief's layout): what a repository path starts with."""
NEVER = frozenset({"kinesphere/__init__.py"})
"""Paths the docs name because they must not exist (the namespace is PEP 420)."""
SKIP = frozenset({"build", "out", "node_modules", "__pycache__"})
"""Folders of generated files (and every dot folder: .git, .venv, caches) hold no docs."""

FENCE = re.compile(r"^\s*(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.+?)\s*#*\s*$")
CODE_SPAN = re.compile(r"(`+)(.+?)\1")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)")
WORD = re.compile(r"[^\s`'\"()\[\],;|=]+")
PLACEHOLDER = re.compile(r"<[^>/]*>|\{[^}/]*\}")
DOTTED = re.compile(r"\bkinesphere(?:\.[A-Za-z_]\w*)+")
QUOTED_COMMAND = re.compile(r"['`\"](kinesphere [^'`\"]+)['`\"]")
MAKE_TARGET = re.compile(r"^([A-Za-z][\w-]*)\s*:(?!=)", re.M)
SHELL_END = frozenset({"&", "|", "&&", "||", ";", ">", ">>", "2>&1"})
"""Words after which a command line's own words end."""


def markdown_files() -> list[Path]:
    found = []
    for folder, dirs, files in os.walk(ROOT):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d not in SKIP
                         and not d.endswith(".egg-info"))
        found += [Path(folder) / f for f in sorted(files) if f.endswith(".md")]
    return found


def split_fences(text: str) -> tuple[list[str], list[str]]:
    """(prose lines, code lines) of a Markdown text: fenced blocks apart."""
    prose: list[str] = []
    code: list[str] = []
    fenced = False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
        elif fenced:
            code.append(line)
        else:
            prose.append(line)
    return prose, code


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: its text lowercased, every character but letters,
    digits, ``_``, ``-`` and spaces dropped, spaces made hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    kept = "".join(c for c in text if c in " -" or unicodedata.category(c)[0] in "LNM"
                   or unicodedata.category(c) == "Pc")
    return kept.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file (repeats get ``-1``, ``-2``, ... as on GitHub)."""
    prose, _ = split_fences(path.read_text(encoding="utf-8"))
    seen: dict[str, int] = {}
    out = set()
    for line in prose:
        m = HEADING.match(line)
        if m:
            base = slug(m.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def links(path: Path) -> Iterator[str]:
    """Link targets of a Markdown file, outside code blocks and code spans."""
    prose, _ = split_fences(path.read_text(encoding="utf-8"))
    for line in prose:
        bare = CODE_SPAN.sub("", line)
        yield from LINK.findall(bare)
        m = REFERENCE.match(bare)
        if m:
            yield m.group(1)


def broken_link(source: Path, target: str) -> str | None:
    """Why ``target`` (written in ``source``) leads nowhere, else None."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # https:, mailto:, ...
        return None
    file_part, _, fragment = target.partition("#")
    dest = (source.parent / file_part).resolve() if file_part else source
    if not dest.is_relative_to(ROOT.resolve()):
        return "leads out of the repository"
    if not dest.exists():
        return "no such file"
    if fragment and dest.suffix == ".md" and fragment not in anchors(dest):
        return f"no heading with anchor #{fragment} in {dest.relative_to(ROOT.resolve())}"
    return None


def repository_paths(text: str) -> set[str]:
    """The words of ``text`` that name a path of this repository."""
    found = set()
    for word in WORD.findall(text):
        word = word.partition("#")[0].rstrip(".:!?").lstrip("<")
        if "://" in word:
            continue
        first = word.split("/", 1)[0]
        if word in TOP_FILES or (first in TOP_DIRS and "/" in word):
            if first == "kinesphere" and not word.endswith(".py"):
                continue  # a key expression under the default prefix
            found.add(word)
    return found


def ignored(path: str) -> bool:
    """Whether ``path`` is what a command makes (``deploy/certs/``, ``out/``): a folder the
    .gitignore at the top or beside it names."""
    parts = path.split("/")
    for depth in range(len(parts)):
        rules = ROOT.joinpath(*parts[:depth], ".gitignore")
        if rules.exists():
            names = {r.strip().strip("/") for r in rules.read_text(encoding="utf-8").splitlines()
                     if r.strip().endswith("/") and not r.startswith("#")}
            if names & set(parts[depth:]):
                return True
    return False


def missing(word: str) -> bool:
    """Whether the path ``word`` names does not exist (and is not one a command makes)."""
    pattern = PLACEHOLDER.sub("*", word).rstrip("/")
    if word in NEVER:
        return (ROOT / word).exists()
    if "*" in pattern:
        return not any(ROOT.glob(pattern))
    return not (ROOT / pattern).exists() and not ignored(pattern)


def table_rows(path: Path) -> Iterator[tuple[int, int, int]]:
    """(line number, cells, the header's cells) of every row of every table of a Markdown
    file; GitHub pads a short row with empty cells, so a lost cell shows nowhere."""
    header = 0
    fenced = False
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
        text = line.strip()
        if fenced or not text.startswith("|"):
            header = 0
            continue
        cells = len(re.split(r"(?<!\\)\|", text.strip("|")))
        if not header:
            header = cells
        yield number, cells, header


def module_names(text: str) -> set[str]:
    """Dotted names of this repository's modules (and what is in them) that ``text`` names:
    ``kinesphere.X...`` where ``kinesphere.X`` is a module or a role's package."""
    return {name for name in DOTTED.findall(text)
            if importlib.util.find_spec(".".join(name.split(".")[:2])) is not None}


def parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    """``parser`` and every sub-command's parser below it."""
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):  # aliases: one parser
                yield from parsers(child)


def help_texts(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """``--help`` of every sub-command this installation has, unwrapped (argparse wraps at
    ``$COLUMNS``), keyed by its prog."""
    monkeypatch.setenv("COLUMNS", "100000")
    return {p.prog: p.format_help() for p in parsers(build_parser())}


def command_lines(path: Path, program: str) -> Iterator[str]:
    """The ``program ...`` command lines a Markdown file shows: lines of its code blocks (a
    console's ``$ `` prompt dropped) and code spans of its prose."""
    prose, code = split_fences(path.read_text(encoding="utf-8"))
    for line in code:
        line = line.strip().removeprefix("$ ")
        if line.startswith(f"{program} "):
            yield line
    for line in prose:
        for span in CODE_SPAN.finditer(line):
            if span.group(2).strip().startswith(f"{program} "):
                yield span.group(2).strip()


def unknown_in(line: str, root: argparse.ArgumentParser) -> str | None:
    """What in the ``kinesphere ...`` command ``line`` names no sub-command or option of
    ``root`` (a usage line's ``[--opt X]`` counts as ``--opt X``), else None. Words in
    CAPITALS, ``<placeholders>`` and positionals are the user's: only names are checked."""
    try:
        words = shlex.split(line, comments=True)
    except ValueError:  # an unbalanced quote in a usage line
        words = line.split()
    parser, commands_done = root, False
    options = dict(root._option_string_actions)
    value_next = False
    for word in words[1:]:
        if word in SHELL_END:
            break
        word = word.strip("[]")
        if value_next:  # the value of the option before
            value_next = False
            continue
        if re.match(r"--?[A-Za-z]", word):
            name, eq, _ = word.partition("=")
            if name not in options:
                return f"{parser.prog} has no option {name}"
            value_next = not eq and options[name].nargs != 0
            continue
        choices = commands(parser)
        if commands_done or not choices:
            commands_done = True
            continue
        if word in choices:
            parser = choices[word]
            options |= parser._option_string_actions
        elif re.fullmatch(r"[a-z][a-z0-9-]*", word):
            return f"{parser.prog} has no sub-command {word}"
        else:
            commands_done = True
    return None


def make_targets() -> set[str]:
    return set(MAKE_TARGET.findall((ROOT / "Makefile").read_text(encoding="utf-8")))


def test_the_checks_see_the_docs_and_every_command(tmp_path: Path) -> None:
    files = {f.relative_to(ROOT).as_posix() for f in markdown_files()}
    assert {"README.md", "docs/architecture.md", "docs/protocol.md", "deploy/README.md"} <= files
    assert slug("Use with ROS 2") == "use-with-ros-2"
    assert slug("The bridge: `kinesphere ros2 bridge`") == "the-bridge-kinesphere-ros2-bridge"
    assert slug("Fleet host (many robots)") == "fleet-host-many-robots"
    assert repository_paths("see `robots/agent/README.md`, and kinesphere/robot/*/command") == {
        "robots/agent/README.md"}
    assert missing("robots/agent/README.md") and not missing("deploy/router.json5")
    assert not missing("platforms/kinesphere/platforms/shipped/<name>/vsam.toml")
    assert missing("services/ecl/data/<platform>.sqlite") and not missing("deploy/certs/ca.pem")
    assert module_names("`kinesphere.laban.Direction`, kinesphere.RobotState, kinesphere.env") == {
        "kinesphere.laban.Direction"}
    assert resolve("kinesphere.laban.Direction.parse") is not MISSING
    assert resolve("kinesphere.laban.Dir") is MISSING
    root = build_parser()
    assert unknown_in("kinesphere ecl bogus ", root) == "kinesphere ecl has no sub-command bogus"
    assert unknown_in("kinesphere -v send b arm --no", root) == "kinesphere send has no option --no"
    assert unknown_in("kinesphere --platforms ~/r databank serve --no", root) == (
        "kinesphere databank serve has no option --no")
    assert unknown_in("kinesphere replay F [--what commands|states] [--wait 5] &", root) is None
    assert unknown_in("kinesphere agent baxter --body ros2 --ros2-namespace /b", root) is None
    assert {"demo", "test", "lint"} <= make_targets() and "VENV" not in make_targets()
    table = tmp_path / "t.md"
    table.write_text("| a | b |\n|---|---|\n| `x \\| y` | z |\n| w |\n", encoding="utf-8")
    assert [(cells, header) for _, cells, header in table_rows(table)] == [
        (2, 2), (2, 2), (2, 2), (1, 2)]


def test_every_relative_link_reaches_a_file_and_its_heading() -> None:
    broken = []
    for md in markdown_files():
        for target in links(md):
            why = broken_link(md, target)
            if why:
                broken.append(f"{md.relative_to(ROOT)}: ({target}) {why}")
    assert not broken, "\n".join(broken)


def test_every_repository_path_the_docs_name_exists() -> None:
    absent = [f"{md.relative_to(ROOT)}: {word}" for md in markdown_files()
              for word in sorted(repository_paths(md.read_text(encoding="utf-8")))
              if missing(word)]
    assert not absent, "\n".join(absent)


def test_every_repository_path_a_help_text_names_exists(monkeypatch: pytest.MonkeyPatch) -> None:
    texts = help_texts(monkeypatch)
    assert len(texts) >= 30, sorted(texts)  # every role is installed by make install
    absent = [f"{prog} --help: {word}" for prog, text in sorted(texts.items())
              for word in sorted(repository_paths(text)) if missing(word)]
    assert not absent, "\n".join(absent)


def test_every_table_row_has_the_cells_of_its_header() -> None:
    short = [f"{md.relative_to(ROOT)}:{n}: {cells} cells, the header has {header}"
             for md in markdown_files() for n, cells, header in table_rows(md) if cells != header]
    assert not short, "\n".join(short)


def test_every_module_the_docs_name_exists() -> None:
    absent = [f"{md.relative_to(ROOT)}: {name}" for md in markdown_files()
              for name in sorted(module_names(md.read_text(encoding="utf-8")))
              if resolve(name) is MISSING]
    assert not absent, "\n".join(absent)


def test_every_kinesphere_command_the_docs_name_exists() -> None:
    root = build_parser()
    lines = [(md, line) for md in markdown_files() for line in command_lines(md, "kinesphere")]
    assert len(lines) >= 100, len(lines)
    wrong = [f"{md.relative_to(ROOT)}: {line}: {why}" for md, line in lines
             if (why := unknown_in(line, root))]
    assert not wrong, "\n".join(wrong)


def test_every_kinesphere_command_a_help_text_names_exists(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    root = build_parser()
    wrong = [f"{prog} --help: {found}: {why}"
             for prog, text in sorted(help_texts(monkeypatch).items())
             for found in QUOTED_COMMAND.findall(text) if (why := unknown_in(found, root))]
    assert not wrong, "\n".join(wrong)


def test_every_make_target_the_docs_name_exists() -> None:
    targets = make_targets()
    absent = [f"{md.relative_to(ROOT)}: {line}" for md in markdown_files()
              for line in command_lines(md, "make")
              if shlex.split(line, comments=True)[1] not in targets]
    assert not absent, "\n".join(absent)


def test_the_readme_stays_a_start_and_reaches_every_topic() -> None:
    """The README is where a newcomer starts (issue 23): short, and one link away from every
    topic file in ``docs/``; new material goes to the topic's file, a new topic gets a file
    and a row in the README's table."""
    readme = ROOT / "README.md"
    lines = readme.read_text(encoding="utf-8").count("\n")
    assert lines <= 300, f"README.md has {lines} lines: move the new text to its docs/ file"
    linked = {(ROOT / target.partition("#")[0]).resolve() for target in links(readme)}
    unlinked = sorted(md.relative_to(ROOT).as_posix() for md in (ROOT / "docs").glob("*.md")
                      if md.resolve() not in linked)
    assert not unlinked, f"give these a row in README.md's 'Where to read on': {unlinked}"
