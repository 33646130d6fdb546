"""The held-out confirmation of a diagnosis: fits on the training part, judged on the held-out part.

Candidates, each fitted on the training part with the same optimiser and stopping rule, on every logged channel:

- the cell as given (no fit);
- the base refit: the :data:`N_BASE` base parameters whose directions explain most of the residual, whichever cause
  owns them;
- each leading cause as a mechanism: its own base parameters (those the cell holds inside their search range) and
  its extension's parameters the data inform.

The baseline is the better of the cell as given and the base refit on the held-out part. A cause is named only when
its fit beats the baseline by :data:`MIN_GAIN` (held-out RMS of the noise-normalised errors) *and* by more than the
data's noise can produce (:func:`battlab.diagnose.held_out.improvement_z` ≥ :data:`Z_MIN`), and beats every other
cause's fit the same way; causes whose fits the data cannot tell apart are a pair, with the experiment that
separates them. When the base refit is the baseline and explains the residual, the cause whose own fit does as well
is named ("refit these": its base parameters). Fits that predict the held-out part worse than no fit are said.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from battlab import causes, parameters
from battlab.cell import Cell
from battlab.diagnose import testability
from battlab.diagnose.confirmation import Confirmation
from battlab.diagnose.data import V_MARGIN, Part
from battlab.diagnose.held_out import HeldOut, held_out, improvement_z
from battlab.identify.experiments import Experiment
from battlab.threads import thread_map
from protocols.errors import InputError

#: causes whose mechanism is fitted and checked on held-out data: those owning the base refit's parameters, the
#: leading passing ones, those whose directions take up most of the residual
CONFIRM = 5
#: at most this many causes fitted (the leading ones and those indistinguishable from them)
MAX_CONFIRM = 6
#: base parameters of the cause-blind base refit
N_BASE = 3
#: relative held-out gain (RMS of noise-normalised errors) a cause's fit must show over the baseline to be named
MIN_GAIN = 0.3
#: ... and by this many standard errors of the paired block test (calibrated on null cases made by PyBaMM)
Z_MIN = 4.0
#: two causes' fits within this relative held-out difference (RMS of noise-normalised errors) are a pair
TIE = 0.1
#: relative held-out gain of a passing cause's fit below which its passing is taken as chance
SOME_GAIN = 0.02
#: the mean squared residual over the data's own noise variance above this with no cause named: the verdict says
#: plainly that the model misses the data
S2_REFIT = 10.0
#: a cause whose direction keeps less than this share after the others' base directions are projected out is one
#: the other causes' base parameters mimic on these data
MIMICKED = 0.05


#: how far [θ̄] each fit's search box reaches beyond the built-in range of the 18 (:attr:`battlab.identify.fit.Options.
#: widen`): the ranges are the paper cell's, and a cell from another file may differ from it by more (PyBaMM's
#: electrolyte diffusivity × 0.25 beside D_e_scale's 0.5-1.5)
WIDEN = 0.5


def fittable(cell: Cell, name: str) -> bool:
    """Whether a fit from ``cell`` can move the base parameter over its whole search box
    (:func:`battlab.identify.fit.search_box` widened by :data:`WIDEN`, extended to hold a value the cell keeps outside
    it): a box whose ends make an impossible cell (an electrolyte volume fraction the cell's active material leaves
    no room for) would stop the fit that tries them."""
    from battlab.identify.fit import search_box

    (lo,), (hi,) = search_box(cell, [name], WIDEN)
    try:
        cell.with_normalised(**{name: float(lo)}).with_normalised(**{name: float(hi)})
    except InputError:
        return False
    return True


def relevance(J: np.ndarray, r: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per column of ``J``: |cos| of the angle between its direction and the residual ``r`` (weights ``w``): how
    much of the residual a small move of that parameter alone would explain."""
    Jw = J * np.sqrt(w)[:, None]
    norm = np.sqrt(np.sum(Jw**2, axis=0))
    return np.abs(Jw.T @ (r * np.sqrt(w))) / np.where(norm > 0, norm, np.inf)


def refit_names(cell: Cell, J: np.ndarray, r: np.ndarray, w: np.ndarray, names: Sequence[str]) -> tuple[str, ...]:
    """The :data:`N_BASE` base parameters whose directions explain most of the residual ``r`` (:func:`relevance`),
    among those ``cell`` can refit (:func:`fittable`)."""
    rel = relevance(J, r, w)
    inside = np.array([fittable(cell, n) for n in names])
    order = [k for k in np.argsort(rel)[::-1] if inside[k]]
    return tuple(names[k] for k in order[:N_BASE])


