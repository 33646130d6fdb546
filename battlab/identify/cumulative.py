"""The one cumulative, group-wise fit (docs/decisions.md), used by ``battlab fit``, the campaign and the benchmarks:
stage k fits the parameters of groups 1..k on the experiments of stages 1..k, starting where stage k − 1 ended;
the final intervals are the last stage's.

The same defaults everywhere (:class:`FitSettings`): parameters the data cannot inform are refused before any
simulation (:func:`battlab.identify.informing.check_informed`), and where a stage would estimate all four orbit
parameters of an electrode its R_s is held at the stage's start value and the identifiable invariants τ, κ, ρ are
fitted and reported (:mod:`battlab.identify.reduced`); a stage that ends with such an electrode's D_s, k or R_f at a
bound is fitted again from the point of the orbit where it has room (the bound was the held R_s's, not the data's).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial

from battlab.cell import Cell
from battlab.identify import fit as F
from battlab.identify import reduced
from battlab.identify.ageing import Ageing
from battlab.identify.experiments import Experiment
from battlab.identify.fit import FitResult, Stage, StageError
from battlab.identify.forward import ForwardModel
from battlab.identify.informing import check_informed
from battlab.progress import Reporter


@dataclass(frozen=True)
class FitSettings:
    """The stopping rule and defaults of every cumulative fit: ``max_evaluations`` simulations per stage, of which
    up to ``polish`` for Gauss–Newton steps after the optimiser stops at its limit (:data:`battlab.identify.fit.
    Options`); ``hold_radii``: fit the identifiable coordinates; ``refuse_uninformed``: refuse parameters the data
    cannot inform; ``workers``: threads per evaluation (None: one per core; results do not depend on it);
    ``soc_span`` > 0: each experiment's start SOC is fitted within ± ``soc_span`` of its own, from where the last
    stage left it (:func:`battlab.identify.fit.fit`; for measurements whose start SOC is not known exactly: a
    still-relaxing rest voltage, a full charge that stops a little short of SOC 1); ``widen``: how far [θ̄] the
    search box reaches beyond the built-in ranges (:attr:`battlab.identify.fit.Options.widen`)."""

    max_evaluations: int = 40
    polish: int = 8
    hold_radii: bool = True
    refuse_uninformed: bool = True
    workers: int | None = None
    soc_span: float = 0.0
    widen: float = 0.0

    def options(self) -> F.Options:
        return F.Options(max_nfev=self.max_evaluations, polish=self.polish, workers=self.workers, widen=self.widen)


#: a stage whose held electrode ends with D_s, k or R_f at a bound is fitted again from another point of its orbit
#: (:func:`battlab.identify.reduced.reseated`) at most this many times, kept when it ends at a lower cost
RESEATS = 2


def _aged(ageing: Ageing | None, res: FitResult) -> Ageing | None:
    """The per-file ageing values starting where ``res`` left them."""
    if ageing is None:
        return None
    values = res.extra.get("ageing", {})
    return ageing.with_start({f: {n: v["value"] for n, v in d.items()} for f, d in values.items()})


def stage_names(stages: Sequence[Stage], hold_radii: bool) -> list[tuple[list[str], list[str]]]:
    """Per stage (cumulative): the names fitted and the radii held."""
    names: list[str] = []
    out = []
    for stg in stages:
        names += [n for n in stg.names if n not in names]
        fitted, held = reduced.split(names) if hold_radii else (list(names), [])
        out.append((fitted, held))
    return out


def check_stages_informed(stages: Sequence[Stage], cell: Cell) -> None:
    """Refuse, before any simulation, a stage whose data (its own and every earlier stage's) cannot inform one of
    its parameters: one :class:`InputError` naming it and the experiment that would."""
    seen: list[Experiment] = []
    for st in stages:
        seen += [e for e in st.experiments if e not in seen]
        check_informed(st.names, seen, 0.01 * float(cell["Q_nom"]))


def fit_cumulative(
    cell: Cell,
    stages: Sequence[Stage],
    settings: FitSettings = FitSettings(),
    *,
    forward: ForwardModel | None = None,
    ageing: Ageing | None = None,
    on_stage: Callable[[int, FitResult], None] | None = None,
    progress: Reporter | None = None,
) -> list[FitResult]:
    """Fit ``stages`` cumulatively from ``cell`` (see the module docstring). ``ageing``
    (:class:`battlab.identify.ageing.Ageing`): per-file ageing values, each stage starting from the last one's.
    ``on_stage(k, result)`` is called after each stage, before the next starts (to keep each finished stage);
    ``progress`` gets ``start``/``advance``/``stop`` events per stage (evaluation k of the stage's limit, its cost).

    Errors in stage k (its fit or ``on_stage``) are raised as :class:`battlab.identify.fit.StageError` with the
    finished stages; an interrupt passes through unchanged."""
    if settings.refuse_uninformed:
        check_stages_informed(stages, cell)
    fm = forward or ForwardModel(cell)
    plan = stage_names(stages, settings.hold_radii)
    current = cell
    exps: list[Experiment] = []
    results: list[FitResult] = []
    opts = settings.options()
    socs: dict[str, float] = {}  # start SOCs fitted so far (soc_span > 0): the next stage starts there
    for k, (stg, (fitted, held)) in enumerate(zip(stages, plan, strict=True), start=1):
        exps += list(stg.experiments)
        rep = progress.child(f"stage {k} of {len(stages)}") if progress is not None else None

        def tick(n: int, cost: float, _rep: Reporter | None = rep) -> None:
            if _rep is not None:
                _rep("advance", n, opts.max_nfev, f"cost {cost:.4g}")

        try:
            if rep is not None:
                rep("start", 0, opts.max_nfev, f"{len(fitted)} parameters, {len(exps)} experiments")
            run = partial(
                F.fit,
                cell,
                list(exps),
                fitted,
                options=opts,
                forward=fm,
                stage=k,
                soc_span=settings.soc_span,
                on_evaluation=tick,
            )
            res = run(start=current, soc_start=socs, ageing=ageing)
            tries = [res.convergence]
            for _ in range(RESEATS if held else 0):  # a bound the held R_s imposes: the same stage from another R_s
                moved = reduced.reseated(res.cell, held, {e.name: e.at_bound for e in res.statistics.estimates})
                if moved is None:
                    break
                if rep is not None:
                    where = ", ".join(f"{r} × {m:.3g}" for r, m in moved[1].items())
                    rep("start", 0, opts.max_nfev, f"again from {where} (its orbit, where no bound holds it)")
                again = run(start=moved[0], soc_start={**socs, **res.extra.get("soc0", {})}, ageing=_aged(ageing, res))
                tries.append(again.convergence)
                if not again.convergence.cost < res.convergence.cost:
                    break
                before = res.extra.get("reseated", {})  # R_s over the held start value: the product of the moves
                again.extra["reseated"] = {r: before.get(r, 1.0) * moved[1].get(r, 1.0) for r in {*before, *moved[1]}}
                res = again
            if len(tries) > 1:  # the stage's cost is all its fits'
                spent = {"iterations": sum(t.iterations for t in tries), "seconds": sum(t.seconds for t in tries)}
                res = replace(res, convergence=replace(res.convergence, **spent))
            socs.update(res.extra.get("soc0", {}))
            ageing = _aged(ageing, res)
            if held:
                res = replace(res, statistics=reduced.with_held(res.statistics, reduced.held_values(res.cell, held)))
            if rep is not None:
                rep("stop", res.convergence.iterations, opts.max_nfev, res.convergence.reason)
            if on_stage is not None:
                on_stage(k, res)
        except Exception as exc:
            if rep is not None:
                rep("failed", text=str(exc))
            raise StageError(k, len(stages), fitted + held, results, exc) from exc
        results.append(res)
        current = res.cell
    return results


__all__ = ["RESEATS", "FitSettings", "Stage", "StageError", "check_stages_informed", "fit_cumulative", "stage_names"]
