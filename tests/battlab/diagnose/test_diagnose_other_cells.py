"""The diagnosis of cells other than the paper's 2.7 Ah NCA (the 12.5 Ah BPX pouch cell): base parameters the cell
holds outside the built-in ranges are refitted from its own values, never from a bound; a refit stays inside the
physical region; the noise level is the one the data show, not the paper's regression's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def test_base_parameters_held_outside_their_range_are_refitted_from_the_cells_own_values(nmc_bpx: Path) -> None:
    """The BPX cell's transference number (0.259), conductivities and rate constants lie outside the built-in ranges
    (the paper cell's). When their directions explain the residual best they are the ones refitted, each over a box
    that holds the cell's own value (before, such parameters were left out, and a fit of one started clipped to the
    range: t_plus from 0.36, which on PyBaMM's plain DFN raised the held-out RMSE from the cell's 0.43 to 0.97 mV;
    PyBaMM's reaction rates × 0.3 could then not be refitted, and were named nothing at 50 mV)."""
    from battlab import Cell, parameters
    from battlab.diagnose.confirm import WIDEN
    from battlab.diagnose.workflow import N_BASE, refit_names
    from battlab.identify.fit import search_box

    cell = Cell.from_bpx(nmc_bpx)
    names = parameters.NAMES
    outside = [n for n in names if not 0.0 <= cell.normalised(n) <= 1.0]
    assert {"t_plus", "k_n", "k_p", "sigma_n"} <= set(outside)
    rng = np.random.default_rng(0)
    J = rng.standard_normal((500, len(names)))
    weight = {n: 1.0 for n in names}
    weight.update({"t_plus": 5.0, "k_n": 4.0, "sigma_p": 3.5, "D_s_n": 3.0, "eps_e_p": 2.0, "D_e_scale": 1.5})
    r = J @ np.array([weight[n] for n in names])
    chosen = refit_names(cell, J, r, np.ones(500), names)
    assert len(chosen) == N_BASE and chosen == ("t_plus", "k_n", "sigma_p"), chosen
    lower, upper = search_box(cell, chosen, WIDEN)
    theta = np.array([cell.normalised(n) for n in chosen])
    assert np.all(lower < theta) and np.all(theta < upper)
    # a film resistance of 0 lies just below its range: it is refitted, from 0, and never below it
    weight["R_f_p"] = 8.0
    r = J @ np.array([weight[n] for n in names])
    assert refit_names(cell, J, r, np.ones(500), names)[0] == "R_f_p"
    (lo,), _ = search_box(cell, ["R_f_p"], WIDEN)
    assert parameters.spec("R_f_p").denormalise(float(lo)) == pytest.approx(0.0, abs=1e-15)


def test_a_volume_fraction_is_refitted_inside_the_room_the_active_material_leaves(nmc_bpx: Path) -> None:
    """The BPX cell's eps_s_n is 0.69: eps_e_n's range reaches 0.45, where the pores and solid overfill the electrode
    (a fit that tried it once stopped the whole diagnosis with an input error, PyBaMM's SEI case). Its search box
    ends where the electrode is full, so it is refitted, and every cell in the box is a possible one."""
    from battlab import Cell, parameters
    from battlab.diagnose.confirm import WIDEN, fittable
    from battlab.diagnose.workflow import refit_names
    from battlab.identify.fit import search_box

    cell = Cell.from_bpx(nmc_bpx)
    names = parameters.NAMES
    assert 0.0 <= cell.normalised("eps_e_n") <= 1.0
    J = np.random.default_rng(1).standard_normal((400, len(names)))
    r = J[:, names.index("eps_e_n")] * 5.0 + J[:, names.index("c_e0")]
    chosen = refit_names(cell, J, r, np.ones(400), names)
    assert chosen[:2] == ("eps_e_n", "c_e0") and fittable(cell, "eps_e_n"), chosen
    _, (hi,) = search_box(cell, ["eps_e_n"], WIDEN)
    top = parameters.spec("eps_e_n").denormalise(float(hi))
    assert top + float(cell["eps_s_n"]) < 1.0 < parameters.spec("eps_e_n").upper + float(cell["eps_s_n"])
    cell.with_values(eps_e_n=top)  # a possible cell


def test_the_noise_variance_is_measured_on_the_log() -> None:
    """Second differences over steady samples: within 10 % of the true level on a log with steps, relaxations,
    current-dependent noise and 100 µV quantisation; NaN with too few steady samples."""
    from battlab.diagnose.residuals import measured_noise_variance

    rng = np.random.default_rng(1)
    t = np.arange(3000.0)
    phase = (t // 120) % 3
    i = np.select([phase == 0, phase == 1], [-25.0, 0.0], 10.0) + rng.normal(0.0, 2e-4, t.size)
    v = 3.7 + 0.02 * np.sin(t / 300.0) + 1e-3 * i * (1.0 - np.exp(-(t % 120) / 20.0))
    sigma = 50e-6 + 20e-6 * np.abs(i)
    y = np.round((v + sigma * rng.standard_normal(t.size)) / 1e-4) * 1e-4
    true = float(np.mean(sigma**2) + 1e-8 / 12.0)
    assert measured_noise_variance(y, i, 0.125) == pytest.approx(true, rel=0.2)
    assert np.isnan(measured_noise_variance(y[:20], i[:20], 0.125))


@pytest.mark.slow
def test_a_bpx_cell_log_at_its_own_noise_gives_s2_near_one(nmc_bpx: Path, tmp_path: Path) -> None:
    """battlab's own simulation of the BPX cell plus 0.2 mV white noise, diagnosed with the same cell: s² ≈ 1 and no
    cause (the paper's noise regression put this 12.5 Ah cell's noise at over 1 V: s² was 1e-7)."""
    import battlab
    from battlab.diagnose.workflow import DiagnoseOptions, diagnose
    from battlab.io.bdf import write_bdf_csv
    from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE, LoggedData
    from protocols import Profile

    cell = battlab.Cell.from_bpx(nmc_bpx)
    q = float(cell["Q_nom"])
    steps = Profile.from_segments(np.tile([60.0, 240.0, 60.0, 240.0], 3), np.tile([-2.0, 0.0, 1.5, 0.0], 3) * q)
    t = np.arange(0.0, 1801.0)
    prof = Profile(t, steps.value_at(t))
    v = battlab.simulate(cell, prof, soc0=0.6, ambient=298.15).voltage
    y = np.round((v + 2e-4 * np.random.default_rng(3).standard_normal(v.size)) / 1e-4) * 1e-4
    cols = {TIME: t, VOLTAGE: y, CURRENT: prof.current, AMBIENT: np.full(t.size, 25.0)}
    path = write_bdf_csv(LoggedData("own", cols, {"soc0": 0.6}), tmp_path / "own.bdf.csv")
    s = diagnose(DiagnoseOptions([path], nmc_bpx)).summary
    assert 0.7 < s["residual"]["s2"] < 1.5, s["residual"]
    assert s["cause"] is None, s["verdict"]
