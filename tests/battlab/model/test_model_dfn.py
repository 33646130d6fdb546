"""The DFN–thermal model proven on its physics: forward sensitivities against finite differences, lithium
conservation, the open-circuit limit, and the errata of docs/decisions.md (Arrhenius sign, Bernardi heat).

All runs go through the public ``battlab.simulate``; the state-level checks read the solver's final state
through the ``solver_trajectories`` fixture (tests/conftest.py).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import battlab
from battlab import Cell, parameters
from battlab.cell import R_GAS, F
from battlab.model.dfn import C_SCALE, DFN
from battlab.model.mesh import Mesh
from battlab.model.solver import Settings
from protocols import Profile

ONE_C = 2.7  # A, nca18650
FD_STEP = 1e-5  # in θ̄
FD_RTOL = 1e-3  # relative 2-norm over time
SUBSET = ("R_s_n", "D_s_p", "k_n", "c_e0", "eps_e_p", "t_plus")
T_SUBSET = ("R_s_n", "D_s_p", "k_n", "c_e0")  # dT_surface/dθ̄ checked in the fast test


# --- profiles -----------------------------------------------------------------------------------------------
def pulse_train(duration: float = 300.0) -> Profile:
    """10 s pulses at 2C, discharge and charge in turn, 10 s rests between them, 1 s samples."""
    t = np.arange(0.0, duration + 1.0)
    phase = (t // 10.0) % 4  # 0: discharge, 1: rest, 2: charge, 3: rest
    current = np.select([phase == 0, phase == 2], [-2.0 * ONE_C, 2.0 * ONE_C], 0.0)
    return Profile(t, current)


def sinusoid(duration: float = 300.0) -> Profile:
    """A 1C, 0.1 Hz sinusoid sampled every second (zero-order hold)."""
    t = np.arange(0.0, duration + 1.0)
    return Profile(t, ONE_C * np.sin(2.0 * np.pi * 0.1 * t))


PROFILES = {"pulse train": pulse_train, "sinusoid": sinusoid}


# --- helpers ------------------------------------------------------------------------------------------------
def theta_bar(cell: Cell) -> np.ndarray:
    return np.array([cell.normalised(n) for n in parameters.NAMES])


def relative_error(exact: np.ndarray, approx: np.ndarray) -> float:
    return float(np.linalg.norm(approx - exact) / np.linalg.norm(exact))


def fd_errors(
    cell: Cell,
    prof: Profile,
    soc0: float,
    names: tuple[str, ...],
    temperature: tuple[str, ...] = (),
    settings: Settings | None = None,
) -> dict[str, float]:
    """Relative 2-norm errors of dV/dθ̄ (and dT_surface/dθ̄ for ``temperature``) against central differences
    on the same time grid, keyed ``"V name"``/``"T name"``."""
    res = battlab.simulate(cell, prof, soc0=soc0, sensitivities=list(names), settings=settings)
    assert res.ended_by is None, res.ended_by
    # the perturbed runs take the steps the base run took (error-controlled steps would move with θ̄)
    settings = replace(settings or Settings(), replay=res.steps)
    assert res.sensitivities.shape == res.sensitivities_T.shape == (prof.t.size, len(names))
    out: dict[str, float] = {}
    for j, name in enumerate(names):
        tb = cell.normalised(name)
        plus = battlab.simulate(cell.with_normalised(**{name: tb + FD_STEP}), prof, soc0=soc0, settings=settings)
        minus = battlab.simulate(cell.with_normalised(**{name: tb - FD_STEP}), prof, soc0=soc0, settings=settings)
        assert plus.ended_by is None and minus.ended_by is None
        fd_v = (plus.voltage - minus.voltage) / (2.0 * FD_STEP)
        assert np.linalg.norm(fd_v) > 1e-6, f"{name}: no voltage sensitivity to check against"
        out[f"V {name}"] = relative_error(fd_v, res.sensitivities[:, j])
        if name in temperature:
            fd_t = (plus.T_surface - minus.T_surface) / (2.0 * FD_STEP)
            assert np.linalg.norm(fd_t) > 1e-6, f"{name}: no temperature sensitivity to check against"
            out[f"T {name}"] = relative_error(fd_t, res.sensitivities_T[:, j])
    return out


def assert_small(errors: dict[str, float], tol: float = FD_RTOL) -> None:
    bad = {k: f"{v:.2e}" for k, v in errors.items() if not v <= tol}
    assert not bad, f"sensitivities off finite differences by more than {tol:g} (relative 2-norm): {bad}"


# --- sensitivities ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("profile", list(PROFILES))
def test_sensitivities_match_finite_differences_subset(nca18650: Cell, profile: str) -> None:
    """dV/dθ̄ (six representative parameters) and dT_surface/dθ̄ (four) vs central differences, ±1e-5 in θ̄."""
    assert_small(fd_errors(nca18650, PROFILES[profile](), 0.5, SUBSET, T_SUBSET))


@pytest.mark.slow
@pytest.mark.parametrize("profile", list(PROFILES))
def test_sensitivities_match_finite_differences_all_18(nca18650: Cell, profile: str) -> None:
    """All 18 dynamic parameters, voltage and surface temperature, non-isothermal."""
    assert_small(fd_errors(nca18650, PROFILES[profile](), 0.5, parameters.NAMES, parameters.NAMES))


def test_sensitivities_at_samples_inside_steps_match_finite_differences(nca18650: Cell) -> None:
    """Steps across samples (up to 5 s on a 1 s grid): interpolated samples carry the interpolated sensitivities,
    the exact derivatives of the discrete solution as at step ends."""
    t = np.arange(0.0, 241.0)
    prof = Profile(t, np.where((t // 40.0) % 2 == 0, -2.0 * ONE_C, 0.5 * ONE_C))
    across = Settings(adaptive=False, across_samples=True, growth=1.5, dt_max=5.0)
    assert_small(fd_errors(nca18650, prof, 0.5, ("R_s_n", "D_s_p", "k_n", "c_e0"), ("k_n",), across))


def test_sensitivity_columns_follow_the_order_asked(nca18650: Cell) -> None:
    prof = pulse_train(60.0)
    a = battlab.simulate(nca18650, prof, soc0=0.5, sensitivities=["k_n", "R_s_n"])
    b = battlab.simulate(nca18650, prof, soc0=0.5, sensitivities=["R_s_n"])
    np.testing.assert_allclose(a.sensitivities[:, 1], b.sensitivities[:, 0], rtol=1e-10, atol=1e-12)
    assert a.parameters == ("k_n", "R_s_n")
    assert not np.allclose(a.sensitivities[:, 0], a.sensitivities[:, 1])


def test_isothermal_run_has_no_temperature_sensitivity(nca18650: Cell) -> None:
    res = battlab.simulate(nca18650, pulse_train(60.0), soc0=0.5, isothermal=True, sensitivities=["R_s_n", "k_n"])
    assert np.all(res.T_surface == 298.15) and np.all(res.T_core == 298.15)
    np.testing.assert_array_equal(res.sensitivities_T, 0.0)
    assert np.linalg.norm(res.sensitivities) > 0.0


# --- lithium conservation and state of charge ---------------------------------------------------------------
def cycle_profile() -> Profile:
    """1C discharge 1200 s, rest 300 s, 1.5C charge 600 s, 0.5C discharge 600 s, rest 300 s (5 s samples)."""
    durations = [1200.0, 300.0, 600.0, 600.0, 300.0]
    currents = [-ONE_C, 0.0, 1.5 * ONE_C, -0.5 * ONE_C, 0.0]
    return Profile.from_segments(np.array(durations), np.array(currents))


def solid_moles(model: DFN, y: np.ndarray, electrode: str) -> float:
    """Moles of lithium in one electrode's particles at state y."""
    cell, mesh, sl = model.cell, model.mesh, model.layout.slices()
    n = mesh.n_n if electrode == "n" else mesh.n_p
    sto = np.reshape(y[sl["s" + electrode]], (n, mesh.n_r)) @ model.vol / model.vol.sum()  # per x cell
    return float(np.mean(sto)) * cell.electrode_moles(electrode)


