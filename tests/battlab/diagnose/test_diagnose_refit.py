"""Which base parameters the diagnosis refits beside an extension: never one the cell holds outside its search
range (a fit would start it clipped to the bound, worse than the cell)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def test_base_parameters_held_outside_their_range_are_not_refitted(nmc_bpx: Path) -> None:
    """The BPX cell's transference number (0.259), conductivities and rate constants lie outside the built-in
    ranges; even when their directions explain the residual best, the refitted ones are the most relevant of those
    inside (before, t_plus was refitted from 0.36, its bound: on PyBaMM's plain DFN the base fit's held-out RMSE
    rose from the cell's 0.43 mV to 0.97 mV)."""
    from battlab import Cell, parameters
    from battlab.diagnose.workflow import N_BASE, refit_names

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
    assert len(chosen) == N_BASE and not set(chosen) & set(outside), chosen
    assert chosen == ("D_s_n", "eps_e_p", "D_e_scale")
