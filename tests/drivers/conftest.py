"""Fixtures for the drivers tests: virtual labs started in-process on free loopback ports."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from drivers.testing import wait_until  # noqa: F401 (re-exported for the tests)
from drivers.virtual.lab import VirtualLab, VirtualLabConfig


@pytest.fixture
def make_lab() -> Iterator[Callable[..., VirtualLab]]:
    """``make_lab(physics=None, effects=(), **config)`` → a started lab; all are stopped at teardown."""
    labs: list[VirtualLab] = []

    def factory(physics: Any = None, effects: tuple[Any, ...] = (), **config: Any) -> VirtualLab:
        lab = VirtualLab(physics, VirtualLabConfig(**config), effects=effects).start()
        labs.append(lab)
        return lab

    yield factory
    for lab in labs:
        lab.stop()
