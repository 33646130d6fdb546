"""What data inform a model extension's parameters, as the causes declare it (:mod:`battlab.causes`): per cause the
library profile kind and the experiment that identifies it, and the check that refuses to fit a parameter the
given data cannot inform (a fit of it would wander to a bound): e.g. activation-energy changes with every
experiment at one ambient temperature, hysteresis without a rest after charge and after discharge."""

from __future__ import annotations

from collections.abc import Sequence

from battlab import causes
from battlab.causes.evidence import AMBIENT_TOL_K, REST_MIN_S, one_ambient, rests_after_both_directions
from battlab.identify.experiments import Experiment
from protocols.errors import InputError

#: per cause: the library profile kind (``protocols.library.KINDS``) and the experiment that informs it (and
#: separates it from what it is confused with on data that cannot tell)
INFORMED_BY: dict[str, tuple[str, str]] = {c.key: (c.informed_by.kind, c.informed_by.experiment) for c in causes.CAUSES}


def uninformed(names: Sequence[str], experiments: Sequence[Experiment], i_rest: float) -> dict[str, str]:
    """Of the parameter ``names`` (``KEY.NAME`` for extensions), those ``experiments`` cannot inform, with why."""
    out: dict[str, str] = {}
    for c in causes.CAUSES:
        out.update(c.not_informed(names, experiments, i_rest))
    return {n: out[n] for n in names if n in out}


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


__all__ = [
    "AMBIENT_TOL_K",
    "INFORMED_BY",
    "REST_MIN_S",
    "check_informed",
    "one_ambient",
    "rests_after_both_directions",
    "uninformed",
]
