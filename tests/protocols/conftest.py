"""Shared fixtures of the protocols tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from protocols.library import Library

GOLDEN = Path(__file__).parent / "golden"
REGENERATE = os.environ.get("PROTOCOLS_REGENERATE_GOLDEN") == "1"


@pytest.fixture(scope="session")
def lib() -> Library:
    """The library, built once per test session."""
    return Library.build()


@pytest.fixture
def golden() -> Path:
    """Folder of the checked-in golden files (rewrite them with PROTOCOLS_REGENERATE_GOLDEN=1)."""
    return GOLDEN


@pytest.fixture
def regenerate() -> bool:
    """Whether to rewrite golden files instead of checking them."""
    return REGENERATE
