"""The plan's SOC and voltage window, checked on the start cell before any hardware moves (battlab.lab.window).

Library profile 304 (pulses, 1 Ah net discharge from SOC 0.4) ends at SOC 0.03: the start cell nca18650 still
carries it at 2.65 V, the virtual truth nca18650-true reaches 2.45 V after 2782 s and the run aborts hours in.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import tomli_w
from click.testing import CliRunner

import battlab
from battlab.cli import main
from battlab.design.plan import grouped_protocol
from battlab.io.plan import Plan
from battlab.lab.catalog import Catalog
from battlab.lab.window import check_window, needs_start_soc
from protocols import Library
from protocols.errors import InputError
from protocols.protocol import ProfileStep, Protocol


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library.build()


def _plan(path: Path, protocol: Protocol) -> Path:
    data = protocol.to_dict()
    data["run"] = {"stable_hold_s": 0.0}
    path.write_text(tomli_w.dumps(data))
    return path


def test_a_profile_that_drains_the_cell_past_its_window_is_named(lib: Library) -> None:
    proto = grouped_protocol("p", [(1, [lib[304], lib[1]])], "")
    cell = battlab.Cell.load("nca18650")
    assert not needs_start_soc(proto, cell)  # it starts with a full charge
    rep = check_window(proto, cell)
    assert [p.profile_id for p in rep.profiles] == [304, 1]
    bad, good = rep.profiles
    assert bad.soc_start == pytest.approx(0.4, abs=1e-3) and bad.soc_min == pytest.approx(0.03, abs=5e-3)
    assert bad.problem is not None and "SOC 0.030" in bad.problem and good.problem is None
    assert good.soc_start == pytest.approx(float(cell.soc_from_voltage(3.9481)), abs=1e-6)  # CCCV to Table 5's OCV
    with pytest.raises(InputError, match=r"^plan\.toml: step 5 \(group 1: profile 304\): from SOC 0\.400"):
        rep.raise_if_bad("plan.toml")


def test_a_plan_starting_from_rest_needs_its_start_soc(lib: Library) -> None:
    proto = Protocol("p", (ProfileStep(lib[1], "profile 1"),))
    cell = battlab.Cell.load("nca18650")
    assert needs_start_soc(proto, cell)
    with pytest.raises(InputError, match="before any step that sets the SOC"):
        check_window(proto, cell)
    assert check_window(proto, cell, start_soc=0.8).ok  # its own start: 0.8 -> 0.43
    low = check_window(proto, cell, start_soc=0.35)  # 1 Ah from 0.35 empties the cell
    assert not low.ok and "step 1 (profile 1)" in low.problems[0]


def test_run_rejects_the_plan_before_anything_is_recorded(
    lib: Library, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("BATTLAB_HOME", str(tmp_path / "home"))
    plan = _plan(tmp_path / "plan.toml", grouped_protocol("p", [(1, [lib[304]])], ""))
    out = tmp_path / "run.h5"
    args = ["run", str(plan), "--cycler", "virtual", "--chamber", "virtual", "--quiet", "-o", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output
    assert isinstance(r.exception, SystemExit)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "profile 304" in lines[0] and "outside [0.05, 0.95]" in lines[0], lines
    assert not out.exists() and Catalog().list() == []


def test_a_real_bench_checks_the_window_at_the_measured_rest_voltage(lib: Library, tmp_path: Path) -> None:
    from battlab.lab.bench import RunSettings
    from battlab.lab.session import _window_check

    plan = Plan.load(_plan(tmp_path / "plan.toml", Protocol("p", (ProfileStep(lib[1], "profile 1"),))))
    cell = battlab.Cell.load("nca18650")
    settings = RunSettings(cycler_url="socket://127.0.0.1:1", chamber_url="modbus-tcp://127.0.0.1:2")
    at_rest = _window_check(plan, cell, settings)
    assert at_rest is not None
    at_rest(float(cell.ocv(0.8)))  # its own start SOC: within the window
    with pytest.raises(InputError, match=r"rest voltage 3\.5"):
        at_rest(float(cell.ocv(0.35)))
