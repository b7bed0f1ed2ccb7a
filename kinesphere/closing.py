"""Resources a ``with`` block ends: one ``__enter__``/``__exit__`` for every class that closes.

Why a base rather than each class writing the pair: what the block's end does (``close``,
whatever happened inside) is one rule, and a class that forgets ``__exit__`` or has it call
something else than ``close`` would leak a file, a renderer or Zenoh declarations.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Self


class Closable(ABC):
    """Used as ``with x:``: the block's end calls :meth:`close`."""

    @abstractmethod
    def close(self) -> None:
        """Release what the object holds (files, threads, Zenoh declarations)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Startable(Closable):
    """Used as ``with x:``: the block's start calls :meth:`start`, its end :meth:`close`."""

    @abstractmethod
    def start(self) -> Self:
        """Begin serving (declare, start threads); returns the object itself."""

    def __enter__(self) -> Self:
        return self.start()