def electrolyte_moles(model: DFN, y: np.ndarray, cell: Cell) -> float:
    m, ce = model.mesh, y[model.layout.slices()["ce"]] * C_SCALE
    total, start = 0.0, 0
    for region, n in (("n", m.n_n), ("s", m.n_s), ("p", m.n_p)):
        total += (
            float(np.sum(ce[start : start + n]))
            * float(cell[f"L_{region}"])
            / n
            * float(cell["A"])
            * float(cell[f"eps_e_{region}"])
        )
        start += n
    return total


@pytest.mark.parametrize("isothermal", [False, True])
def test_lithium_is_conserved_over_a_cycle(nca18650: Cell, solver_trajectories: list, isothermal: bool) -> None:
    """Solid + electrolyte lithium after a charge/discharge cycle equals the initial inventory to 1e-8."""
    cell, soc0 = nca18650, 0.6
    res = battlab.simulate(cell, cycle_profile(), soc0=soc0, isothermal=isothermal)
    assert res.ended_by is None
    model = DFN(cell, Mesh(), isothermal=isothermal)
    y = np.asarray(solver_trajectories[-1].final_state, float)
    sto_n, sto_p = cell.stoichiometry(soc0)
    ce_volume = sum(float(cell[f"L_{r}"]) * float(cell[f"eps_e_{r}"]) for r in "nsp") * float(cell["A"])
    initial = cell.electrode_moles("n") * sto_n + cell.electrode_moles("p") * sto_p + float(cell["c_e0"]) * ce_volume
    final = model.lithium(y, theta_bar(cell))
    assert abs(final - initial) / initial < 1e-8
    # the electrolyte keeps its own inventory (the reaction source integrates to zero over the cell) ...
    assert abs(electrolyte_moles(model, y, cell) / (float(cell["c_e0"]) * ce_volume) - 1.0) < 1e-8
    # ... while lithium did move between the electrodes: the net charge passed, ∫I dt / F (1C x 600 s out)
    moved = solid_moles(model, y, "n") - cell.electrode_moles("n") * sto_n
    assert moved == pytest.approx(-ONE_C * 600.0 / F, rel=1e-7)
    assert moved == pytest.approx(cycle_profile().net_charge * 3600.0 / F, rel=1e-7)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_state_of_charge_follows_the_coulomb_count(nca18650: Cell, solver_trajectories: list, sign: float) -> None:
    """Positive current (charge) raises both electrodes' SOC by exactly ∫I dt / capacity; negative lowers it."""
    cell, soc0 = nca18650, 0.5
    prof = Profile.from_segments(np.array([900.0, 300.0]), np.array([sign * ONE_C, 0.0]), t0=0.0)
    res = battlab.simulate(cell, prof, soc0=soc0)
    assert res.ended_by is None
    model = DFN(cell, Mesh())
    y = np.asarray(solver_trajectories[-1].final_state, float)
    n0, n1, p0, p1 = cell.stoichiometry_window()
    soc_n = (solid_moles(model, y, "n") / cell.electrode_moles("n") - n0) / (n1 - n0)
    soc_p = (solid_moles(model, y, "p") / cell.electrode_moles("p") - p0) / (p1 - p0)
    expected = soc0 + prof.net_charge / cell.capacity()
    assert expected == pytest.approx(soc0 + sign * ONE_C * 900.0 / 3600.0 / cell.capacity(), rel=1e-12)
    assert soc_n == pytest.approx(expected, abs=1e-8)
    assert soc_p == pytest.approx(expected, abs=1e-8)


