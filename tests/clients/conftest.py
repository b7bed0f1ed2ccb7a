"""Fixtures of the client tests against real robots."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING

import pytest

from support.client_fleet import ClientFleet, running_fleet

if TYPE_CHECKING:
    from kinesphere.clients.gamepad.inputs.pad import PygameInput


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ClientFleet]:
    """The databank, a PackBot and a youBot as processes, shared by the module's tests."""
    yield from running_fleet(tmp_path_factory.mktemp("logs"))


@pytest.fixture
def inp(pygame_up: None) -> PygameInput:
    """The gamepad's pygame input with the default mapping, no event pending (pygame is
    imported here, after ``pygame_up`` chose SDL's headless drivers)."""
    import pygame

    from kinesphere.clients.gamepad import mapfile
    from kinesphere.clients.gamepad.inputs import pad

    pygame.event.clear()
    return pad.PygameInput(mapfile.load())
