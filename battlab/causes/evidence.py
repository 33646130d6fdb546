"""What a set of experiments can show, read from their currents and ambients alone: the checks a cause uses to say
that data cannot inform its parameters (:attr:`battlab.causes.cause.Cause.uninformed`) or that a diagnosis
cannot test it (:attr:`battlab.causes.cause.Cause.untestable`).

An experiment here is anything with ``ambient`` [K] and ``profile.t`` [s], ``profile.current`` [A, + = charge]
(:class:`battlab.identify.experiments.Experiment`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

#: ambients closer than this [K] count as one temperature
AMBIENT_TOL_K = 5.0
#: a rest after a current this long [s] shows the relaxation after it
REST_MIN_S = 60.0
#: a reversal of the current shows a state that follows its direction when each side passes the charge of this many
#: hours at the rest threshold (at the callers' C/100 threshold: 1 % of the capacity, which moves a one-state
#: hysteresis by about a fifth of its swing at its typical decay rate of 50 per stoichiometry)
REVERSAL_HOURS_AT_REST = 1.0


class Experiment(Protocol):
    ambient: float
    profile: Any


def one_ambient(experiments: Sequence[Experiment]) -> bool:
    """Every experiment at one ambient temperature (within :data:`AMBIENT_TOL_K`)."""
    amb = [float(e.ambient) for e in experiments]
    return bool(amb) and max(amb) - min(amb) < AMBIENT_TOL_K


def ambient_text(experiments: Sequence[Experiment]) -> str:
    """``"every experiment is at one ambient temperature (25 °C)"``."""
    return f"every experiment is at one ambient temperature ({float(experiments[0].ambient) - 273.15:.0f} °C)"


def reverses_direction(experiments: Sequence[Experiment], i_rest: float) -> bool:
    """Some experiment passes at least ``i_rest`` × :data:`REVERSAL_HOURS_AT_REST` of charge [A h] one way and then
    as much the other way (rests between are allowed): a state that follows the current's direction is swept while
    the voltage is scored."""
    q_min = i_rest * REVERSAL_HOURS_AT_REST
    for e in experiments:
        p = e.scored_profile  # a lead-in informs nothing: it is never scored
        t, i = np.asarray(p.t, float), np.asarray(p.current, float)
        if t.size < 2:
            continue
        dq = np.abs(i[:-1]) * np.diff(t) / 3600.0  # [A h], each step at its left current
        sign, done, q = 0, {1: False, -1: False}, 0.0
        for k in range(i.size - 1):
            s = int(np.sign(i[k])) if abs(i[k]) > i_rest else 0
            if s == 0:
                continue
            if s != sign:
                sign, q = s, 0.0
            q += dq[k]
            if q >= q_min:
                done[s] = True
                if done[-s]:
                    return True
    return False


def rests_after_both_directions(experiments: Sequence[Experiment], i_rest: float) -> bool:
    """Some experiment rests (|I| ≤ ``i_rest`` [A] for :data:`REST_MIN_S`) after a charge and some after a
    discharge."""
    seen = {1: False, -1: False}
    for e in experiments:
        p = e.scored_profile  # a lead-in informs nothing: it is never scored
        t, i = np.asarray(p.t, float), np.asarray(p.current, float)
        last, rest_start = 0, None
        for k in range(i.size):
            if abs(i[k]) > i_rest:
                last, rest_start = int(np.sign(i[k])), None
            elif last:
                rest_start = t[k] if rest_start is None else rest_start
                if t[k] - rest_start >= REST_MIN_S:
                    seen[last] = True
    return seen[1] and seen[-1]
