"""The plan's SOC and voltage window, checked on the start cell before any hardware moves.

A plan whose profile drains or fills the cell past its window aborts at a voltage limit hours into a run (a library
pulse train from SOC 0.4 that passes 1 Ah net on discharge ends at SOC 0.03). :func:`check_window` walks the plan's
steps from its start state on a cell (the start cell of an identification, e.g. ``nca18650``) and simulates every
profile step with :func:`battlab.simulate` from the state the steps before it leave:

* the start: SOC 1 after a CCCV or CV to the top of the cell's OCV range that ends on a current taper, the given
  start SOC (``--soc0``, the virtual cell's), or the SOC whose OCV is the measured rest voltage;
* a CCCV or CV step: the SOC whose OCV is its voltage (the hold ends near equilibrium);
* a CC step: coulomb counting up to its capacity or time end (never past the SOC of a voltage end's OCV), on the
  cell's capacity;
* a rest: no change; a profile: its net charge over the cell's capacity.

Each profile must keep its coulomb-counted SOC within [``soc_margin``, 1 − ``soc_margin``] and its simulated voltage
at least ``voltage_margin_V`` inside the plan's voltage limits (where the run aborts), and the simulation must
finish. The margins stand for what the start cell does not know yet: the true cell's capacity and resistance (the
truth of the virtual lab, ``nca18650-true``, reaches 2.5 V in that pulse train where ``nca18650`` stays at 2.65 V).
Each profile is simulated from rest at its start SOC (the steps before it, CCCV holds and rests, are not
simulated), so the check is of the profiles, not of the adjustments between them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocols.errors import InputError
from protocols.protocol import CCCV, ConstantCurrent, ConstantVoltage, ProfileStep, Protocol, Quantity, Rest

#: a profile's coulomb-counted SOC must stay this far inside [0, 1]
SOC_MARGIN = 0.05
#: [V] a profile's simulated voltage must stay this far inside the plan's voltage limits
VOLTAGE_MARGIN_V = 0.1
#: [V] a CCCV or CV this close to the top of the cell's OCV range (or above it) charges the cell full
FULL_TOLERANCE_V = 0.01


@dataclass(frozen=True)
class ProfileWindow:
    """One profile step of a plan on the cell: its position (1-based step), SOC at its start and the extremes of its
    coulomb-counted SOC, its simulated voltage extremes [V], why the simulation stopped early (None: it did not),
    and what is wrong (None: within the window)."""

    step: int
    label: str
    profile_id: Any
    soc_start: float
    soc_min: float
    soc_max: float
    v_min: float
    v_max: float
    ended_by: str | None
    problem: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "step": self.step,
            "label": self.label,
            "profile": self.profile_id,
            "soc_start": self.soc_start,
            "soc_min": self.soc_min,
            "soc_max": self.soc_max,
            "v_min": self.v_min,
            "v_max": self.v_max,
            "ended_by": self.ended_by,
            "problem": self.problem,
        }


@dataclass(frozen=True)
class WindowReport:
    """The window check of a plan: how its start state was known, and every profile step's window."""

    cell: str
    start: str
    profiles: list[ProfileWindow] = field(default_factory=list)

    @property
    def problems(self) -> list[str]:
        return [f"step {p.step} ({p.label}): {p.problem}" for p in self.profiles if p.problem]

    @property
    def ok(self) -> bool:
        return not self.problems

    def raise_if_bad(self, where: str) -> WindowReport:
        """An :class:`InputError` naming ``where``, the first bad step and how many more; else self."""
        bad = self.problems
        if bad:
            more = f" (and {len(bad) - 1} more: {'; '.join(bad[1:])})" if len(bad) > 1 else ""
            raise InputError(
                f"{where}: {bad[0]}{more}; simulated on cell {self.cell} from {self.start}. Start the profile from "
                "another SOC (a charge or discharge step before it) or leave it out (battlab design writes plans "
                "that pass this check)"
            )
        return self

    def to_dict(self) -> dict[str, Any]:
        return {"cell": self.cell, "start": self.start, "ok": self.ok, "profiles": [p.to_dict() for p in self.profiles]}


def _ocv_range(cell: Any) -> tuple[float, float]:
    return float(cell.ocv(0.0)), float(cell.ocv(1.0))


def _soc_at(cell: Any, voltage: float) -> float:
    lo, hi = _ocv_range(cell)
    return cell.soc_from_voltage(float(np.clip(voltage, lo, hi)))


def _ends_on_taper(step: CCCV | ConstantVoltage) -> bool:
    return any(e.quantity is Quantity.CURRENT for e in step.ends)


def resets_to_full(step: Any, cell: Any) -> bool:
    """Whether ``step`` leaves the cell full whatever its state before: a CCCV or CV charge to the top of the
    cell's OCV range (within :data:`FULL_TOLERANCE_V`) that ends on a current taper."""
    if isinstance(step, CCCV) and step.current <= 0:
        return False
    if isinstance(step, ConstantVoltage) and step.direction.value != "charge":
        return False
    return (
        isinstance(step, CCCV | ConstantVoltage)
        and step.voltage >= _ocv_range(cell)[1] - FULL_TOLERANCE_V
        and _ends_on_taper(step)
    )