#: the particle radii, held in every cause's fit: by the scaling symmetry (R_s, D_s, k, R_f) → (λR_s, λ²D_s, λk,
#: R_f/λ) a radius moved with its diffusivity changes κ = k/R_s and ρ = R_f·R_s at the same τ = R_s²/D_s, so a
#: solid-diffusion fit that moved R_s took up a change of the reaction rates (PyBaMM's k × 0.3 was named
#: solid_diffusion); D_s alone spans τ at the cell's radius
HELD_RADII = ("R_s_n", "R_s_p")


#: a cause's fit moves at most this many of its base parameters, the most relevant to the residual: more, with nearly
#: dependent directions, let 20 evaluations wander to a corner of the box (PyBaMM's electrolyte case: 8 electrolyte
#: parameters ended at their upper bounds, 9.3 mV held out, where the base refit's D_e_scale alone reached 2.5 mV)
MECHANISM_BASE = 4


def mechanism_names(
    cell: Cell, key: str, informed: Sequence[str], relevant: Mapping[str, float] | None = None
) -> tuple[str, ...]:
    """What a cause's fit moves: its base parameters among the 18 that ``cell`` can refit (the radii held:
    :data:`HELD_RADII`), with ``relevant`` (name → :func:`relevance`) the :data:`MECHANISM_BASE` most relevant of
    them, then its extension's ``informed`` parameters (``KEY.NAME``)."""
    c = causes.cause(key)
    base = [n for n in parameters.NAMES if n in c.base and n not in HELD_RADII and fittable(cell, n)]
    if relevant is not None:
        base = sorted(base, key=lambda n: -relevant.get(n, 0.0))[:MECHANISM_BASE]
        base = [n for n in parameters.NAMES if n in base]
    return (*base, *informed)


@dataclass
class Candidate:
    """One fit of the confirmation (``key`` a cause, or ``"base"``: the base refit) and its held-out errors."""

    key: str
    names: tuple[str, ...]
    confirmation: Confirmation
    held: HeldOut


def confirm(
    cell: Cell,
    specs: Sequence[tuple[str, tuple[str, ...]]],
    train: Sequence[Experiment],
    parts: Sequence[Part],
    max_iter: int,
) -> list[Candidate]:
    """Per (key, names): fit ``names`` on ``train`` (the cause's extension switched on for a cause that has one; the
    voltage and the logged temperature) and score the fit on the held-out ``parts``. The models are built one after
    the other, their fits then run side by side."""
    from battlab.identify.fit import Options, fit
    from battlab.identify.forward import ForwardModel

    def model(key: str) -> Cell:
        return cell.with_extension(key) if key != "base" and causes.cause(key).extension is not None else cell

    models = [model(k) for k, _ in specs]
    fms = [ForwardModel(m, v_margin=V_MARGIN) for m in models]
    compiled = all(fm.thread_safe for fm in fms)

    def one(k: int) -> Candidate:
        key, names = specs[k]
        res = fit(
            models[k],
            list(train),
            names,
            options=Options(max_nfev=max_iter, temperature=True, widen=WIDEN),
            forward=fms[k],
        )
        rmse_train = float(np.sqrt(np.mean([v**2 for v in res.rmse_mV.values()]))) if res.rmse_mV else float("nan")
        held = held_out(fms[k], res.cell, parts)
        conf = Confirmation(
            key,
            names,
            {n: float(res.cell.value(n)) for n in names},
            rmse_train,
            held.rmse_mV,
            bool(res.convergence.converged),
            held.metric,
            held.rmse_K,
        )
        return Candidate(key, names, conf, held)

    return thread_map(one, range(len(specs)), None if compiled else 1)


@dataclass
class Verdict:
    """What the confirmation decided: the cause named (or None) and how (``"extension"``, ``"refit"``), the
    baseline (``"cell"`` or ``"base refit"``) and its held-out errors, causes the data cannot tell apart, fits worse
    than no fit."""

    cause: str | None
    how: str | None
    baseline: str
    base: HeldOut
    chosen: Candidate | None
    pairs: list[list[str]] = field(default_factory=list)
    worse: list[str] = field(default_factory=list)
    z: float = 0.0
    #: causes in ``pairs`` these data cannot fit (their evidence is missing) though they pass their score test
    untested: tuple[str, ...] = ()


