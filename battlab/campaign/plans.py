"""The campaign's test plans: capacity check, OCV test, SOC preparation, profile measurements, conventional tests.

Every experiment is split in two runs on the same cell: a *preparation* (full charge by CCCV, a discharge by the
charge that brings the cell to the profile's start SOC, a rest) logged coarsely, and a *measurement* (a short rest,
the profile, a rest after it) logged every second. The measurement log starts at rest, so its start SOC comes from
the rest voltage on the identified OCV (as for any logged data), and the fit reads only the measurement.

Currents positive = charge; 1C = the rated capacity [A]; the SOC adjustment uses the capacity measured by the
campaign's capacity check (a lab does the same), not the rated one.
"""

from __future__ import annotations

from battlab.io.plan import Plan, RunOptions
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
#: sample period of preparations, capacity checks and constant-current tests [s]
COARSE_S = 10.0
#: sample period of the OCV test [s] (C/20: 0.4 mAh between samples; at 60 s the voltage at the end of the C/20
#: discharge passes the 2.45 V abort limit between two samples, measured on nca18650-true)
OCV_S = 30.0
#: sample period of profile measurements [s] (the Fisher information's 1 s)
FINE_S = 1.0
#: the rest that starts a measurement [s] (its first sample gives the start SOC), and the one after the profile
REST_BEFORE_S, REST_AFTER_S = 60.0, 600.0


#: abort limits of tests that discharge to 2.5 V: 100 mV below it (the most the run's pre-flight allows), so that the
#: sample that sees the end of a discharge comes before the abort limit (at 50 mV below, a C/3 discharge of
#: nca18650-true passed it within one 10 s sample)
TO_EMPTY_LIMITS = SafetyLimits(voltage_min=V_MIN - 0.1)
#: a preparation's discharge to a SOC stops at V_MIN + this [V] if the cell runs out first: its cut-off guards, it is
#: not the aim, and at its end a C/2 discharge falls up to 90 mV per 10 s sample (a truth with a stoichiometry-
#: dependent solid diffusivity, b± = 2), so a guard at V_MIN let it pass the 2.45 V abort limit between two samples
PREP_GUARD_V = 0.1


def _plan(
    name: str,
    steps: list[Step],
    capacity_ah: float,
    period_s: float,
    ambient_degC: float,
    limits: SafetyLimits | None = None,
) -> Plan:
    proto = Protocol(name, tuple(steps), limits or SafetyLimits(), capacity_ah).check()
    return Plan(proto, RunOptions(sample_period_s=period_s, ambient_degC=ambient_degC, stable_hold_s=0.0))


def full_charge(capacity_ah: float, label: str = "full charge") -> CCCV:
    """CCCV at C/3 to 4.2 V until the current falls to C/50 (at most 6 h). C/3, not C/2: the engine switches to CV
    at a sample, and on a cell that is already nearly full a C/2 step overshoots the 4.25 V abort limit within the
    first 10 s sample (measured: 4.2518 V on nca18650-true after the OCV test)."""
    return CCCV(capacity_ah / 3, V_MAX, (current_below(capacity_ah / 50), after(6 * 3600)), label)


def capacity_check(capacity_ah: float, ambient_degC: float, *, rest_s: float = 3600.0) -> Plan:
    """Full charge, rest, C/3 discharge to 2.5 V, rest: the discharged charge is the capacity."""
    steps: list[Step] = [
        full_charge(capacity_ah),
        Rest((after(rest_s),), "rest after charge"),
        ConstantCurrent(-capacity_ah / 3, (voltage_below(V_MIN), after(4.5 * 3600)), "C/3 discharge"),
        Rest((after(rest_s),), "rest after discharge"),
    ]
    return _plan("capacity check (C/3 after CCCV)", steps, capacity_ah, COARSE_S, ambient_degC, TO_EMPTY_LIMITS)


#: the step index (1-based) of the capacity check's discharge
CAPACITY_STEP = 3


def ocv_test(
    capacity_ah: float, ambient_degC: float, *, c_rate: float = 1 / 20, rest_s: float = 1800.0, period_s: float = OCV_S
) -> Plan:
    """One C/20 cycle: full charge, rest, discharge to 2.5 V, rest, charge to 4.2 V, rest (steps 3-6 are the
    pseudo-OCV)."""
    limit_s = 1.2 * 3600.0 / c_rate
    i = c_rate * capacity_ah
    steps: list[Step] = [
        full_charge(capacity_ah),
        Rest((after(rest_s),), "rest"),
        ConstantCurrent(-i, (voltage_below(V_MIN), after(limit_s)), f"C/{1 / c_rate:g} discharge"),
        Rest((after(rest_s),), "rest"),
        ConstantCurrent(i, (voltage_above(V_MAX), after(limit_s)), f"C/{1 / c_rate:g} charge"),
        Rest((after(rest_s),), "rest"),
    ]
    return _plan(f"OCV test C/{1 / c_rate:g}", steps, capacity_ah, period_s, ambient_degC, TO_EMPTY_LIMITS)


