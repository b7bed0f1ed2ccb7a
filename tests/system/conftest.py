"""Fixtures of the system tests that more than one module uses."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from support.system import Secured, secured_system


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Secured]:
    """The deploy/ configs as shipped, running behind a TLS router (one per module)."""
    yield from secured_system(tmp_path_factory.mktemp("secured"))