def withhold(v: Verdict, twins: Sequence[tuple[str, str, float]], untested: set[str]) -> Verdict:
    """The verdict with its named cause (or the group its fits cannot tell apart) joined by the causes these data
    cannot fit (``untested``: passing their score test ahead of the named cause, their evidence missing) that are
    indistinguishable from it (``twins``): the fit of the named cause may then stand in for the untested one (e.g.
    an OCV shift for a one-state hysteresis on a drive that never rests after a charge), so they are a group, with
    the experiment that tests the untested one."""
    members = [v.cause] if v.cause is not None else (v.pairs[0] if v.pairs else [])
    alike = [b if a in members else a for a, b, _ in twins if (a in members) != (b in members)]
    hidden = tuple(k for k in dict.fromkeys(alike) if k in untested)
    if not hidden:
        return v
    return replace(v, cause=None, pairs=[[*members, *hidden], *v.pairs[1:]], untested=hidden)


def _beats(a: HeldOut, b: HeldOut, block_s: float, gain: float = MIN_GAIN) -> bool:
    """Whether ``b`` predicts better than ``a`` by ``gain`` and by more than noise (:data:`Z_MIN`)."""
    return b.metric <= (1.0 - gain) * a.metric and improvement_z(a, b, block_s) >= Z_MIN


def decide(cell: HeldOut, base_fit: Candidate | None, fits: Sequence[Candidate], block_s: float) -> Verdict:
    """The decision of the module docstring."""
    baseline, base = "cell", cell
    if base_fit is not None and base_fit.held.metric < cell.metric:
        baseline, base = "base refit", base_fit.held
    worse = [f.key for f in fits if f.held.metric > cell.metric]
    winners = sorted((f for f in fits if _beats(base, f.held, block_s)), key=lambda f: f.held.metric)
    if winners:
        best = winners[0]
        ties = [f.key for f in winners[1:] if f.held.metric <= (1.0 + TIE) * best.held.metric]
        z = improvement_z(base, best.held, block_s)
        if ties:
            return Verdict(None, None, baseline, base, best, [[best.key, *ties]], worse, z)
        return Verdict(best.key, "extension", baseline, base, best, [], worse, z)
    if baseline == "base refit" and base_fit is not None and _beats(cell, base_fit.held, block_s):
        alike = sorted(
            (f for f in fits if f.held.metric <= (1.0 + TIE) * base_fit.held.metric), key=lambda f: f.held.metric
        )
        z = improvement_z(cell, base_fit.held, block_s)
        if len(alike) == 1:
            return Verdict(alike[0].key, "refit", "cell", cell, alike[0], [], worse, z)
        if len(alike) > 1:
            return Verdict(None, "refit", "cell", cell, alike[0], [[f.key for f in alike]], worse, z)
    return Verdict(None, None, baseline, base, None, [], worse)


#: a cause whose own directions take up at least this share of the largest share is fitted (when the base
#: directions explain the residual beyond the noise)
SHARE_OF_BEST = 0.5
#: a cause whose own directions take up at least this part of what the base directions leave of the residual is
#: fitted first: its extension explains what no refit can (an adiabatic cell logged as cooled: the 18 base directions
#: take 0.4 % of the residual, the thermal cause's 87 %)
BEYOND_BASE = 0.5


