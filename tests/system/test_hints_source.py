"""Every command kinesphere tells a user to run is built by ``kinesphere.hints`` (one place,
which ``test_hints.py`` runs hint by hint): no other module spells a quoted ``'kinesphere
...'`` command in a message. Docstrings and ``--help`` texts are documentation, not hints."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from support.paths import ROOT

QUOTED = re.compile(r"['`(]kinesphere [a-z]")
DOCUMENTATION = frozenset({"help", "description", "epilog", "usage"})
PACKAGES = ("kinesphere", *(f"{d}/kinesphere" for d in
                            ("platforms", "robots", "services", "clients", "deploy")))


def _documentation(tree: ast.AST) -> set[int]:
    """Ids of the string nodes that are docstrings or ``help=``-like arguments."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            skip.add(id(node.value))  # docstrings, attribute docstrings
        if isinstance(node, ast.keyword) and node.arg in DOCUMENTATION:
            skip.update(id(sub) for sub in ast.walk(node.value))
    return skip


def quoted_commands(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _documentation(tree)
    return [f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}"
            for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in skip and QUOTED.search(node.value)]


def test_only_the_hints_module_spells_a_command() -> None:
    found = [hit for pkg in PACKAGES for f in sorted((ROOT / pkg).rglob("*.py"))
             if f != ROOT / "kinesphere" / "hints.py" for hit in quoted_commands(f)]
    assert found == [], "build these with kinesphere.hints:\n" + "\n".join(found)


def test_the_scan_finds_a_spelt_command(tmp_path: Path) -> None:
    f = ROOT / "tests" / "system" / "test_hints_source.py"
    example = "start one with 'kinesphere router'"
    assert QUOTED.search(example) and quoted_commands(f)
