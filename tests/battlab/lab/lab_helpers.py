"""Helpers for the runner tests (imported by the test modules; fixtures live in conftest.py)."""

from __future__ import annotations

from pathlib import Path

from battlab.lab.plan import Plan
from drivers.testing import wait_until  # noqa: F401 (re-exported for the tests)


def plan_from(text: str, tmp_path: Path, name: str = "plan.toml") -> Plan:
    """A plan from TOML text (written to ``tmp_path/name`` so errors name a file)."""
    path = tmp_path / name
    path.write_text(text)
    return Plan.load(path)