def needs_start_soc(protocol: Protocol, cell: Any) -> bool:
    """Whether a profile step comes before any step that sets the SOC by voltage (CCCV, CV): only then does the
    plan's start state decide the check."""
    for s in protocol.steps:
        if isinstance(s, CCCV | ConstantVoltage):
            return False
        if isinstance(s, ProfileStep):
            return True
    return False


def _after_cc(step: ConstantCurrent, soc: float, cell: Any) -> float:
    cap = cell.capacity()
    ah = np.inf
    for e in step.ends:
        if e.quantity is Quantity.CAPACITY:
            ah = min(ah, abs(e.value))
        elif e.quantity is Quantity.TIME:
            ah = min(ah, abs(step.current) * e.value / 3600.0)
    if not np.isfinite(ah):  # ends on voltage only: up to the voltage end's OCV
        ah = cap
    new = soc + np.sign(step.current) * ah / cap
    for e in step.ends:
        if e.quantity is Quantity.VOLTAGE:
            bound = _soc_at(cell, e.value)
            new = max(new, bound) if step.current < 0 else min(new, bound)
    return float(np.clip(new, 0.0, 1.0))


def check_window(
    protocol: Protocol,
    cell: Any,
    *,
    start_soc: float | None = None,
    start: str | None = None,
    ambient_K: float = 298.15,
    soc_margin: float = SOC_MARGIN,
    voltage_margin_V: float = VOLTAGE_MARGIN_V,
    steps: Sequence[int] | None = None,
) -> WindowReport:
    """Walk ``protocol`` on ``cell`` from ``start_soc`` (see the module docstring) and check every profile step.

    ``start`` says how ``start_soc`` is known (for the messages). A plan whose first profile comes before any step
    that sets the SOC by voltage needs ``start_soc``. ``steps``: only these profile steps (1-based) are simulated;
    the others only move the SOC. ``ambient_K`` [K] is the chamber's set point."""
    from battlab.simulation import simulate

    lim = protocol.limits
    lo, hi = float(lim.voltage_min), float(lim.voltage_max)
    cap = cell.capacity()
    how = start or (f"SOC {start_soc:g}" if start_soc is not None else "the plan's first charge")
    report = WindowReport(cell.name, how)
    soc = start_soc
    for k, s in enumerate(protocol.steps, start=1):
        if isinstance(s, CCCV | ConstantVoltage):
            soc = 1.0 if resets_to_full(s, cell) else _soc_at(cell, s.voltage)
        elif isinstance(s, ConstantCurrent):
            if soc is not None:
                soc = _after_cc(s, soc, cell)
        elif isinstance(s, Rest):
            pass
        elif isinstance(s, ProfileStep):
            p = s.profile
            label = s.label or f"profile {p.id}"
            if soc is None:
                raise InputError(
                    f"step {k} ({label}) runs before any step that sets the SOC: give the start SOC (--soc0) or "
                    "begin the plan with a charge"
                )
            path = soc + p.soc(cap, 0.0)
            if steps is None or k in steps:
                res = simulate(cell, p, soc0=float(np.clip(soc, 0.0, 1.0)), ambient=ambient_K, v_limits=(lo, hi))
                v_min = float(res.voltage.min()) if res.voltage.size else float("nan")
                v_max = float(res.voltage.max()) if res.voltage.size else float("nan")
                problem = _problem(
                    res, soc, path, v_min, v_max, (lo, hi), soc_margin, voltage_margin_V, float(p.duration)
                )
                report.profiles.append(
                    ProfileWindow(
                        k, label, p.id, soc, float(path.min()), float(path.max()), v_min, v_max, res.ended_by, problem
                    )
                )
            soc = float(np.clip(soc + p.net_charge / cap, 0.0, 1.0))
    return report


def _problem(
    res: Any,
    soc: float,
    path: np.ndarray,
    v_min: float,
    v_max: float,
    limits: tuple[float, float],
    soc_margin: float,
    v_margin: float,
    duration: float,
) -> str | None:
    lo, hi = limits
    s_lo, s_hi = float(path.min()), float(path.max())
    if res.ended_by is not None:
        t = float(res.t[-1] - res.t[0]) if res.t.size else 0.0
        return f"from SOC {soc:.3f} the cell stops at {res.ended_by} after {t:.0f} of {duration:.0f} s"
    if s_lo < soc_margin or s_hi > 1.0 - soc_margin:
        return f"from SOC {soc:.3f} it passes SOC {s_lo:.3f}–{s_hi:.3f}, outside [{soc_margin:g}, {1 - soc_margin:g}]"
    if v_min < lo + v_margin or v_max > hi - v_margin:
        return (
            f"from SOC {soc:.3f} its voltage spans {v_min:.3f}–{v_max:.3f} V, within {v_margin:g} V of the plan's "
            f"limits [{lo:g}, {hi:g}] V"
        )
    return None


__all__ = [
    "SOC_MARGIN",
    "VOLTAGE_MARGIN_V",
    "ProfileWindow",
    "WindowReport",
    "check_window",
    "needs_start_soc",
    "resets_to_full",
]
