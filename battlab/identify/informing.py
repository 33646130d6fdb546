"""What data inform a model extension: per catalog cause the library profile kind and the experiment that
identifies it, and the checks that refuse to fit an extension parameter the given data cannot inform (a fit of
it would wander to a bound): activation-energy changes with every experiment at one ambient temperature (they act
only through a change of temperature), hysteresis without a rest after charge and after discharge (its state
moves only with the direction of the current and shows in the relaxation after it)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from battlab.identify.experiments import Experiment
from protocols.errors import InputError

#: per cause: the library profile kind (``protocols.library.KINDS``) and the experiment that informs it (and
#: separates it from what it is confused with on data that cannot tell)
INFORMED_BY: dict[str, tuple[str, str]] = {
    "contact_resistance": (
        "pulse",
        "short pulses at two ambient temperatures (a series resistance and the film "
        "resistance R_f differ only in their temperature dependence)",
    ),
    "current_sensor": (
        "pulse",
        "pulses in both directions with long rests (an offset drains the cell at rest, a "
        "gain scales charge and discharge alike)",
    ),
    "thermal": (
        "drive",
        "the same profile at two ambient temperatures (activation energies act only through a change of temperature)",
    ),
    "equilibrium": ("pulse", "long low-rate pulses (1000 s) over the SOC window with rests (the OCV curve)"),
    "hysteresis": (
        "pulse",
        "charge and discharge pulses each followed by a rest (a change of direction, then relaxation onto the branch)",
    ),
    "double_layer": (
        "pulse",
        "1 s and 3 s bipolar pulses sampled at 10 Hz or faster, fitted with the double layer on",
    ),
    "capacity_fade": (
        "pulse",
        "a long test with rests at both ends and at several SOCs (a loss of capacity shows in the charge balance "
        "over hours, the side current's Tafel slope in how it changes with the negative electrode's potential)",
    ),
    "electrolyte": ("pulse", "long high-rate pulses (300-1000 s at 2C or more: large electrolyte gradients)"),
}
#: ambients closer than this [K] count as one temperature
AMBIENT_TOL_K = 5.0
#: a rest after a current this long [s] shows the relaxation that informs hysteresis
REST_MIN_S = 60.0


def one_ambient(experiments: Sequence[Experiment]) -> bool:
    """Every experiment at one ambient temperature (within :data:`AMBIENT_TOL_K`)."""
    amb = [float(e.ambient) for e in experiments]
    return bool(amb) and max(amb) - min(amb) < AMBIENT_TOL_K


def rests_after_both_directions(experiments: Sequence[Experiment], i_rest: float) -> bool:
    """Some experiment rests (|I| ≤ ``i_rest`` [A] for :data:`REST_MIN_S`) after a charge and some after a
    discharge."""
    seen = {1: False, -1: False}
    for e in experiments:
        t, i = np.asarray(e.profile.t, float), np.asarray(e.profile.current, float)
        last, rest_start = 0, None
        for k in range(i.size):
            if abs(i[k]) > i_rest:
                last, rest_start = int(np.sign(i[k])), None
            elif last:
                rest_start = t[k] if rest_start is None else rest_start
                if t[k] - rest_start >= REST_MIN_S:
                    seen[last] = True
    return seen[1] and seen[-1]


def uninformed(names: Sequence[str], experiments: Sequence[Experiment], i_rest: float) -> dict[str, str]:
    """Of the parameter ``names`` (``KEY.NAME`` for extensions), those ``experiments`` cannot inform, with why."""
    out: dict[str, str] = {}
    ambient = one_ambient(experiments)
    rests = None
    for n in names:
        key, _, name = n.partition(".")
        if key == "thermal" and name.startswith("dE_") and ambient:
            t = float(experiments[0].ambient) - 273.15
            out[n] = f"every experiment is at one ambient temperature ({t:.0f} °C)"
        elif key == "hysteresis":
            rests = rests_after_both_directions(experiments, i_rest) if rests is None else rests
            if not rests:
                out[n] = "no experiment rests after a charge and after a discharge"
    return out


def check_informed(names: Sequence[str], experiments: Sequence[Experiment], i_rest: float) -> None:
    """Refuse to fit parameters the data cannot inform: one :class:`InputError` naming them, why, and the
    experiment that would inform them."""
    bad = uninformed(names, experiments, i_rest)
    if not bad:
        return
    first = next(iter(bad))
    key = first.partition(".")[0]
    more = f" (and {', '.join(list(bad)[1:])})" if len(bad) > 1 else ""
    raise InputError(
        f"{first}{more}: not identifiable from these data: {bad[first]}; add {INFORMED_BY[key][1]}, "
        "or leave it out of the fitted parameters"
    )