# --- equilibrium ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("soc", [0.02, 0.2, 0.5, 0.8, 0.98])
@pytest.mark.parametrize("isothermal", [True, False])
def test_zero_current_gives_the_open_circuit_voltage(nca18650: Cell, soc: float, isothermal: bool) -> None:
    """At rest the terminal voltage is U⁺(θ⁺) − U⁻(θ⁻) = cell.ocv(soc), and stays there."""
    prof = Profile(np.array([0.0, 1.0, 10.0, 100.0]), np.zeros(4))
    res = battlab.simulate(nca18650, prof, soc0=soc, isothermal=isothermal)
    assert res.ended_by is None
    sto_n, sto_p = nca18650.stoichiometry(soc)
    ocv = float(nca18650.fn("U_p", sto_p) - nca18650.fn("U_n", sto_n))
    assert ocv == pytest.approx(float(nca18650.ocv(soc)), abs=1e-12)
    np.testing.assert_allclose(res.voltage, ocv, rtol=0, atol=1e-6)
    np.testing.assert_allclose(res.T_surface, 298.15, rtol=0, atol=1e-9)


def test_zero_current_ocv_of_a_bpx_cell(nmc_bpx: Path) -> None:
    cell = Cell.from_bpx(nmc_bpx)
    for soc in (0.1, 0.5, 0.9):
        res = battlab.simulate(cell, Profile(np.array([0.0, 10.0]), np.zeros(2)), soc0=soc, isothermal=True)
        np.testing.assert_allclose(res.voltage, float(cell.ocv(soc)), rtol=0, atol=1e-6)


