"""Shared test configuration: where the shared measurement data lives (``../shared/data`` beside the checkout)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DATA = Path(os.environ.get("BATTLAB_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def pytest_configure(config: pytest.Config) -> None:
    """In CI the data must be there: a test that skips for want of it would hide a failure."""
    if os.environ.get("CI") and not DATA.is_dir():
        raise pytest.UsageError(f"CI: shared data not found at {DATA} (set BATTLAB_DATA)")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"shared data not found at {DATA} (set BATTLAB_DATA)")
    return DATA
