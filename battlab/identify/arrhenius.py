"""Activation energies (B5) from data at several ambient temperatures, through per-temperature refits.

The model scales D_s±, k±, D_e and κ with temperature as ψ(T) = ψ_ref exp[(E_ψ/R)(1/T_ref − 1/T)]. Fitted at the
reference temperature (the data nearest T_ref), a parameter refitted on the data of another ambient T (the
others held) gives the value ψ_T that, with the cell's present E_ψ, matches those data; the activation energy that
carries ψ_ref to it is E_ψ + R ln(ψ_T/ψ_ref)/(1/T_ref − 1/T). With several temperatures, the change is the
least-squares slope of ln(ψ_T/ψ_ref) against (1/T_ref − 1/T) through the origin (the reference point). Each refit
uses the exact sensitivities of the 18, so this costs one LM fit per temperature; the refits go from the ambient
nearest T_ref outwards, each starting where the ones before it carry the values if the cell predicts its data better
there (:func:`continued_start`: a cold test that the nominal energies make the cell fail would otherwise be refitted
from a simulation that stops early).

The fitted cell keeps the reference values and gets the new activation energies (clipped to
:data:`E_RANGE`). Whatever else differs between the tests at those temperatures (e.g. a cell that aged between
them) is attributed to the temperature as well: the report gives the per-temperature values to judge that; with
per-file ageing (:mod:`battlab.identify.ageing`) each refit also fits its files' own lithium and capacity.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from battlab.cell import R_GAS, Cell
from protocols.errors import InputError

#: dynamic parameter → its activation energy in the cell
ACTIVATION: dict[str, str] = {
    "D_s_n": "E_D_s_n",
    "D_s_p": "E_D_s_p",
    "k_n": "E_k_n",
    "k_p": "E_k_p",
    "D_e_scale": "E_D_e",
    "kappa_scale": "E_kappa",
}
#: [J/mol] the range an activation energy is kept in
E_RANGE = (0.0, 150e3)
#: [K] data whose ambient is this close to T_ref are reference data; others are grouped to the nearest kelvin
REF_TOL = 5.0
#: [θ̄] how far a refit's search box reaches beyond each parameter's built-in range (``fit.Options.widen``): a
#: per-temperature value is the reference value that the present activation energy carries to the data's ambient,
#: not a value at T_ref, so the reference ranges do not hold it (the Panasonic cell at 0 °C: κ_scale stopped on its
#: lower bound 0.5 with E_κ 35 kJ/mol, and the energies came out too low for the cold tests)
REFIT_WIDEN = 1.0


@dataclass
class ArrheniusFit:
    """Per-temperature values (ambient K → name → value), the activation energies before and after [J/mol], the
    cell with the new ones, and the refits' RMSE [mV] per experiment before and after."""

    cell: Cell
    names: tuple[str, ...]
    values: dict[float, dict[str, float]]
    start: dict[str, float]
    energies: dict[str, float]
    rmse_before_mV: dict[str, float] = field(default_factory=dict)
    rmse_after_mV: dict[str, float] = field(default_factory=dict)
    clipped: list[str] = field(default_factory=list)
    #: per-file ageing values of the refits (file -> name -> {value, ci95, ...}), with ``ageing``
    ageing: dict[str, dict[str, dict[str, object]]] = field(default_factory=dict)

    def report(self) -> dict[str, object]:
        return {
            "names": list(self.names),
            "values_by_ambient_K": {f"{t:.2f}": v for t, v in self.values.items()},
            "E_start_J_per_mol": self.start,
            "E_J_per_mol": self.energies,
            "clipped": self.clipped,
            "rmse_before_mV": self.rmse_before_mV,
            "rmse_after_mV": self.rmse_after_mV,
            **({"ageing": self.ageing} if self.ageing else {}),
        }


def split_by_ambient(experiments: Sequence, t_ref: float) -> tuple[list, dict[float, list]]:
    """(reference experiments within :data:`REF_TOL` of ``t_ref``, {ambient rounded to 0.1 K: experiments})."""
    ref, other = [], {}
    for e in experiments:
        if abs(e.ambient - t_ref) <= REF_TOL:
            ref.append(e)
        else:
            other.setdefault(round(float(e.ambient), 1), []).append(e)
    return ref, other


def activated(names: Sequence[str]) -> tuple[str, ...]:
    """The names among ``names`` that have an activation energy."""
    return tuple(n for n in names if n in ACTIVATION)