# --- errata: Arrhenius sign, Bernardi heat ----------------------------------------------------------------------
ENERGIES = ("E_D_s_n", "E_D_s_p", "E_k_n", "E_k_p", "E_D_e", "E_kappa")


@pytest.fixture(scope="module")
def flat(nca18650: Cell) -> Cell:
    """The cell with every activation energy 0: no Arrhenius dependence at all (one compiled model)."""
    return nca18650.with_values(**{e: 0.0 for e in ENERGIES})


def test_transport_and_kinetics_speed_up_when_hot(nca18650: Cell, flat: Cell) -> None:
    """Arrhenius with the corrected sign (docs/decisions.md): with E > 0, D_s, D_e, κ and k are larger above T_ref and
    smaller below it, so the overpotentials shrink when hot and grow when cold, compared with the same cell
    without temperature dependence."""
    assert all(float(nca18650[e]) > 0.0 for e in ENERGIES)
    dis = Profile.constant(-ONE_C, 600.0, 10.0)
    chg = Profile.constant(ONE_C, 600.0, 10.0)

    def v(cell: Cell, prof: Profile, ambient: float) -> np.ndarray:
        res = battlab.simulate(cell, prof, soc0=0.5, ambient=ambient, isothermal=True)
        assert res.ended_by is None
        return res.voltage

    # at T_ref the activation energies do nothing
    np.testing.assert_allclose(v(nca18650, dis, 298.15), v(flat, dis, 298.15), rtol=0, atol=1e-9)
    hot, cold = 318.15, 278.15
    # discharge: a smaller overpotential is a higher voltage; charge: a lower one
    assert np.all(v(nca18650, dis, hot) - v(flat, dis, hot) > 1e-3)
    assert np.all(v(nca18650, chg, hot) - v(flat, chg, hot) < -1e-3)
    assert np.all(v(nca18650, dis, cold) - v(flat, dis, cold) < -1e-3)


@pytest.mark.parametrize("ambient", [273.15, 318.15])
def test_a_films_resistance_is_its_reference_value_over_the_arrhenius_factor(flat: Cell, ambient: float) -> None:
    """R_f(T) = R_f,ref / exp[(E/R)(1/T_ref − 1/T)] (a film's ionic conduction is thermally activated): at a fixed
    temperature, the cell with E_R_f± is the cell without them whose R_f± are scaled by that factor, to round-off;
    and the cold film's drop is the larger."""
    E = {"E_R_f_n": 58.9e3, "E_R_f_p": 40e3}
    activated = flat.with_values(**E)
    factor = {e: float(np.exp(E[f"E_R_f_{e}"] / R_GAS * (1 / 298.15 - 1 / ambient))) for e in ("n", "p")}
    scaled = flat.with_values(**{f"R_f_{e}": float(flat[f"R_f_{e}"]) / factor[e] for e in ("n", "p")})
    prof = Profile.constant(-ONE_C, 300.0, 10.0)
    va, vs, vf = (
        battlab.simulate(c, prof, soc0=0.5, ambient=ambient, isothermal=True).voltage for c in (activated, scaled, flat)
    )
    np.testing.assert_allclose(va, vs, rtol=0, atol=1e-9)
    # on discharge a larger film drop is a lower voltage: colder than T_ref the films resist more, hotter less
    assert np.all((va - vf) * (ambient - 298.15) > 1e-4)


