"""Files the tests write for the product's loaders: a bad one is refused with a clear error."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from kinesphere.errors import KinesphereError


def refused(load: Callable[[Path], object], folder: Path, text: str, name: str = "bad.toml",
            code: str | None = "malformed") -> KinesphereError:
    """What ``load`` says of a file ``name`` in ``folder`` holding ``text``: an error with
    ``code`` (``None``: whichever the problem has), never a traceback nor a result, for the
    caller to check that it names the problem."""
    path = folder / name
    path.write_text(text, encoding="utf-8")
    with pytest.raises(KinesphereError) as info:
        load(path)
    assert code is None or info.value.code == code, info.value
    return info.value