#: the first step index of the OCV test's slow cycle
OCV_FIRST_STEP = 3


def prepare(
    soc0: float, capacity_ah: float, measured_ah: float, ambient_degC: float, *, rest_s: float = 1800.0
) -> Plan:
    """Bring the cell to ``soc0``: full charge, rest, discharge (1 − soc0) × the measured capacity at C/2 (or to
    V_MIN + :data:`PREP_GUARD_V`, if the cell runs out first), rest."""
    steps: list[Step] = [full_charge(capacity_ah), Rest((after(600.0),), "rest after full charge")]
    dq = (1.0 - soc0) * measured_ah
    if dq > 1e-3:
        steps.append(
            ConstantCurrent(
                -0.5 * capacity_ah,
                (capacity_reached(dq), voltage_below(V_MIN + PREP_GUARD_V)),
                f"to SOC {soc0:.2f} at C/2",
            )
        )
    steps.append(Rest((after(rest_s),), f"rest at SOC {soc0:.2f}"))
    return _plan(f"prepare SOC {soc0:.2f}", steps, capacity_ah, COARSE_S, ambient_degC)


def prepare_empty(capacity_ah: float, ambient_degC: float, *, rest_s: float = 1800.0) -> Plan:
    """Empty the cell: C/2 discharge to 2.5 V, rest."""
    steps: list[Step] = [
        ConstantCurrent(-0.5 * capacity_ah, (voltage_below(V_MIN), after(3 * 3600)), "empty at C/2"),
        Rest((after(rest_s),), "rest when empty"),
    ]
    return _plan("prepare SOC 0", steps, capacity_ah, COARSE_S, ambient_degC, TO_EMPTY_LIMITS)


def measurement(
    profile: Profile, capacity_ah: float, ambient_degC: float, *, label: str = "", rest_after_s: float = REST_AFTER_S
) -> Plan:
    """A short rest, the profile, a rest after it (if ``rest_after_s`` > 0), logged every second; the profile is
    step 2."""
    steps: list[Step] = [
        Rest((after(REST_BEFORE_S),), "rest before"),
        ProfileStep(profile, label or f"profile {profile.id}"),
    ]
    if rest_after_s > 0:
        steps.append(Rest((after(rest_after_s),), "rest after"))
    return _plan(label or f"profile {profile.id}", steps, capacity_ah, FINE_S, ambient_degC)


def prepared_measurement(
    profile: Profile, capacity_ah: float, measured_ah: float, ambient_degC: float, *, rest_after_s: float = REST_AFTER_S
) -> Plan:
    """The preparation and the measurement of ``profile`` as one run, logged every second: the log starts where a
    full charge leaves the cell nearly uniform, so its replay carries the gradients the discharge to the start SOC and
    the rest leave (a measurement log of its own starts from a uniform cell at its first rest voltage)."""
    prep = prepare(float(profile.soc0 if profile.soc0 is not None else 0.5), capacity_ah, measured_ah, ambient_degC)
    meas = measurement(profile, capacity_ah, ambient_degC, rest_after_s=rest_after_s)
    steps = [*prep.protocol.steps, *meas.protocol.steps]
    return _plan(f"{meas.protocol.name}, prepared", steps, capacity_ah, FINE_S, ambient_degC)


def constant_current(
    c_rate: float,
    capacity_ah: float,
    ambient_degC: float,
    *,
    period_s: float | None = None,
    rest_after_s: float = REST_AFTER_S,
) -> Plan:
    """A constant-current test to the voltage limit (positive c_rate = charge, to 4.2 V; else to 2.5 V), from a
    rest, with a rest after it; logged every ``period_s`` (default: 10 s below 1C, 1 s from 1C: the voltage falls
    fast at the end of a fast discharge, and the test ends at the sample that passes the limit, which must come
    before the abort limit :data:`TO_EMPTY_LIMITS`)."""
    period_s = period_s if period_s is not None else (FINE_S if abs(c_rate) >= 1.0 else COARSE_S)
    limit = voltage_above(V_MAX) if c_rate > 0 else voltage_below(V_MIN)
    what = "charge" if c_rate > 0 else "discharge"
    steps: list[Step] = [
        Rest((after(REST_BEFORE_S),), "rest before"),
        ConstantCurrent(c_rate * capacity_ah, (limit, after(1.3 * 3600 / abs(c_rate))), f"{abs(c_rate):.3g}C {what}"),
        Rest((after(rest_after_s),), "rest after"),
    ]
    limits = TO_EMPTY_LIMITS if c_rate < 0 else None
    return _plan(f"{abs(c_rate):.3g}C {what}", steps, capacity_ah, period_s, ambient_degC, limits)
