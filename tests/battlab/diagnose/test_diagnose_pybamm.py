"""``battlab diagnose`` on data made by another model: PyBaMM's DFN (lumped thermal) on the BPX NMC pouch cell,
cooled at 10 W m⁻² K⁻¹, with one of PyBaMM's own options as the hidden effect, 50 min at 1 s of pulses with rests
and UDDS, the virtual tester's noise, written as BDF CSV and diagnosed through the CLI with the same BPX file
(benchmarks/pybamm_effects.py makes the data and runs every case).

The diagnosis must name the hidden cause, or name none while listing it among the causes that pass their score
test; it must never name another cause, and on PyBaMM's plain DFN (0.35 mV RMSE from battlab's, the noise about
0.2 mV) it must name nothing. PyBaMM takes about a minute per case here: the data are made once per module, and
only the null and the hysteresis run here (about 4 min on 2 loaded cores); the benchmark runs the other causes."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.conftest import reference

reference("pybamm")

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import pybamm_effects as pe  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory, nmc_bpx: Path) -> Callable[[str], tuple[Path, Any]]:
    """``made(case)``: (the BDF CSV of ``case``, PyBaMM's noise-free solution), made on first use."""
    assert pe.BPX.resolve() == nmc_bpx.resolve()
    folder = tmp_path_factory.mktemp("pybamm_effects")
    from battlab import Cell

    prof = pe.profile(float(Cell.from_bpx(pe.cell_file(folder))["Q_nom"]))
    cache: dict[str, tuple[Path, Any]] = {}

    def make(name: str) -> tuple[Path, Any]:
        if name not in cache:
            truth = pe.solve(pe.CASES[name], prof)
            cache[name] = (pe.write_case(truth, folder / f"{name}.bdf.csv", name), truth)
        return cache[name]

    return make


@pytest.fixture(scope="module")
def cell_file(tmp_path_factory: pytest.TempPathFactory, nmc_bpx: Path) -> Path:
    return pe.cell_file(tmp_path_factory.mktemp("cell"))


def test_pybamm_is_fed_the_profile_exactly_and_matches_battlab_within_half_a_millivolt(made, cell_file) -> None:
    """PyBaMM's discharge capacity equals the integral of the zero-order-hold current, and its plain DFN is within
    0.5 mV RMSE of battlab's on the same BPX file (measured 0.35 mV: the null case's model difference, above the
    noise). An upper bound only: battlab closer to PyBaMM passes."""
    import battlab
    from battlab import Cell

    _, truth = made("null")
    assert truth.charge_error_Ah < 1e-6
    cell = Cell.from_bpx(cell_file)
    res = battlab.simulate(cell, pe.profile(float(cell["Q_nom"])), soc0=pe.SOC0, ambient=pe.AMBIENT_K)
    assert res.voltage.size == truth.voltage.size
    rmse = 1e3 * float(np.sqrt(np.mean((res.voltage - truth.voltage) ** 2)))
    assert rmse < 0.5, rmse
    assert abs(float(res.T_core.max()) - float(truth.temperature.max())) < 0.5  # K: cooled, a 3 K rise


def _null_named_on_a_small_win() -> bool:
    from battlab.diagnose import workflow

    return workflow.MIN_GAIN < 0.1


@pytest.mark.parametrize(
    "case",
    [
        pytest.param(
            "null",
            marks=pytest.mark.xfail(
                _null_named_on_a_small_win(),
                reason="PyBaMM's plain DFN differs from battlab's by 0.35 mV, twice the noise: a fitted current-sensor "
                "gain wins 12 % on held-out data (0.41 -> 0.36 mV), which a 2 % naming rule takes for a cause",
                strict=True,
            ),
        ),
        "hysteresis",
        "capacity_fade",
    ],
)
def test_the_diagnosis_of_pybamm_data_names_the_hidden_cause_or_nothing(case, made, cell_file, tmp_path) -> None:
    """Through the CLI: the hidden cause named, or none named with the hidden one among those the data cannot tell;
    never another cause (measured: hysteresis named, held-out RMSE 1.61 -> 0.37 mV; PyBaMM's reaction-limited SEI
    named capacity_fade, 10.3 -> 1.6 mV)."""
    csv, _ = made(case)
    summary, _ = pe.diagnose_cli(csv, cell_file, tmp_path / "report")
    s2 = summary["residual"]["s2"]
    # the noise level is the log's own: the null's 0.35 mV model difference is a few times the noise (measured s²
    # 5.1; bounded above only, as a battlab closer to PyBaMM lowers it), a 10 mV hysteresis far above it (135)
    assert (s2 < 20.0) if case == "null" else (s2 > 20.0), s2
    verdict = pe.judge(pe.CASES[case], summary)
    assert verdict in ("right", "honest"), (verdict, summary["cause"], summary["ranking"][:3], summary["verdict"])
