"""Standard test protocols of the paper's workflow: OCV test, HPPC, and the "conventional" test set.

All currents are multiples of the rated capacity (1C = ``capacity_ah`` A); the voltage window is the cell's
2.5-4.2 V. Full charge is CCCV at C/2 to 4.2 V until |I| <= C/50.
"""

from __future__ import annotations

from collections.abc import Sequence

from protocols.constants import RATED_CAPACITY_AH
from protocols.drive_cycles import Cycle, drive_profile
from protocols.errors import InputError
from protocols.profile import Profile
from protocols.protocol import (
    CCCV,
    ConstantCurrent,
    ProfileStep,
    Protocol,
    Rest,
    SafetyLimits,
    Step,
    after,
    capacity_reached,
    current_below,
    voltage_above,
    voltage_below,
)

V_MIN, V_MAX = 2.5, 4.2


def _full_charge(cap: float, label: str = "full charge") -> CCCV:
    return CCCV(0.5 * cap, V_MAX, (current_below(cap / 50), after(5 * 3600)), label)


def ocv_test(
    *,
    c_rate: float = 1 / 20,
    cycles: int = 1,
    capacity_ah: float = RATED_CAPACITY_AH,
    rest_s: float = 3600.0,
    limits: SafetyLimits | None = None,
) -> Protocol:
    """Slow pseudo-OCV test: full charge, rest, then ``cycles`` x (discharge to 2.5 V, rest, charge to 4.2 V,
    rest) at ``c_rate`` (paper: three C/50 cycles; the campaign uses one C/20 cycle)."""
    if cycles < 1 or c_rate <= 0:
        raise InputError(f"ocv test: need cycles >= 1 and a positive C-rate (got {cycles}, {c_rate})")
    cap = capacity_ah
    limit_s = 1.2 * 3600.0 / c_rate
    steps: list[Step] = [_full_charge(cap), Rest((after(rest_s),), "rest")]
    for n in range(1, cycles + 1):
        steps += [
            ConstantCurrent(-c_rate * cap, (voltage_below(V_MIN), after(limit_s)), f"C/{1 / c_rate:g} discharge {n}"),
            Rest((after(rest_s),), "rest"),
            ConstantCurrent(c_rate * cap, (voltage_above(V_MAX), after(limit_s)), f"C/{1 / c_rate:g} charge {n}"),
            Rest((after(rest_s),), "rest"),
        ]
    name = f"OCV test C/{1 / c_rate:g} x{cycles}"
    return Protocol(name, tuple(steps), limits or SafetyLimits(), cap).check()


def hppc(
    *,
    capacity_ah: float = RATED_CAPACITY_AH,
    soc_step: float = 0.1,
    n_levels: int = 9,
    discharge_pulse_c: float = 1.0,
    charge_pulse_c: float = 0.75,
    pulse_s: float = 10.0,
    pulse_rest_s: float = 40.0,
    step_c_rate: float = 1 / 3,
    relax_s: float = 3600.0,
    limits: SafetyLimits | None = None,
) -> Protocol:
    """Hybrid pulse power characterisation: from full, at each of ``n_levels`` SOC levels (100 %, 90 %, ...)
    rest ``relax_s``, a discharge pulse, a rest, a charge pulse, a rest, then discharge ``soc_step`` of
    capacity at ``step_c_rate``."""
    cap = capacity_ah
    steps: list[Step] = [_full_charge(cap)]
    for n in range(n_levels):
        soc = 1.0 - n * soc_step
        steps += [
            Rest((after(relax_s),), f"relax at SOC {soc:.2f}"),
            ConstantCurrent(-discharge_pulse_c * cap, (after(pulse_s), voltage_below(V_MIN)), "discharge pulse"),
            Rest((after(pulse_rest_s),), "pulse rest"),
            ConstantCurrent(charge_pulse_c * cap, (after(pulse_s), voltage_above(V_MAX)), "charge pulse"),
            Rest((after(pulse_rest_s),), "pulse rest"),
            ConstantCurrent(-step_c_rate * cap, (capacity_reached(soc_step * cap), voltage_below(V_MIN)), "SOC step"),
        ]
    return Protocol("HPPC", tuple(steps), limits or SafetyLimits(), cap).check()


def conventional(
    *,
    capacity_ah: float = RATED_CAPACITY_AH,
    discharge_c_rates: Sequence[float] = (0.1, 0.2, 1 / 3, 2.0),
    charge_c_rates: Sequence[float] = (0.2, 0.5, 1.0),
    drive: Profile | None = None,
    rest_s: float = 3600.0,
    limits: SafetyLimits | None = None,
) -> Protocol:
    """The paper's "conventional" set: 7 constant-current tests plus a drive cycle.

    Discharges at C/10, C/5, C/3 and 2C (each from full, to 2.5 V) and charges at C/5, C/2 and 1C (each from
    empty, to 4.2 V); the 0.5C and 1C discharges are left out because the paper validates on them (Table 12).
    Then a drive cycle (default: the library's UDDS profile from SOC 0.8) after setting SOC 0.8.
    """
    cap = capacity_ah
    steps: list[Step] = []
    for c in discharge_c_rates:
        steps += [
            _full_charge(cap),
            Rest((after(rest_s),), "rest"),
            ConstantCurrent(-c * cap, (voltage_below(V_MIN), after(1.3 * 3600 / c)), f"{c:.3g}C discharge"),
            Rest((after(rest_s),), "rest"),
        ]
    for c in charge_c_rates:
        steps += [
            ConstantCurrent(-0.5 * cap, (voltage_below(V_MIN), after(3 * 3600)), "empty at C/2"),
            Rest((after(rest_s),), "rest"),
            ConstantCurrent(c * cap, (voltage_above(V_MAX), after(1.3 * 3600 / c)), f"{c:.3g}C charge"),
            Rest((after(rest_s),), "rest"),
        ]
    p = drive if drive is not None else drive_profile(Cycle.UDDS, soc0=0.8, id="udds")
    soc0 = 0.8 if p.soc0 is None else float(p.soc0)
    steps += [_full_charge(cap), Rest((after(rest_s),), "rest")]
    if soc0 < 1.0:
        steps.append(
            ConstantCurrent(-0.5 * cap, (capacity_reached((1 - soc0) * cap), voltage_below(V_MIN)), "to start SOC")
        )
    steps += [Rest((after(rest_s),), "rest"), ProfileStep(p, "drive cycle"), Rest((after(rest_s),), "rest")]
    return Protocol("conventional", tuple(steps), limits or SafetyLimits(), cap).check()
