"""Helpers for the runner tests (imported by the test modules; fixtures live in conftest.py)."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from battlab.lab.plan import Plan


def plan_from(text: str, tmp_path: Path, name: str = "plan.toml") -> Plan:
    """A plan from TOML text (written to ``tmp_path/name`` so errors name a file)."""
    path = tmp_path / name
    path.write_text(text)
    return Plan.load(path)


def wait_until(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.01) -> bool:
    """Poll ``predicate`` for at most ``timeout_s`` real seconds (every wait in these tests is bounded)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()
