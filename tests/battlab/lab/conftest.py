"""Fixtures for the runner tests: a private run catalog, virtual labs on free loopback ports, plans from text."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from battlab.lab.catalog import Catalog
from drivers.virtual.lab import VirtualLab, VirtualLabConfig


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``$BATTLAB_HOME`` in the test's directory: the run catalog is private to the test."""
    path = tmp_path / "home"
    monkeypatch.setenv("BATTLAB_HOME", str(path))
    return path


@pytest.fixture
def catalog(home: Path) -> Catalog:
    return Catalog()


@pytest.fixture
def make_lab() -> Iterator[Callable[..., VirtualLab]]:
    """``make_lab(physics=None, **config)`` → a started lab (stand-in physics by default); stopped at teardown."""
    labs: list[VirtualLab] = []

    def factory(physics: Any = None, **config: Any) -> VirtualLab:
        config.setdefault("modbus_rtu_port", None)
        config.setdefault("espec_port", None)
        lab = VirtualLab(physics, VirtualLabConfig(**config)).start()
        labs.append(lab)
        return lab

    yield factory
    for lab in labs:
        lab.stop()