@pytest.mark.parametrize("electrode", ["n", "p"])
def test_hotter_ambient_gives_a_smaller_diffusion_overpotential(nca18650: Cell, flat: Cell, electrode: str) -> None:
    """D_s rises with T: the diffusion overpotential (here the voltage lost when D_s is halved) shrinks as the
    ambient warms. Without Arrhenius factors it hardly moves, so the trend is D_s's own."""
    name = f"D_s_{electrode}"
    prof = Profile.constant(-ONE_C, 600.0, 10.0)

    def loss(cell: Cell, ambient: float) -> float:
        fast = battlab.simulate(cell, prof, soc0=0.5, ambient=ambient, isothermal=True)
        slow = battlab.simulate(
            cell.with_values(**{name: 0.5 * float(cell[name])}), prof, soc0=0.5, ambient=ambient, isothermal=True
        )
        return float(fast.voltage[-1] - slow.voltage[-1])

    cold, ref, hot = (loss(nca18650, T) for T in (283.15, 298.15, 313.15))
    assert 0.0 < hot < ref < cold
    assert abs(loss(flat, 313.15) - loss(flat, 283.15)) < 0.25 * (cold - hot)


@pytest.mark.parametrize("direction", [-1.0, 1.0], ids=["discharge", "charge"])
def test_irreversible_heat_warms_the_cell_both_ways(nca18650: Cell, direction: float) -> None:
    """With zero entropic coefficients only the irreversible heat I(U − V) remains: it is ≥ 0 for charge and
    discharge alike (Bernardi; the paper's B3 as printed cools the cell on charge)."""
    cell = nca18650.with_values(dUdT_n="0", dUdT_p="0")
    ambient = 298.15
    prof = Profile.constant(direction * 2.0 * ONE_C, 600.0, 5.0)
    res = battlab.simulate(cell, prof, soc0=0.5 - 0.1 * direction, ambient=ambient, isothermal=False)
    assert res.ended_by is None
    assert res.T_core[0] == pytest.approx(ambient, abs=1e-12)
    assert np.all(np.diff(res.T_core) >= -1e-12)  # heats monotonically from ambient
    assert np.all(res.T_core >= res.T_surface - 1e-12)  # the heat flows out through the surface
    assert res.T_core[-1] - ambient > 0.3
    assert res.T_surface[-1] - ambient > 0.1


def test_entropic_heat_changes_sign_with_the_current(nca18650: Cell) -> None:
    """The reversible heat −I T ∂U/∂T flips with the current: the temperature difference it makes (cell with vs
    without entropic coefficients) has opposite signs on charge and discharge."""
    flat = nca18650.with_values(dUdT_n="0", dUdT_p="0")
    diffs = []
    for direction in (-1.0, 1.0):
        prof = Profile.constant(direction * ONE_C, 300.0, 10.0)
        a = battlab.simulate(nca18650, prof, soc0=0.5)
        b = battlab.simulate(flat, prof, soc0=0.5)
        diffs.append(a.T_core[-1] - b.T_core[-1])
    assert abs(diffs[0]) > 1e-3 and abs(diffs[1]) > 1e-3
    assert np.sign(diffs[0]) == -np.sign(diffs[1])


def test_constant_functions_as_numbers_or_strings(nca18650: Cell) -> None:
    """A function-valued parameter given as a constant expression string ("0") is the same model as the number
    (here the activity term d ln f / d ln c_e; a number 0 is what BPX cells carry)."""
    prof = pulse_train(60.0)
    ref = battlab.simulate(nca18650.with_values(dlnf_scale=0.0), prof, soc0=0.5, isothermal=True)
    res = battlab.simulate(nca18650.with_values(dlnf="0"), prof, soc0=0.5, isothermal=True)
    np.testing.assert_allclose(res.voltage, ref.voltage, rtol=0, atol=1e-9)
