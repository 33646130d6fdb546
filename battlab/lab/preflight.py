"""Pre-flight checks that need no instrument: the plan within the cell's and the instruments' limits.

:func:`check_plan` runs before anything is switched on and returns the :class:`~battlab.lab.limits.Envelope`
the run enforces; every problem is an :class:`InputError` naming the plan, the step (1-based) and the limit. The
checks that need the instruments (identities, the cell's rest voltage, the chamber at its set point) are the
engine's pre-flight state (:mod:`battlab.lab.engine`).
"""

from __future__ import annotations

from battlab.lab.limits import CELL_VOLTAGE_MARGIN_V, CellWindow, Envelope, InstrumentLimits
from battlab.lab.plan import Plan
from protocols.errors import InputError
from protocols.protocol import CCCV, ConstantCurrent, ConstantVoltage, ProfileStep

#: the chamber's set point must stay this far below the surface-temperature abort limit
AMBIENT_MARGIN_K = 2.0


def check_plan(plan: Plan, cell: CellWindow, limits: InstrumentLimits) -> Envelope:
    """Check ``plan`` against the cell and the instruments; return the safety envelope of the run."""
    where = plan.source or plan.protocol.name
    p = plan.protocol
    lim = p.limits
    try:
        p.check()
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    cyc, cha = limits.cycler, limits.chamber
    problems: list[str] = []
    lo, hi = cell.voltage_min - CELL_VOLTAGE_MARGIN_V, cell.voltage_max + CELL_VOLTAGE_MARGIN_V
    if lim.voltage_min < lo or lim.voltage_max > hi:
        problems.append(
            f"[limits] voltage band [{lim.voltage_min:g}, {lim.voltage_max:g}] V exceeds cell {cell.name}'s window "
            f"[{cell.voltage_min:g}, {cell.voltage_max:g}] V by more than {CELL_VOLTAGE_MARGIN_V:g} V"
        )
    if lim.voltage_min < cyc.voltage_min or lim.voltage_max > cyc.voltage_max:
        problems.append(
            f"[limits] voltage band [{lim.voltage_min:g}, {lim.voltage_max:g}] V is outside the cycler's range "
            f"[{cyc.voltage_min:g}, {cyc.voltage_max:g}] V ({limits.source})"
        )
    if lim.current_max > cell.current_max * (1 + 1e-9):
        problems.append(
            f"[limits] current_max {lim.current_max:g} A exceeds cell {cell.name}'s {cell.current_max:g} A (5C)"
        )
    if lim.temperature_max > cell.temperature_max_K + 1e-9:
        problems.append(
            f"[limits] temperature_max {lim.temperature_max - 273.15:g} degC exceeds cell {cell.name}'s "
            f"{cell.temperature_max_K - 273.15:g} degC"
        )
    env = Envelope(
        voltage_min=lim.voltage_min,
        voltage_max=lim.voltage_max,
        current_charge_max=min(lim.current_max, cell.current_max, cyc.current_charge_max),
        current_discharge_max=min(lim.current_max, cell.current_max, cyc.current_discharge_max),
        temperature_max_K=min(lim.temperature_max, cell.temperature_max_K),
    )
    for k, s in enumerate(p.steps, start=1):
        at = f"step {k} ({s.kind.value}{': ' + s.label if s.label else ''})"
        currents: list[float] = []
        if isinstance(s, ConstantCurrent | CCCV):
            currents.append(s.current)
        if isinstance(s, ProfileStep):
            currents += [float(s.profile.current.max()), float(s.profile.current.min())]
        for i in currents:
            bound = env.current_charge_max if i > 0 else env.current_discharge_max
            if abs(i) > bound * (1 + 1e-9):
                side = "charge" if i > 0 else "discharge"
                problems.append(
                    f"{at}: current {i:g} A exceeds the {side} limit {bound:g} A (plan, cell and cycler limits)"
                )
        if isinstance(s, ConstantVoltage | CCCV) and not cell.voltage_min <= s.voltage <= cell.voltage_max:
            problems.append(
                f"{at}: voltage {s.voltage:g} V is outside cell {cell.name}'s window "
                f"[{cell.voltage_min:g}, {cell.voltage_max:g}] V"
            )
    T_amb = plan.options.ambient_degC
    if not cha.temperature_min <= T_amb <= cha.temperature_max:
        problems.append(
            f"[run] ambient_degC {T_amb:g} is outside the chamber's range [{cha.temperature_min:g}, "
            f"{cha.temperature_max:g}] degC ({limits.source})"
        )
    if T_amb + 273.15 > env.temperature_max_K - AMBIENT_MARGIN_K:
        problems.append(
            f"[run] ambient_degC {T_amb:g} is within {AMBIENT_MARGIN_K:g} K of the surface-temperature limit "
            f"{env.temperature_max_K - 273.15:g} degC"
        )
    if problems:
        more = f" (and {len(problems) - 1} more: {'; '.join(problems[1:])})" if len(problems) > 1 else ""
        raise InputError(f"{where}: {problems[0]}{more}")
    return env


__all__ = ["AMBIENT_MARGIN_K", "check_plan"]
