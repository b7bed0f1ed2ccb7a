"""The fixtures every test folder shares, and the ``processes`` and ``realtime`` markers.

``hub`` and ``databank`` are one per test session (per pytest-xdist worker): the agent tests of
every folder join one loopback hub and ask one real databank process (serving every shipped
platform under the default prefix), started once. A test that must not meet them (it stops its
databank, or serves other robots under the same prefix) opens a hub of its own with
``zconfig.loopback_hub``.

A test that starts processes (the databank, agents, routers, ``kinesphere`` commands, pip) is
marked ``processes`` (``pytest -m "not processes"`` runs the quick rest). Using a fixture that
starts one marks a test; a test that starts one itself is marked in its module. A test that
judges robots against the clock (keyframes on time, a gamepad's ticks) is marked ``realtime``:
``make test`` runs every other test on all cores, then these two at a time, the longest
(``realtime(longest=True)``) beside all the others.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

from kinesphere import zconfig
from kinesphere.procs import Supervisor
from support.agents import DatabankProcess, databank_on
from support.cells import load_laban_editor
from support.network import Hub
from support.system import supervisor

PROCESS_FIXTURES = frozenset({"databank", "sup", "fleet", "secured"})
"""Fixtures that start processes: a test using one is marked ``processes``."""


def pytest_configure(config: pytest.Config) -> None:
    """Drop ``COLUMNS`` and ``LINES``: pytest-xdist's workers get an 80x24 terminal's, and the
    commands the tests start would lay out their tables for it instead of for the file their
    output goes to (the docs show that output, and the tests compare it)."""
    for name in ("COLUMNS", "LINES"):
        os.environ.pop(name, None)


def pytest_itemcollected(item: pytest.Item) -> None:
    if PROCESS_FIXTURES & set(getattr(item, "fixturenames", ())):
        item.add_marker(pytest.mark.processes)


@pytest.hookimpl(trylast=True)  # after ``-m`` has deselected
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Files in the order pytest-xdist is to hand them out (``--no-loadscope-reorder``): one
    with a test marked ``realtime(longest=True)`` first, then by how many tests they hold, most
    first (pytest-xdist's own order). A worker holding two tests or fewer is handed the next
    file: the one that starts the longest test is handed the second largest file behind it at
    once, and the other, busy with the largest file, takes the rest as it gets through it."""
    files: dict[str, list[pytest.Item]] = {}
    for item in items:
        files.setdefault(item.nodeid.split("::")[0], []).append(item)
    order = sorted(files.values(), key=lambda tests: (not any(map(_longest, tests)),
                                                      -len(tests)))
    items[:] = [item for tests in order for item in tests]


def _longest(item: pytest.Item) -> bool:
    mark = item.get_closest_marker("realtime")
    return mark is not None and bool(mark.kwargs.get("longest"))


@pytest.fixture(scope="session")
def hub() -> Iterator[Hub]:
    """The loopback Zenoh hub the tests' sessions and processes join (one per test session)."""
    with zconfig.loopback_hub() as (session, endpoint):
        yield Hub(session, endpoint)


@pytest.fixture(scope="session")
def databank(hub: Hub) -> Iterator[DatabankProcess]:
    """The real databank process serving every shipped platform on the hub (one per test
    session; stopped before the hub)."""
    with databank_on(hub) as bank:
        yield bank


@pytest.fixture
def sup(tmp_path: Path) -> Iterator[Supervisor]:
    """Processes started by the test, stopped (and checked for leftovers) after it."""
    yield from supervisor(tmp_path / "logs")


@pytest.fixture(scope="module")
def pygame_up() -> Iterator[None]:
    """pygame initialised headless (SDL's dummy drivers) for the module's tests."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    import pygame

    from kinesphere.clients.gamepad.inputs import pad

    pad.init_pygame(headless=True)
    yield
    pygame.quit()


@pytest.fixture(scope="session")
def laban_editor() -> ModuleType:
    """LabanEditor's ``labanProcessor.py`` loaded as a module (``to_sphere``,
    ``coordinate2laban``): the cells it writes are what kinesphere's notation must write."""
    return load_laban_editor()
