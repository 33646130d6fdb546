"""Concatenate selected library profiles into one experiment (a :class:`Protocol`).

Before each profile the cell is brought to the profile's start SOC, by one of (:class:`SocMethod`):

* ``CCCV_TO_OCV`` (default): constant current towards the target (charge if the target is above the
  tracked SOC, else discharge) until the voltage reaches the open-circuit voltage of the target SOC, then
  hold that voltage until |I| <= ``cutoff_c_rate`` C or ``cv_max_s``; the cell then sits at the target's
  equilibrium voltage, whatever the coulomb-counting drift. The OCV table defaults to the paper's Table 5
  (0.2-0.8 SOC); pass the identified one.
* ``RESET``: CCCV charge to the top of the voltage window (full), rest, then discharge (1 - SOC0) x capacity
  at constant current (capacity end, with the window's lower voltage as a stop): slower, but every profile
  starts from the same reference.
* ``REST``: no adjustment, only the rest (profiles run back to back; the report shows where the SOC drifts).

Then ``rest_before_s`` of rest, the profile, and ``rest_after_s`` of rest. When the start SOC is unknown
(``start_soc=None``) the first adjustment is a ``RESET``. The protocol carries ``limits`` (the safety
limits) and the report gives the durations and charge; CV holds end on current, so their duration is
reported as a bound (``cv_time_budget_s``), and the CC parts are estimated from coulomb counting.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from protocols.constants import RATED_CAPACITY_AH, TABLE5_OCV
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
    voltage_below,
)


class SocMethod(Enum):
    """How the cell is brought to each profile's start SOC."""

    CCCV_TO_OCV = "cccv_to_ocv"
    RESET = "reset"
    REST = "rest"


@dataclass(frozen=True)
class ConcatenationReport:
    """Durations [s] and charge [Ah] of a concatenated experiment (estimates where noted)."""

    n_profiles: int
    profile_s: float
    rest_s: float
    adjust_cc_s: float
    cv_time_budget_s: float
    charge_throughput_ah: float
    net_charge_ah: float
    soc_at_profile_start: tuple[float, ...]
    soc_end: float

    @property
    def duration_s(self) -> float:
        """Profiles + rests + CC adjustments (CV holds excluded: they end on current)."""
        return self.profile_s + self.rest_s + self.adjust_cc_s

    @property
    def duration_max_s(self) -> float:
        """Upper bound: ``duration_s`` plus every CV hold at its time limit."""
        return self.duration_s + self.cv_time_budget_s


@dataclass(frozen=True)
class Concatenation:
    """The experiment and its report."""

    protocol: Protocol
    report: ConcatenationReport


def ocv_at(soc: float, table: Sequence[tuple[float, float]]) -> float:
    """Open-circuit voltage [V] at ``soc`` by linear interpolation in ``table`` of (SOC, V) pairs."""
    pts = sorted(table)
    s = np.array([p[0] for p in pts])
    v = np.array([p[1] for p in pts])
    if not s[0] - 1e-9 <= soc <= s[-1] + 1e-9:
        raise InputError(f"start SOC {soc:g} is outside the OCV table's range [{s[0]:g}, {s[-1]:g}]")
    return float(np.interp(soc, s, v))


def concatenate(
    profiles: Sequence[Profile],
    *,
    name: str = "concatenation",
    start_soc: float | None = None,
    capacity_ah: float = RATED_CAPACITY_AH,
    method: SocMethod = SocMethod.CCCV_TO_OCV,
    adjust_c_rate: float = 0.5,
    cutoff_c_rate: float = 1 / 50,
    cv_max_s: float = 3600.0,
    rest_before_s: float = 1800.0,
    rest_after_s: float = 600.0,
    window_v: tuple[float, float] = (2.5, 4.2),
    ocv_table: Sequence[tuple[float, float]] = TABLE5_OCV,
    limits: SafetyLimits | None = None,
) -> Concatenation:
    """Build the experiment for ``profiles`` in the given order (see the module docstring)."""
    if not profiles:
        raise InputError("concatenate: no profiles given")
    limits = limits or SafetyLimits()
    i_adj = adjust_c_rate * capacity_ah
    cutoff = cutoff_c_rate * capacity_ah
    v_lo, v_hi = window_v
    steps: list[Step] = []
    soc = start_soc
    profile_s = rest_s = adjust_s = cv_s = 0.0
    q_abs = q_net = 0.0
    starts: list[float] = []

    def rest(seconds: float, label: str) -> None:
        nonlocal rest_s
        if seconds > 0:
            steps.append(Rest((after(seconds),), label))
            rest_s += seconds

    def cc(current: float, amp_hours: float, label: str, stop: object) -> None:
        nonlocal adjust_s, q_abs, q_net
        steps.append(ConstantCurrent(current, (capacity_reached(amp_hours), stop), label))  # type: ignore[arg-type]
        adjust_s += amp_hours * 3600.0 / abs(current)
        q_abs += amp_hours
        q_net += amp_hours * np.sign(current)

    for k, p in enumerate(profiles, start=1):
        if p.soc0 is None:
            raise InputError(f"concatenate: profile {p.id} (#{k}) has no start SOC")
        target = float(p.soc0)
        label = f"to SOC {target:g} for profile {p.id}"
        how = SocMethod.RESET if soc is None and method is not SocMethod.REST else method
        if how is SocMethod.RESET:
            steps.append(CCCV(i_adj, v_hi, (current_below(cutoff), after(cv_max_s + 4 * 3600)), f"full: {label}"))
            was = 0.0 if soc is None else soc
            adjust_s += (1.0 - was) * capacity_ah * 3600.0 / i_adj
            cv_s += cv_max_s
            q_abs += (1.0 - was) * capacity_ah
            q_net += (1.0 - was) * capacity_ah
            rest(rest_after_s, "rest after full charge")
            if target < 1.0:
                cc(-i_adj, (1.0 - target) * capacity_ah, label, voltage_below(v_lo))
            soc = target
        elif how is SocMethod.CCCV_TO_OCV:
            assert soc is not None
            v_target = ocv_at(target, ocv_table)
            if abs(target - soc) > 1e-9:
                current = i_adj if target > soc else -i_adj
                budget = after(math.ceil(abs(target - soc) * 3600.0 / adjust_c_rate + cv_max_s))
                steps.append(CCCV(current, v_target, (current_below(cutoff), budget), label))
                adjust_s += abs(target - soc) * capacity_ah * 3600.0 / i_adj
                cv_s += cv_max_s
                q_abs += abs(target - soc) * capacity_ah
                q_net += (target - soc) * capacity_ah
            soc = target
        assert soc is not None
        rest(rest_before_s, f"rest before profile {p.id}")
        starts.append(soc)
        steps.append(ProfileStep(p, f"profile {p.id}"))
        profile_s += p.duration
        q_abs += p.charge_throughput
        q_net += p.net_charge
        soc = soc + p.net_charge / capacity_ah
        rest(rest_after_s, f"rest after profile {p.id}")
    protocol = Protocol(
        name,
        tuple(steps),
        limits,
        capacity_ah,
        f"{len(profiles)} profiles ({', '.join(str(p.id) for p in profiles)}), SOC set by {method.value}",
    ).check()
    report = ConcatenationReport(
        len(profiles),
        profile_s,
        rest_s,
        adjust_s,
        cv_s,
        float(q_abs),
        float(q_net),
        tuple(starts),
        float(soc),
    )
    return Concatenation(protocol, report)
