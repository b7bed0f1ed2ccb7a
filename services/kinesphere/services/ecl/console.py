"""The console the ``kinesphere ecl`` commands print their tables on.

Its own module because both command modules use it and the look-up commands load the
generator's commands (``build_cli``), not the other way round.
"""

from __future__ import annotations

from rich.console import Console


def table_console() -> Console:
    """A terminal keeps its width; piped output is never truncated."""
    console = Console()
    return console if console.is_terminal else Console(width=10_000)
