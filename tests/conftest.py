"""Shared test configuration: where the shared measurement data lives (``../shared/data`` beside the checkout), and
the reference packages the tests compare against (:func:`reference`)."""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from battlab import Cell
    from battlab.report.browser import PageCheck

DATA = Path(os.environ.get("BATTLAB_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def pytest_configure(config: pytest.Config) -> None:
    """In CI the data must be there: a test that skips for want of it would hide a failure."""
    if os.environ.get("CI") and not DATA.is_dir():
        raise pytest.UsageError(f"CI: shared data not found at {DATA} (set BATTLAB_DATA)")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The files with a slow test first, each file's tests kept together and in order. The workers take whole
    files in this order (``--no-loadscope-reorder``; xdist's own order, most tests first, left the long files with
    few tests to the end, where one worker ran them while the other had nothing left)."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow)  # stable


#: the reference packages some tests compare against (top-level import name), and how to install each
REFERENCES = {
    "pybamm": 'PyBaMM, the reference DFN: pip install -e ".[test]"',
    "beep": "TRI's BEEP, the reference schedule-file readers: pip install --no-deps beep==2026.2.7",
    "bdf": 'batterydf, the reference Battery Data Format validator: pip install -e ".[test]"',
}


def reference(module: str) -> ModuleType:
    """Import ``module`` of a reference package (a key of :data:`REFERENCES`, e.g. ``"beep.protocol.biologic"``).

    Without it the test (or, called at module level, the whole module) is skipped on a developer's machine, and
    fails in CI (the environment variable ``CI`` set): a comparison that silently loses its reference checks
    nothing. Import with ``from tests.conftest import reference`` (pytest runs from the checkout)."""
    top = module.partition(".")[0]
    if top not in REFERENCES:
        raise KeyError(f"{top!r} is not a reference package of the tests ({', '.join(REFERENCES)})")
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        why = f"{module} cannot be imported ({exc}); {REFERENCES[top]}"
        if os.environ.get("CI"):
            pytest.fail(f"CI: {why}", pytrace=False)
        pytest.skip(why, allow_module_level=True)


@pytest.fixture
def chromium() -> str:
    """Chromium on PATH; in CI its absence is a failure (.ci/run installs it), elsewhere a skip."""
    from battlab.report.browser import find_chromium

    exe = find_chromium()
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("CI: chromium is not installed (.ci/run installs Debian's chromium)")
        pytest.skip("chromium not installed (apt-get install chromium)")
    return exe


@pytest.fixture
def open_elsewhere(
    chromium: str, tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Callable[[Path], PageCheck]:
    """``open_elsewhere(page)``: ``page`` rendered in headless Chromium from a fresh working directory (not the one
    that wrote it, so a figure path relative to the writer's directory fails to load), with its screenshot beside
    the page; a :class:`battlab.report.browser.PageCheck`."""
    from battlab.report.browser import check_page

    def check(page: Path) -> PageCheck:
        page = Path(page).resolve()
        monkeypatch.chdir(tmp_path_factory.mktemp("elsewhere"))
        return check_page(page, page.with_suffix(".png"))

    return check


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not DATA.is_dir():
        pytest.skip(f"shared data not found at {DATA} (set BATTLAB_DATA)")
    return DATA


@pytest.fixture(scope="session")
def nmc_bpx(shared_data: Path) -> Path:
    """The NMC pouch cell of the BPX examples (12.5 Ah), the cell of the PyBaMM comparisons."""
    path = shared_data / "bpx" / "nmc_pouch_cell_BPX.json"
    if not path.is_file():
        pytest.fail(f"{path} is missing from the shared data")
    return path


@pytest.fixture(scope="session")
def nca18650() -> Cell:
    """The built-in 2.7 Ah NCA 18650 at the paper's nominal values."""
    from battlab import Cell

    return Cell.load("nca18650")


@pytest.fixture
def solver_trajectories(monkeypatch: pytest.MonkeyPatch) -> list:
    """The raw ``battlab.model.solver.Trajectory`` of every ``battlab.simulate`` call made in the test.

    ``simulate`` returns only outputs; tests of the state (lithium inventory, SOC) read ``final_state`` from the
    solver's trajectory, whichever stepper (``run`` or ``run_native``) produced it.
    """
    from battlab.model import solver

    captured: list = []
    for name in ("run", "run_native"):
        fn = getattr(solver, name, None)
        if fn is None:
            continue

        def spy(*args: object, _fn=fn, **kwargs: object) -> object:
            traj = _fn(*args, **kwargs)
            captured.append(traj)
            return traj

        monkeypatch.setattr(solver, name, spy)
    return captured
