"""Model-discrimination design: the next experiment that best tells two (or more) candidate causes apart.

Each candidate is a cell fitted to the data so far (its cause's parameters at their fitted values). For a candidate
experiment (a library profile at an ambient temperature the chamber can reach) each cell's voltage (and, where
compared, surface temperature) is simulated with its exact sensitivities; the criterion is Atkinson and Fedorov's
T-optimality, linearised: the divergence one cell's prediction keeps from the other's after the other refits its own
parameters,

    T_ab = min_δ ‖W^½ (ŷ_a − ŷ_b − S_b δ)‖²,

with W the noise model's weights (eqs. 37–40), taken both ways (the experiment must separate them whichever is
true): T = min(T_ab, T_ba). Under Gaussian noise with the weights' variance, T/2 is the Kullback–Leibler divergence of
the two predictions after refitting, so T is about the χ² by which the wrong one will miss. The chosen experiment
maximises T per lab hour among those that reach a divergence worth running (:data:`T_ENOUGH`), else maximises T.
An experiment that would pass a cell's voltage window or its temperature limit on either candidate is excluded
and said (the run's safety limits would abort it, or the plan's window refuse it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.noise import NoiseModel
from protocols.profile import Profile

#: a divergence (χ²) above this separates the candidates with room to spare: the cheapest such experiment is taken
T_ENOUGH = 100.0
#: preparation before each profile (a full charge, a discharge to the start SOC, a rest) and the rest after [h]
PREPARATION_H = 2.0


@dataclass(frozen=True)
class Option:
    """One candidate experiment: a library profile at an ambient [K], its divergence T (χ² units), its lab hours, and
    why it was excluded (None: it can run)."""

    profile_id: str
    ambient: float
    divergence: float
    hours: float
    excluded: str | None = None

    @property
    def per_hour(self) -> float:
        return self.divergence / self.hours if self.hours > 0 else 0.0


@dataclass(frozen=True)
class Discrimination:
    """The chosen experiment (None: nothing can run), every option weighed, and the candidates compared."""

    causes: tuple[str, ...]
    chosen: Option | None
    options: tuple[Option, ...] = field(default_factory=tuple)

    def summary(self) -> dict[str, object]:
        return {
            "causes": list(self.causes),
            "criterion": "T-optimal (Atkinson-Fedorov, linearised), both ways: chi2 by which the wrong cause misses",
            "chosen": None if self.chosen is None else self.chosen.__dict__,
            "options": [o.__dict__ for o in sorted(self.options, key=lambda o: -o.divergence)],
            "excluded": [
                {"profile": o.profile_id, "ambient_degC": o.ambient - 273.15, "why": o.excluded}
                for o in self.options
                if o.excluded
            ],
        }


def _t_criterion(ya: np.ndarray, yb: np.ndarray, Sb: np.ndarray, w: np.ndarray) -> float:
    """min_δ ‖W^½ (ya − yb − Sb δ)‖² (linear least squares)."""
    sw = np.sqrt(w)
    d = (ya - yb) * sw
    if Sb.size == 0:
        return float(d @ d)
    A = Sb * sw[:, None]
    delta, *_ = np.linalg.lstsq(A, d, rcond=None)
    rest = d - A @ delta
    return float(rest @ rest)


def _anchored(
    models: Mapping[str, tuple[Cell, Sequence[str]]],
    profile: Profile,
    soc0: float,
    ambient: float,
    runs: dict,
    cache: dict | None = None,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per model (voltage, sensitivities) of the option's run stacked on the same profile's run at ``ambient``
    (the anchor: a refit must keep the data already taken there); the option's run alone where the anchor run stops.
    ``cache``: the profile's anchor runs by model, shared by its options at every ambient."""
    from battlab.simulation import simulate

    cache = {} if cache is None else cache
    out = {}
    for key, (cell, names) in models.items():
        r = runs[key]
        if key not in cache:
            cache[key] = simulate(cell, profile, soc0=soc0, ambient=ambient, T0=ambient, sensitivities=list(names))
        a = cache[key]
        if a.ended_by is not None or a.voltage.size < profile.t.size:
            return {k: (v.voltage, _sens(v)) for k, v in runs.items()}
        out[key] = (np.concatenate([r.voltage, a.voltage]), np.vstack([_sens(r), _sens(a)]))
    return out


def _sens(res: Any) -> np.ndarray:
    """A simulation's sensitivities (an empty block when it computed none)."""
    return res.sensitivities if res.sensitivities is not None else np.zeros((res.voltage.size, 0))