def candidates(
    passing: Sequence[Any],
    twins: Sequence[tuple[str, str, float]],
    share: dict[str, float] | None = None,
    owners: Sequence[str] = (),
    base_share: float = 1.0,
) -> list[str]:
    """The causes to fit. When the base directions explain the residual (``share`` given, with ``base_share`` the
    part the 18 base directions take): first the causes whose own directions take at least :data:`BEYOND_BASE` of
    the part the base directions leave; then ``owners`` (the causes that own the base refit's parameters: its fix
    may be theirs); then the leading passing extensions; then the causes whose own directions take up most of the
    residual (at least :data:`SHARE_OF_BEST` of the largest share); :data:`CONFIRM` of these in all; and any cause
    the data cannot tell apart from one of those (score directions alike, or an extension inside another cause's own
    directions: it need not pass, the other's parameters take up its effect); at most :data:`MAX_CONFIRM`."""
    by_share = sorted((share or {}).items(), key=lambda kv: -kv[1])
    left = max(1.0 - base_share, 1e-12)
    beyond = [k for k, v in by_share if (v - base_share) / left >= BEYOND_BASE]
    lead = list(dict.fromkeys([*beyond, *owners, *(s.cause for s in passing[:CONFIRM])]))
    if by_share:
        best = by_share[0][1]
        lead += [k for k, v in by_share if v >= SHARE_OF_BEST * best and k not in lead]
    lead = lead[:CONFIRM]
    alike = [b if a in lead else a for a, b, _ in twins if (a in lead) != (b in lead)]
    return [*lead, *(k for k in dict.fromkeys(alike) if k not in lead)][:MAX_CONFIRM]


def mimicked_by(J: np.ndarray, S: np.ndarray, w: np.ndarray, names: Sequence[str], n: int = 2) -> list[str]:
    """The ``n`` base parameters whose directions are most nearly parallel to the cause's first direction."""
    sw = np.sqrt(w)
    a = S[:, 0] * sw
    Jw = J * sw[:, None]
    den = np.sqrt(np.sum(Jw**2, axis=0)) * np.sqrt(np.sum(a**2))
    cos = np.abs(Jw.T @ a) / np.where(den > 0, den, np.inf)
    return [names[k] for k in np.argsort(cos)[::-1][:n] if cos[k] > 0]


def separating_experiment(keys: Sequence[str]) -> tuple[str, str]:
    """(library profile kind, the experiment) that tells the causes ``keys`` apart: what one of them declares for
    another (:attr:`battlab.causes.cause.Cause.separates`), else each one's own evidence."""
    cs = [causes.cause(k) for k in keys]
    for a in cs:
        for b in cs:
            if b.key in a.separates:
                return a.informed_by.kind, a.separates[b.key]
    return cs[0].informed_by.kind, "; ".join(f"{c.key}: {c.informed_by.experiment}" for c in cs)


def cannot_tell(v: Verdict, fits: Sequence[Candidate]) -> list[dict[str, Any]]:
    """The causes these data cannot decide between: each pair (or group) whose fits predict the held-out part
    alike, with why and the experiment that separates them; and, with no cause named, passing causes whose fit wins
    by :data:`SOME_GAIN` to :data:`MIN_GAIN` (a smaller win: the pass was chance)."""
    out: list[dict[str, Any]] = []
    for group in v.pairs:
        kind, experiment = separating_experiment(v.untested or group)
        fitted = [k for k in group if k not in v.untested]
        why = (
            f"their fits predict the held-out data alike ({', '.join(group)})"
            if not v.untested
            else f"{', '.join(v.untested)} passes its score test alike with {', '.join(fitted)}, and these data "
            "cannot fit it"
        )
        out.append(
            {
                "causes": list(group),
                "cause": group[0],
                "why": why,
                "kind": kind,
                "experiment": experiment,
            }
        )
    if v.cause is None and not v.pairs:
        for f in fits:
            gain = 1.0 - f.held.metric / v.base.metric
            if SOME_GAIN <= gain < MIN_GAIN or (gain >= MIN_GAIN and f.key != "base"):
                short = (
                    f"short of the {100 * MIN_GAIN:.0f} % that name it"
                    if gain < MIN_GAIN
                    else "but not by the noise margin (the paired block test's standard errors) that names it"
                )
                e = testability.cause_entry(
                    f.key,
                    f"passes its score test, and its fit lowers the held-out error by {100 * gain:.0f} %, {short}",
                )
                out.append({"causes": [f.key], **e})
    return out


__all__ = [
    "CONFIRM",
    "HELD_RADII",
    "MECHANISM_BASE",
    "MAX_CONFIRM",
    "MIMICKED",
    "MIN_GAIN",
    "N_BASE",
    "S2_REFIT",
    "SHARE_OF_BEST",
    "SOME_GAIN",
    "TIE",
    "WIDEN",
    "Z_MIN",
    "Candidate",
    "Verdict",
    "cannot_tell",
    "candidates",
    "confirm",
    "decide",
    "fittable",
    "mechanism_names",
    "mimicked_by",
    "refit_names",
    "relevance",
    "separating_experiment",
    "withhold",
]
