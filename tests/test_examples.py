"""The shipped example plans load, pass the run's pre-flight checks on the virtual tester, and keep the cell in its
window.

``battlab run`` has no dry-run option, so the checks are the ones it makes before switching anything on
(:func:`battlab.lab.preflight.check_plan` against the virtual tester's limits), plus a noise-free simulation of
every profile step from its start SOC: a profile that would trip the voltage limit on the first run of a new
user fails here instead. Running a whole plan takes longer than this suite allows (about 15 s of a loaded
machine per plan at the virtual tester's 1000x).
"""

from __future__ import annotations

from pathlib import Path

import pytest

import battlab
from battlab.io.plan import Plan
from battlab.lab.limits import VIRTUAL_LIMITS, CellWindow
from battlab.lab.preflight import check_plan
from protocols import ProfileStep, Rest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PLANS = sorted(EXAMPLES.glob("*.toml"))


@pytest.fixture(scope="module")
def cell() -> battlab.Cell:
    return battlab.Cell.load("nca18650")


def test_the_examples_ship_a_plan_and_a_readme() -> None:
    assert EXAMPLES / "plan.toml" in PLANS
    readme = (EXAMPLES / "README.md").read_text()
    for path in PLANS:
        assert f"examples/{path.name}" in readme, f"{path.name} is not described in examples/README.md"


@pytest.mark.parametrize("path", PLANS, ids=lambda p: p.name)
def test_example_plan_loads_and_passes_preflight_on_the_virtual_tester(path: Path, cell: battlab.Cell) -> None:
    plan = Plan.load(path)
    envelope = check_plan(plan, CellWindow.of(cell), VIRTUAL_LIMITS)
    lim = plan.protocol.limits
    assert (envelope.voltage_min, envelope.voltage_max) == (lim.voltage_min, lim.voltage_max)
    assert plan.entries(), "the plan runs no step"
    # every step ends by itself: a step without an end would hold the tester forever
    for k, step in enumerate(plan.protocol.steps, start=1):
        assert isinstance(step, ProfileStep) or step.ends, f"step {k} has no end condition"
        if isinstance(step, Rest):
            assert any(e.quantity.value == "time" for e in step.ends), f"rest step {k} has no time end"


@pytest.mark.parametrize("path", PLANS, ids=lambda p: p.name)
def test_example_profiles_stay_in_the_cell_window(path: Path, cell: battlab.Cell) -> None:
    profiles = [s.profile for s in Plan.load(path).protocol.steps if isinstance(s, ProfileStep)]
    for p in profiles:
        assert p.soc0 is not None, f"profile {p.id} gives no start SOC"
        res = battlab.simulate(cell, p, soc0=p.soc0, ambient=298.15)
        assert res.ended_by is None, f"profile {p.id} from SOC {p.soc0}: stopped early ({res.ended_by})"
        assert res.t[-1] == pytest.approx(p.t[-1])


def test_example_plan_reaches_its_profiles_at_their_start_soc() -> None:
    """The plan's own arithmetic: charged to 100 %, discharged 0.54 Ah of 2.7 Ah, the profiles start at 80 %."""
    plan = Plan.load(EXAMPLES / "plan.toml")
    steps = plan.protocol.steps
    discharge = next(s for s in steps if s.kind.value == "cc")
    removed = next(e.value for e in discharge.ends if e.quantity.value == "capacity")
    soc = 1.0 - removed / plan.protocol.capacity_ah
    first = next(s for s in steps if isinstance(s, ProfileStep))
    assert soc == pytest.approx(first.profile.soc0)
    assert steps[0].kind.value == "cccv" and steps[0].voltage == pytest.approx(4.2)


@pytest.mark.parametrize("path", PLANS, ids=lambda p: p.name)
def test_example_plan_exports_to_a_tester_format(path: Path, tmp_path: Path) -> None:
    """``battlab export`` takes a plan with a ``[run]`` table (the runner's options are not exported)."""
    from click.testing import CliRunner

    from battlab.cli import main

    r = CliRunner().invoke(main, ["export", str(path), "--format", "maccor", "-o", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert any(p.suffix == ".000" for p in tmp_path.iterdir())
