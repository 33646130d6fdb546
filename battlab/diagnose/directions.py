"""The score tests' directions from the model itself: each catalog extension's exact sensitivities at its "off"
values, beside the base parameters', on the data's own profile (the inputs of
:func:`battlab.diagnose.score.score_test`).

At "off" the extended model is the base model, so one simulation with the extension on at "off" gives both: the base
parameters' columns J and the extension's columns S, dV/dθ̄ on the same steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from battlab import causes, parameters
from battlab.cell import Cell
from battlab.identify.forward import ForwardModel
from battlab.model.extensions import CATALOG
from battlab.simulation import simulate
from battlab.threads import thread_map
from protocols.profile import Profile

#: causes score-tested by default: every catalog extension whose voltage is differentiable at "off" (the double
#: layer's is not at C_dl = 0: for any C_dl > 0 the right limit at a current step holds the overpotential); the
#: causes' base parameters are weighed by how much of the residual they take up
#: (:func:`battlab.diagnose.mechanisms.shares`)
DEFAULT_CAUSES: tuple[str, ...] = tuple(c.key for c in causes.extended() if c.differentiable_at_off)

#: per catalog cause: a typical size of its parameters' change from "off" (physical units, magnitude, as the causes
#: declare them; a parameter not listed, e.g. a hysteresis decay rate, is no size), against which the smallest
#: change a data set would detect is compared
TYPICAL: dict[str, dict[str, float]] = {c.key: c.typical for c in causes.extended() if c.typical}


@dataclass(frozen=True)
class Directions:
    """One extension's score-test inputs on one profile: J (n_t × p) of the base parameters, S (n_t × q) of the
    extension's (in ``names`` order), the voltage at "off" [V] (the base model's) and the samples reached."""

    cause: str
    J: np.ndarray
    S: np.ndarray
    names: tuple[str, ...]
    voltage: np.ndarray
    S_T: np.ndarray | None = None  # the extension's dT_surface/dθ̄ (n_t × q) [K]


def extension_directions(
    cell: Cell,
    profile: Profile,
    soc0: float,
    base_names: Sequence[str],
    *,
    causes: Sequence[str] | None = None,
    ambient: float = 298.15,
    isothermal: bool = False,
    T0: float | None = None,
    v_limits: tuple[float, float] | None = None,
) -> list[Directions]:
    """Directions of the extensions :data:`DEFAULT_CAUSES` (or ``causes``) at the fitted base ``cell``: its
    extensions are switched off first; one that cannot run here (``thermal`` when isothermal) is left out.
    ``ambient``, ``T0`` [K] and ``v_limits`` [V] as in :func:`battlab.simulate` (measured data may pass the cell's
    window: widen it as the replay of a log does); the arrays end where the simulation stopped."""
    base = cell
    for key in list(cell.extensions):
        base = base.without_extension(key)
    keys = [k for k in (causes or DEFAULT_CAUSES) if k in CATALOG and not (isothermal and CATALOG[k].requires_thermal)]
    models = {k: base.with_extension(k) for k in keys}
    # the models are built here, one after the other; their simulations then run side by side
    compiled = all(ForwardModel(m, isothermal=isothermal).thread_safe for m in models.values())

    def one(key: str) -> Directions:
        names = tuple(p.qualified for p in parameters.EXTENSIONS[key])
        res = simulate(
            models[key],
            profile,
            soc0=soc0,
            ambient=ambient,
            isothermal=isothermal,
            sensitivities=[*base_names, *names],
            T0=T0,
            v_limits=v_limits,
        )
        sens, sens_T = res.sensitivities, res.sensitivities_T
        p = len(base_names)
        return Directions(key, sens[:, :p], sens[:, p:], names, res.voltage, None if sens_T is None else sens_T[:, p:])

    return thread_map(one, keys, None if compiled else 1)