def fit_arrhenius(
    cell: Cell,
    groups: dict[float, list],
    names: Sequence[str],
    *,
    forward: object,
    options: object,
    ageing: object = None,
) -> ArrheniusFit:
    """Refit ``names`` (those with an activation energy) of the reference-fitted ``cell`` on each ambient's
    experiments and set the activation energies from the slopes (see the module docstring). ``ageing``
    (:class:`battlab.identify.ageing.Ageing`): each file's own ageing values are fitted in its ambient's refit (the
    temperature then explains only what ageing does not)."""
    from battlab.identify import fit as F

    names = activated(names)
    if not names:
        raise InputError(
            f"--arrhenius: none of the fitted parameters has an activation energy ({', '.join(ACTIVATION)})"
        )
    if not groups:
        raise InputError("--arrhenius needs data at an ambient temperature other than T_ref (more than 5 K away)")
    t_ref = float(cell["T_ref"])
    wide = replace(options, widen=max(options.widen, REFIT_WIDEN))
    values: dict[float, dict[str, float]] = {}
    before: dict[str, float] = {}
    after: dict[str, float] = {}
    aged: dict[str, dict[str, dict[str, object]]] = {}
    # nearest ambient first: each later refit may start where the ambients done so far carry the values
    for amb in sorted(groups, key=lambda a: (abs(a - t_ref), a)):
        exps = groups[amb]
        start = continued_start(cell, names, values, amb, forward, exps)
        res = F.fit(cell, exps, names, forward=forward, options=wide, ageing=ageing, start=start)
        aged.update(res.extra.get("ageing", {}))
        values[amb] = {n: float(res.cell[n]) for n in names}
        before.update(res.rmse_before_mV)
        after.update(res.rmse_mV)
    values = dict(sorted(values.items()))
    start = {ACTIVATION[n]: float(cell[ACTIVATION[n]]) for n in names}
    energies, clipped = slopes(cell, names, values)
    return ArrheniusFit(cell.with_values(**energies), names, values, start, energies, before, after, clipped, aged)


def slopes(cell: Cell, names: Sequence[str], values: dict[float, dict[str, float]]) -> tuple[dict[str, float], list]:
    """The activation energies [J/mol] that carry the reference values of ``cell`` to the per-temperature ``values``
    (least squares through the reference point, clipped to :data:`E_RANGE`) and the names of those clipped."""
    t_ref = float(cell["T_ref"])
    x = np.array([1.0 / t_ref - 1.0 / amb for amb in values])
    energies, clipped = {}, []
    for n in names:
        key = ACTIVATION[n]
        y = np.array([np.log(values[amb][n] / float(cell[n])) for amb in values])
        e_new = float(cell[key]) + R_GAS * float(np.dot(x, y) / np.dot(x, x))
        if not E_RANGE[0] <= e_new <= E_RANGE[1]:
            clipped.append(key)
            e_new = float(np.clip(e_new, *E_RANGE))
        energies[key] = e_new
    return energies, clipped


def continued_start(
    cell: Cell, names: Sequence[str], values: dict[float, dict[str, float]], amb: float, forward: object, exps: list
) -> Cell:
    """Where the refit at ambient ``amb`` [K] starts: of ``cell`` as it is (its present activation energies carry its
    reference values there) and, once nearer ambients are refitted, the values their slopes carry to ``amb`` and the
    values of the nearest refitted ambient held unchanged down to ``amb`` (no activation between them: the mildest
    extrapolation), the one that predicts ``exps`` best. A refit from a start whose simulation stops early gets no
    gradient from the samples it does not reach (the voltage is held after the stop) and ends far from a fit: the
    Panasonic cell's 0 °C US06 refit started at 580 mV from the nominal energies and ended at 314 mV; the 10 °C
    refit's slopes carry it to 393 mV, its values held to 114 mV, from where it ends at 62 mV (16 evaluations)."""
    if not values:
        return cell
    t_ref = float(cell["T_ref"])
    energies, _ = slopes(cell, names, values)
    x = 1.0 / t_ref - 1.0 / amb
    near = min(values, key=lambda a: abs(a - amb))
    x_near = 1.0 / t_ref - 1.0 / near
    candidates = [cell]
    for n_values in (
        {n: float(cell[n]) * np.exp((energies[ACTIVATION[n]] - float(cell[ACTIVATION[n]])) / R_GAS * x) for n in names},
        {n: values[near][n] * np.exp(float(cell[ACTIVATION[n]]) / R_GAS * (x_near - x)) for n in names},
    ):
        candidates.append(cell.with_values(**n_values))
    return min(candidates, key=lambda c: fit_cost(forward, c, exps))


def fit_cost(forward: object, cell: Cell, exps: Sequence) -> float:
    """½‖r‖² of ``cell`` on ``exps``: the fit's own weighted residual (:class:`battlab.identify.problem.Problem`,
    where a simulation that stops early holds its last voltage), without sensitivities."""
    from battlab.identify.problem import Problem

    r, _, _ = Problem(forward, exps, (), cell.theta_bar()).evaluate(np.zeros(0))
    return 0.5 * float(r @ r)
