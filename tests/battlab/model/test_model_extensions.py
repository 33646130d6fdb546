"""Model extensions: exact sensitivities w.r.t. their parameters (against central differences on the same steps),
the base model reproduced at their "off" values, the option set in the compiled stepper's cache key, and the
cell API that carries them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import battlab
from battlab import Cell, causes, parameters
from battlab.model import solver
from battlab.model.extensions import CATALOG, ModelOptions
from battlab.model.mesh import Mesh
from battlab.model.solver import Settings
from protocols import Profile
from protocols.errors import InputError

ONE_C = 2.7  # A, nca18650
FD_STEP = 1e-5  # in θ̄
FD_RTOL = 1e-3  # relative 2-norm over time
AMBIENT = 283.15  # K: away from T_ref, so that every temperature dependence shows

#: per extension: values that switch it on (for the FD check away from "off"), as each cause declares them
ON = {c.key: dict(c.example) for c in causes.extended()}


def pulses(duration: float = 400.0) -> Profile:
    """20 s pulses at 2C, discharge and charge in turn with rests between them, 1 s samples."""
    t = np.arange(0.0, duration + 1.0)
    phase = (t // 20.0) % 4
    return Profile(t, np.select([phase == 0, phase == 2], [-2.0 * ONE_C, 2.0 * ONE_C], 0.0))


@pytest.fixture(scope="module")
def nca() -> Cell:
    return Cell.load("nca18650")


def fd_errors(
    cell: Cell, prof: Profile, soc0: float, names: tuple[str, ...], dormant: tuple[str, ...] = ()
) -> dict[str, float]:
    """Relative 2-norm errors of dV/dθ̄ against central differences on the steps of the base run; ``dormant``
    parameters may have no effect here (then both must be 0)."""
    res = battlab.simulate(cell, prof, soc0=soc0, ambient=AMBIENT, sensitivities=list(names))
    assert res.ended_by is None, res.ended_by
    settings = replace(Settings(), replay=res.steps)
    out = {}
    for j, name in enumerate(names):
        tb = cell.normalised(name)
        kw = {"soc0": soc0, "ambient": AMBIENT, "settings": settings}
        plus = battlab.simulate(cell.with_normalised(**{name: tb + FD_STEP}), prof, **kw)
        minus = battlab.simulate(cell.with_normalised(**{name: tb - FD_STEP}), prof, **kw)
        fd = (plus.voltage - minus.voltage) / (2.0 * FD_STEP)
        if np.linalg.norm(fd) <= 1e-9 and name in dormant:  # e.g. a hysteresis rate while its width is 0
            assert np.linalg.norm(res.sensitivities[:, j]) <= 1e-9, f"{name}: FD 0, exact not"
            continue
        assert np.linalg.norm(fd) > 1e-6, f"{name}: no voltage sensitivity to check against"
        out[name] = float(np.linalg.norm(res.sensitivities[:, j] - fd) / np.linalg.norm(fd))
    return out


#: the voltage is not differentiable at C_dl = 0: for any C_dl > 0 the right limit at a current step holds the
#: charge-transfer overpotential (the capacitor), at 0 it jumps; the score test needs a small positive reference
SINGULAR_OFF = {c.key for c in causes.extended() if not c.differentiable_at_off}


@pytest.mark.parametrize(
    ("key", "where"), [(k, w) for w in ("on", "off") for k in CATALOG if not (w == "off" and k in SINGULAR_OFF)]
)
def test_extension_sensitivities_match_finite_differences(nca: Cell, key: str, where: str) -> None:
    cell = nca.with_extension(key, **(ON[key] if where == "on" else {}))
    names = tuple(p.qualified for p in parameters.EXTENSIONS[key]) + ("R_s_n", "k_p")
    # at "off", a parameter that only shapes the effect (not its size) has none
    dormant = tuple(p.qualified for p in parameters.EXTENSIONS[key] if where == "off" and p.shapes)
    errors = fd_errors(cell, pulses(), 0.6, names, dormant)
    bad = {k: f"{v:.2e}" for k, v in errors.items() if not v <= FD_RTOL}
    assert not bad, f"{key} ({where}): sensitivities off finite differences: {bad}"


@pytest.mark.parametrize("key", list(CATALOG))
def test_extension_at_its_off_values_is_the_base_model(nca: Cell, key: str) -> None:
    prof = pulses()
    base = battlab.simulate(nca, prof, soc0=0.6, sensitivities=["R_s_n", "c_e0"])
    # on the base run's steps: an extension's own states take part in the error control and move the steps (by
    # less than the scheme's error: up to 0.04 mV with hysteresis on these pulses)
    same_steps = replace(Settings(), replay=base.steps)
    off = battlab.simulate(
        nca.with_extension(key), prof, soc0=0.6, sensitivities=["R_s_n", "c_e0"], settings=same_steps
    )
    assert off.ended_by is None
    # to round-off: Newton stops at a residual of 1e-9 (scaled) on a system with more unknowns
    np.testing.assert_allclose(off.voltage, base.voltage, rtol=0, atol=1e-10)
    np.testing.assert_allclose(off.T_surface, base.T_surface, rtol=0, atol=1e-10)
    np.testing.assert_allclose(off.sensitivities, base.sensitivities, rtol=0, atol=1e-9)


def test_contact_resistance_drops_the_voltage_by_r_i(nca: Cell) -> None:
    prof = pulses(60.0)
    base = battlab.simulate(nca, prof, soc0=0.6, isothermal=True)
    res = battlab.simulate(nca.with_extension("contact_resistance", R_c=0.01), prof, soc0=0.6, isothermal=True)
    np.testing.assert_allclose(res.voltage - base.voltage, 0.01 * prof.current, atol=1e-12)


def test_current_sensor_offset_is_a_current_the_cell_carries_at_rest(nca: Cell) -> None:
    """A logged rest with a sensor offset of +0.05 A: the cell is discharged by 0.05 A (the log reads 0)."""
    prof = Profile(np.arange(0.0, 3601.0, 60.0), np.zeros(61))
    res = battlab.simulate(nca.with_extension("current_sensor", offset=0.05), prof, soc0=0.5, isothermal=True)
    ref = battlab.simulate(nca, Profile(prof.t, np.full(61, -0.05)), soc0=0.5, isothermal=True)
    np.testing.assert_allclose(res.voltage, ref.voltage, rtol=0, atol=1e-9)


def test_side_reaction_consumes_cyclable_lithium_at_i_side_over_f(nca: Cell) -> None:
    """An hour at rest with I_side = 10 mA: the cell's lithium (solid + electrolyte) falls by I_side t / F, all of
    it from the negative electrode, and the voltage falls as in a self-discharge."""
    from battlab.cell import F

    cell = nca.with_extension("capacity_fade", I_side=0.01)
    t = np.arange(0.0, 3601.0, 60.0)
    stepper = solver.native_stepper(cell, Mesh(), True)
    th = cell.theta_bar()
    limits = {"V_min": 2.0, "V_max": 4.5, "T_max": 400.0}
    traj = solver.run_native(stepper, t, np.zeros(t.size), 298.15, th, 0.5, 298.15, [], Settings(), limits)
    model = stepper.model
    x0 = solver.initial_state(model, 0.5, th, 298.15)
    lost = model.lithium(x0, th[:18]) - model.lithium(traj.final_state, th[:18])
    assert lost == pytest.approx(0.01 * 3600.0 / F, rel=1e-6)
    assert traj.voltage[-1] < traj.voltage[0] - 1e-4


def test_option_sets_compile_separately_and_are_cached(nca: Cell) -> None:
    on = nca.with_extension("contact_resistance", R_c=0.001)
    a = solver.native_stepper(nca, Mesh(), False)
    b = solver.native_stepper(on, Mesh(), False)
    assert a is not b and b.model.n_theta == 20
    assert solver.native_stepper(nca.with_extension("contact_resistance", R_c=0.002), Mesh(), False) is b
    assert ModelOptions.of(on).parameter_names[-2:] == ("contact_resistance.R_c", "contact_resistance.dRc_dT")


def test_cell_carries_its_extensions(nca: Cell) -> None:
    cell = nca.with_extension("contact_resistance", R_c=0.0015)
    assert cell.extensions == {"contact_resistance": {"R_c": 0.0015, "dRc_dT": 0.0}}
    assert nca.extensions == {}
    moved = cell.with_values(D_s_n=3e-14).with_normalised(**{"contact_resistance.R_c": 0.5})
    assert moved.extensions["contact_resistance"]["R_c"] == pytest.approx(0.01)
    assert moved.value("contact_resistance.R_c") == pytest.approx(0.01)
    assert cell.hash() != nca.hash() and cell.static_hash() != nca.static_hash()
    assert cell.static_hash() == moved.static_hash()
    assert cell.without_extension("contact_resistance").hash() == nca.hash()
    import pickle

    assert pickle.loads(pickle.dumps(cell)).extensions == cell.extensions


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda c: c.with_extension("warp_drive"), "unknown model extension 'warp_drive'"),
        (lambda c: c.with_extension("contact_resistance", R_x=1.0), "has no parameter 'R_x'"),
        (lambda c: c.with_extension("current_sensor", gain=-1.5), "gain must be above -1"),
        (lambda c: c.with_values(**{"contact_resistance.R_c": 0.1}), "extension 'contact_resistance' is not on"),
    ],
)
def test_bad_extension_input_is_one_clear_error(nca: Cell, call, match: str) -> None:
    with pytest.raises(InputError, match=match):
        call(nca)


def test_activation_energies_to_fit_in_an_isothermal_simulation_is_one_clear_error(nca: Cell) -> None:
    with pytest.raises(InputError, match="'thermal' acts through the temperature"):
        battlab.simulate(nca.with_extension("thermal"), pulses(20.0), soc0=0.5, isothermal=True)


def test_sensitivity_to_an_extension_that_is_off_is_refused(nca: Cell) -> None:
    with pytest.raises(InputError, match="extension 'contact_resistance' is not on"):
        battlab.simulate(nca, pulses(20.0), soc0=0.5, sensitivities=["contact_resistance.R_c"])


def test_bpx_keeps_the_extensions(nca: Cell, tmp_path) -> None:
    cell = nca.with_extension("contact_resistance", R_c=0.0015).with_extension("current_sensor", offset=-0.01)
    back = Cell.from_bpx(cell.to_bpx(tmp_path / "cell.json"))
    assert back.extensions == cell.extensions
    assert list(back.extensions) == ["contact_resistance", "current_sensor"]
    assert Cell.from_bpx(nca.to_bpx(tmp_path / "base.json")).extensions == {}


def test_a_fit_recovers_extension_parameters_with_the_base_ones(nca: Cell) -> None:
    """The fit machinery takes KEY.NAME like the 18: a contact resistance and a sensor offset hidden in synthetic
    data are found with R_f_n, from the base values."""
    from battlab.identify import fit as F
    from battlab.identify.experiments import Experiment
    from battlab.identify.forward import DT_FIRST

    truth = nca.with_extension("contact_resistance", R_c=0.006).with_extension("current_sensor", offset=0.03)
    truth = truth.with_values(R_f_n=2e-4)
    prof = pulses(1200.0)
    fit_steps = Settings(adaptive=False, dt_first=DT_FIRST)
    y = battlab.simulate(truth, prof, soc0=0.6, settings=fit_steps).voltage
    start = nca.with_extension("contact_resistance").with_extension("current_sensor")
    exp = Experiment("pulses", prof, y, 0.6, 1e-8)
    names = ("contact_resistance.R_c", "current_sensor.offset", "R_f_n")
    res = F.fit(start, [exp], names)
    assert res.cell.value("contact_resistance.R_c") == pytest.approx(0.006, rel=1e-3)
    assert res.cell.value("current_sensor.offset") == pytest.approx(0.03, rel=1e-3)
    assert res.cell.value("R_f_n") == pytest.approx(2e-4, rel=1e-3)