def weigh(
    models: Mapping[str, tuple[Cell, Sequence[str]]],
    profile: Profile,
    soc0: float,
    ambient: float,
    noise: NoiseModel,
    limits: tuple[float, float, float],
    anchor: float | None = None,
    anchor_runs: dict | None = None,
) -> Option:
    """The option of one profile at one ambient: ``models`` maps each cause to its fitted cell and the parameters
    it would refit; ``limits`` (V_min, V_max [V], T_max [K]) those of the run. ``anchor`` [K]: the ambient of the
    data already taken; at another ambient each refit must also keep the same profile's prediction there (a nested
    alternative that a base parameter mimics at the anchor shows where that parameter's temperature dependence
    differs from the alternative's); ``anchor_runs``: the profile's runs there, filled and reused across ambients."""
    from battlab.simulation import simulate

    v_min, v_max, t_max = limits
    runs = {}
    for key, (cell, names) in models.items():
        res = simulate(cell, profile, soc0=soc0, ambient=ambient, T0=ambient, sensitivities=list(names))
        if res.ended_by is not None or res.voltage.size < profile.t.size:
            return Option(str(profile.id), ambient, 0.0, 0.0, f"{key}: the run would stop ({res.ended_by})")
        if res.voltage.min() < v_min or res.voltage.max() > v_max:
            return Option(str(profile.id), ambient, 0.0, 0.0, f"{key}: the voltage leaves {v_min}-{v_max} V")
        if res.T_surface is not None and float(np.max(res.T_surface)) > t_max:
            return Option(str(profile.id), ambient, 0.0, 0.0, f"{key}: the surface passes {t_max - 273.15:.0f} degC")
        runs[key] = res
    if anchor is not None and abs(anchor - ambient) <= 0.5 and anchor_runs is not None:
        anchor_runs.update(runs)  # this option is the anchor run
    if anchor is not None and abs(anchor - ambient) > 0.5:
        stacked = _anchored(models, profile, soc0, anchor, runs, anchor_runs)
    else:
        stacked = {k: (r.voltage, _sens(r)) for k, r in runs.items()}
    q = noise.q(profile)
    keys = list(stacked)
    w = np.full(stacked[keys[0]][0].size, 1.0 / max(q, noise.floor) ** 2)
    t = np.inf
    for a in keys:
        for b in keys:
            if a != b:
                t = min(t, _t_criterion(stacked[a][0], stacked[b][0], stacked[b][1], w))
    hours = float(profile.t[-1] - profile.t[0]) / 3600.0 + PREPARATION_H
    return Option(str(profile.id), ambient, float(t), hours)


def discriminate(
    models: Mapping[str, tuple[Cell, Sequence[str]]],
    profiles: Sequence[Profile],
    ambients: Sequence[float],
    *,
    noise: NoiseModel | None = None,
    limits: tuple[float, float, float] | None = None,
    budget_hours: float | None = None,
    anchor: float | None = None,
) -> Discrimination:
    """Weigh every profile (at its ``soc0``) at every ambient [K] and choose (see the module docstring); options over
    ``budget_hours`` are excluded; ``anchor``: see :func:`weigh`."""
    noise = noise or NoiseModel()
    first = next(iter(models.values()))[0]
    lim = limits or (float(first["V_min"]), float(first["V_max"]), float(first["T_max"]))
    options = []
    # the anchor's own ambient first: its runs are the ones the other ambients' options stack on
    order = sorted(ambients, key=lambda a: anchor is None or abs(float(a) - anchor) > 0.5)
    for p in profiles:
        at_anchor: dict = {}
        for amb in order:
            soc0 = float(p.soc0 if p.soc0 is not None else 0.5)
            o = weigh(models, p, soc0, float(amb), noise, lim, anchor, at_anchor)
            if o.excluded is None and budget_hours is not None and o.hours > budget_hours:
                o = Option(o.profile_id, o.ambient, o.divergence, o.hours, f"{o.hours:.1f} h over the budget")
            options.append(o)
    ok = [o for o in options if o.excluded is None]
    enough = [o for o in ok if o.divergence >= T_ENOUGH]
    chosen = max(enough, key=lambda o: o.per_hour) if enough else max(ok, key=lambda o: o.divergence, default=None)
    return Discrimination(tuple(models), chosen, tuple(options))


__all__ = ["PREPARATION_H", "T_ENOUGH", "Discrimination", "Option", "discriminate", "weigh"]
