"""Fixtures of the client tests against real robots."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from support.client_fleet import ClientFleet, running_fleet


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ClientFleet]:
    """The databank, a PackBot and a youBot as processes, shared by the module's tests."""
    yield from running_fleet(tmp_path_factory.mktemp("logs"))
