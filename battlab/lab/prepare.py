"""The run's PREFLIGHT phase: the bench made ready and checked before the first step.

Identities (compared with the recorded ones on a resume), the instrument reset, the instrument's own protections
programmed from the envelope (voltage and current limits, over-temperature trip, I/O watchdog: each where the
cycler's capabilities declare it, else noted and left to the runner's own checks), the cell's rest
voltage within the envelope (and the plan's SOC and voltage window from it, when the plan starts from rest:
:mod:`battlab.lab.window`), the chamber free of alarms, at its set point and stable; then the run's origin on
the instrument clock (re-anchored when the instrument's clock restarted during a resume).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from battlab.lab.calls import InstrumentCalls
from battlab.lab.limits import Envelope
from battlab.lab.plan import RunOptions
from battlab.lab.run_state import Abort
from battlab.lab.safety import check_sample
from battlab.lab.steps import Sample
from drivers.clock import Clock
from drivers.interfaces import Chamber, Cycler
from protocols.errors import InputError


@dataclass(frozen=True)
class BenchReady:
    """What the preflight found: identities, whether the cycler reports a cell temperature, the rest voltage [V],
    the chamber's stable temperature [degC], the run's origin t0 [s, instrument clock] and notes for the log."""

    identities: dict[str, str]
    has_T: bool
    rest_voltage: float
    ambient_stable_degC: float
    t0: float
    notes: list[str] = field(default_factory=list)


def prepare_bench(
    calls: InstrumentCalls,
    cycler: Cycler,
    chamber: Chamber,
    env: Envelope,
    options: RunOptions,
    config: Any,
    clock: Clock,
) -> BenchReady:
    """Make the bench ready for a run (see the module docstring); any failure is an :class:`Abort`."""
    notes: list[str] = []
    identities = {
        "cycler": calls.call("cycler identity", cycler.identify),
        "chamber": calls.call("chamber identity", chamber.identify),
    }
    expected = config.expected_identities
    if expected:
        for role, idn in identities.items():
            if role in expected and expected[role] != idn:
                raise Abort(
                    "preflight",
                    f"{role} identity changed since the run started: {expected[role]!r} then, {idn!r} now",
                )
    caps = cycler.capabilities
    calls.call("cycler reset", cycler.initialize)
    if caps.clear_protection:
        calls.call("clear protection", cycler.clear_protection)
    errors = calls.call("cycler error queue", cycler.errors)
    if errors:
        notes.append(f"cycler error queue at start: {errors}")
    calls.call("current limits", cycler.set_current_limits, env.current_charge_max, env.current_discharge_max)
    if caps.low_voltage_cutoff:
        calls.call("voltage limits", cycler.set_voltage_limits, env.voltage_min, env.voltage_max)
    else:
        calls.call("voltage limit", cycler.set_voltage_limits, None, env.voltage_max)
        notes.append("no instrument low-voltage cut-off: the runner enforces voltage_min")
    if caps.temperature_limit:
        calls.optional("over-temperature trip", cycler.set_temperature_limit, env.temperature_max_K)
    else:
        calls.note_unavailable("over-temperature trip", f"{cycler.name} has none")
    if caps.watchdog:
        calls.optional("watchdog", cycler.set_watchdog, config.watchdog_s)
    else:
        calls.note_unavailable("watchdog", f"{cycler.name} has none")
    if options.sample_period_s > config.watchdog_s / 3:
        raise Abort(
            "preflight",
            f"sample_period_s {options.sample_period_s:g} s is too long for the "
            f"instrument watchdog of {config.watchdog_s:g} s (at most a third of it)",
        )
    m = calls.call("measure", cycler.measure)
    has_T = m.temperature_K is not None
    t_first = m.t_s if caps.timestamps and m.t_s is not None else clock.now()
    first = Sample(t_first, m.voltage_V, m.current_A, m.temperature_K)
    bad = check_sample(first, env)
    if bad is not None:
        raise Abort("preflight", f"cell at rest: {bad.message} (is the cell connected?)")
    rest_voltage = first.v
    if getattr(config, "window_check", None) is not None:
        try:  # the plan's start state is the cell at rest: its window is checked before any output is on
            config.window_check(rest_voltage)
        except InputError as exc:
            raise Abort("preflight", str(exc)) from None
    alarms = calls.call("chamber alarms", chamber.alarms)
    if alarms:
        raise Abort("preflight", f"chamber alarm(s) before the run: {alarms}")
    o = options
    calls.call("chamber set point", chamber.set_point, o.ambient_degC)
    poll = max(min(5.0, o.stable_hold_s / 6 if o.stable_hold_s > 0 else 5.0), o.sample_period_s)
    try:
        ambient = calls.call(
            "chamber stable",
            lambda: chamber.wait_stable(o.stable_tol_K, o.stable_timeout_s, clock, hold_s=o.stable_hold_s, poll_s=poll),
        )
    except Abort as exc:
        raise Abort("preflight", exc.message) from None
    now = clock.now()
    t0, last_tt = config.t0_s, config.last_test_time_s
    if t0 is None:
        t0_run = now
    else:
        t0_run = t0
        if last_tt is not None and now - t0 <= last_tt:
            t0_run = now - last_tt - options.sample_period_s
            notes.append(f"instrument clock restarted: test time re-anchored at {last_tt + o.sample_period_s:.3f} s")
    return BenchReady(identities, has_T, rest_voltage, ambient, t0_run, notes)
