"""What a data set can and cannot tell a diagnosis, whatever the residual says: the causes it cannot test at any size
(:func:`untestable`), the smallest change of each extension parameter it would detect (:func:`detectable_sizes`),
the parameters a score test should run on (:func:`informed_columns`) and the causes too small to see on it
(:func:`undetectable`), each with the experiment that would show them (:data:`battlab.identify.informing.INFORMED_BY`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from battlab import causes, parameters
from battlab.identify.experiments import Experiment
from battlab.identify.informing import INFORMED_BY


def cause_entry(cause: str, why: str, **extra: Any) -> dict[str, Any]:
    """One cause the data cannot decide, as the summary lists it: why, and the experiment that would decide it."""
    return {"cause": cause, "why": why, **extra, "kind": INFORMED_BY[cause][0], "experiment": INFORMED_BY[cause][1]}


def untestable(train: Sequence[Experiment], named: str | None, i_rest: float) -> list[dict[str, Any]]:
    """Causes this diagnosis cannot decide on whatever their size (so "no cause" says nothing about them), with the
    experiment that would, as each cause declares (:meth:`battlab.causes.cause.Cause.why_untestable`): e.g. the
    double layer, never score-tested (its voltage is not differentiable at C_dl = 0); the thermal extension's
    activation energies when every experiment has one ambient; hysteresis when the current never changes
    direction."""
    out = []
    for c in causes.extended():
        why = c.why_untestable(train, i_rest)
        if why is not None and c.key != named:
            out.append(cause_entry(c.key, why))
    return out


def detectable_sizes(
    cause: str,
    r: np.ndarray,
    J: np.ndarray,
    S: np.ndarray,
    w: np.ndarray,
    t: np.ndarray,
    p_threshold: float,
    block_s: float,
) -> dict[str, float]:
    """Per extension parameter of ``cause`` (its name, not qualified): the smallest change from "off" [its unit]
    these data detect at ``p_threshold`` (:func:`battlab.diagnose.score.detectable_size`, ``S`` in θ̄ per column in
    catalog order; inf: the base parameters mimic it)."""
    from battlab.diagnose.score import detectable_size

    specs = parameters.EXTENSIONS[cause]
    size = detectable_size(r, J, S, w, t, p_threshold, block_s=block_s)
    return {p.name: float(z * (p.upper - p.lower)) for p, z in zip(specs, size, strict=True)}


def informed_columns(cause: str, sizes: dict[str, float]) -> list[int]:
    """The columns of ``cause``'s parameters (catalog order) that these data would detect somewhere in their search
    range (smallest detectable change, :func:`detectable_sizes`, at most the range's width): the score test runs on
    those only, as a direction no value in range could show adds a degree of freedom to the test but no power (at
    one ambient the kinetics' activation energies need 10-100 × their range; over 25, 10 and 40 °C those of the
    reaction rates still do, and the nine-direction thermal test missed a 64 %-visible case at p 0.006 against
    0.0014). All columns when none is informed (the test then says so itself)."""
    specs = parameters.EXTENSIONS[cause]
    keep = [j for j, p in enumerate(specs) if sizes[p.name] <= p.upper - p.lower]
    return keep or list(range(len(specs)))


#: a cause whose effect lies this little (W-norm share) outside the free base parameters' directions is hidden
#: behind them, not small: its undetectable size says what they take up, not what the data rule out
HIDDEN_SHARE = 0.05


def undetectable(
    sizes: dict[str, dict[str, float]],
    skip: set[str],
    typical: dict[str, dict[str, float]],
    hidden: dict[str, tuple[float, list[str]]] | None = None,
) -> list[dict[str, Any]]:
    """Causes not seen whose typical size (:data:`battlab.diagnose.directions.TYPICAL`) is below the smallest these
    data would detect, for every parameter with a typical size: "too small to see" is then all that "no cause" says
    about them. Each with the sizes and the experiment that would show it. ``hidden``: per cause (the share of its
    effect outside the free base directions, the base parameters that mimic it); one below :data:`HIDDEN_SHARE`
    is said to be hidden behind them (``"hidden_by"``), not small: these data do not rule it out at any size."""
    out = []
    for cause, det in sizes.items():
        typ = {n: v for n, v in typical.get(cause, {}).items() if n in det}
        if cause in skip or not typ or any(abs(v) >= det[n] for n, v in typ.items()):
            continue
        units = {p.name: p.unit for p in parameters.EXTENSIONS[cause]}
        below = ", ".join(
            f"{n} below {det[n]:.3g} {units[n]} (typical {v:.3g})"
            if np.isfinite(det[n])
            else f"{n} (mimicked by the base)"
            for n, v in typ.items()
        )
        share, by = (hidden or {}).get(cause, (1.0, []))
        if share < HIDDEN_SHARE and by:
            why = (
                f"hidden behind {', '.join(by)} on these data (only {100 * share:.1f} % of its effect lies outside "
                f"the base parameters' directions): {below} is taken up by them, not ruled out"
            )
            entry = cause_entry(cause, why, smallest_detectable={n: det[n] for n in typ}, typical=typ, hidden_by=by)
        else:
            why = f"too small to see on these data: {below} goes undetected"
            entry = cause_entry(cause, why, smallest_detectable={n: det[n] for n in typ}, typical=typ)
        out.append(entry)
    return out
