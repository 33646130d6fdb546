"""Extension parameters the data cannot inform are refused before a fit, with the experiment that would inform
them: activation-energy changes at one ambient, hysteresis without a rest after charge and after discharge or a
reversal of the current that sweeps its state."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from battlab.identify.experiments import Experiment
from battlab.identify.informing import check_informed, uninformed
from protocols import Profile
from protocols.errors import InputError


def _exp(current: list[tuple[float, float]], ambient_C: float = 25.0) -> Experiment:
    """Piecewise-constant (current [A], duration [s]) at 1 s samples."""
    i = np.concatenate([np.full(int(d), c) for c, d in current])
    t = np.arange(i.size, dtype=float)
    return Experiment("e", Profile(t, i, id="e"), np.full(i.size, 3.7), 0.5, 1e-8, ambient=ambient_C + 273.15)


def test_activation_energies_need_two_ambients() -> None:
    one = [_exp([(-2.7, 600), (0.0, 600)]), _exp([(-1.0, 600)], 27.0)]
    assert set(uninformed(["thermal.dE_D_s_n", "thermal.h2a_scale", "R_f_n"], one, 0.027)) == {"thermal.dE_D_s_n"}
    two = [*one, _exp([(-2.7, 600)], 10.0)]
    assert uninformed(["thermal.dE_D_s_n"], two, 0.027) == {}


def test_hysteresis_needs_a_rest_after_charge_and_after_discharge_or_a_reversal() -> None:
    names = ["hysteresis.M_n", "hysteresis.gamma_n"]
    discharge_only = [_exp([(-2.7, 300), (0.0, 600), (-2.7, 300), (0.0, 600)])]
    assert set(uninformed(names, discharge_only, 0.027)) == set(names)
    # a short charge (2.7 A for 30 s: 0.0225 Ah, below 1 % of the 2.7 Ah capacity) barely moves the state
    brief_charge = [_exp([(-2.7, 300), (0.0, 600), (2.7, 30), (-2.7, 30)])]
    assert set(uninformed(names, brief_charge, 0.027)) == set(names)
    # a square wave of 0.0833 Ah half-periods (3 % of the capacity) sweeps it, with no rest at all
    square = [_exp([(2.7, 111), (-2.7, 111)] * 3)]
    assert uninformed(names, square, 0.027) == {}
    both = [_exp([(-2.7, 300), (0.0, 120)]), _exp([(2.7, 300), (0.0, 120)])]
    assert uninformed(names, both, 0.027) == {}
    with pytest.raises(
        InputError, match=r"hysteresis.M_n \(and hysteresis.gamma_n\): not identifiable .* followed by a rest"
    ):
        check_informed(names, discharge_only, 0.027)


def test_fit_refuses_activation_energies_on_one_ambient_in_one_line(hidden_effect_csv, tmp_path) -> None:
    from battlab.cli import main

    data = hidden_effect_csv(tmp_path / "udds.bdf.csv")
    r = CliRunner().invoke(
        main,
        ["fit", data, "--cell", "nca18650", "--extension", "thermal", "--params", "thermal.dE_D_s_n,R_f_n"]
        + ["-o", str(tmp_path / "out.bpx.json")],
    )
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "thermal.dE_D_s_n: not identifiable from these data" in lines[0], r.output
    assert "two ambient temperatures" in lines[0] and "Traceback" not in r.output
    assert not (tmp_path / "out.bpx.json").exists()
