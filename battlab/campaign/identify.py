"""The campaign's fits, validation scores and residual analysis on its own experiments.

The OED fit is ``battlab fit`` itself on the campaign's run logs (:func:`battlab.identify.workflow.fit`); the
conventional fit runs the same engine (:func:`battlab.identify.cumulative.fit_cumulative`) with the same settings, so
both share start point, optimiser, stopping rule (``[fit] max_evaluations``) and defaults, weighted by the noise
model fitted from repeated trials.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell


def _json(path: Path, data: Any) -> None:
    from battlab.jsonable import json_default

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, default=json_default))


def cumulative_fit(
    cell: Cell,
    stages: Sequence[Any],
    camp: Any,
    output: Path,
    progress: Callable[[float, float, str], None],
) -> dict[str, Any]:
    """Fit ``stages`` (:class:`battlab.identify.fit.Stage`) cumulatively from ``cell`` with the one engine and its
    defaults (:func:`battlab.identify.cumulative.fit_cumulative`: radii held, uninformed parameters refused); write
    the BPX cell and ``<stem>.summary.json`` beside it; return the summary (:mod:`battlab.identify.fit_summary`:
    per parameter value, interval and whether it can be trusted, the invariants, the stages) with, on the virtual
    lab, the recovery table against the truth."""
    from battlab.identify.cumulative import fit_cumulative
    from battlab.identify.fit_steps import bpx_metadata
    from battlab.identify.fit_summary import dynamic_summary
    from battlab.identify.forward import ForwardModel

    progress(0, len(stages), "stage 1")

    def done(k: int, res: Any) -> None:
        progress(k, len(stages), f"stage {k} of {len(stages)} done ({res.convergence.iterations} evaluations)")

    fm = ForwardModel(cell, v_margin=0.15)
    results = fit_cumulative(cell, stages, settings(camp), forward=fm, on_stage=done)
    summary = dynamic_summary(results, len(results))
    summary["data_hours"] = float(sum(e.hours for s in stages for e in s.experiments))
    finish(summary, camp, cell)
    output.parent.mkdir(parents=True, exist_ok=True)
    extra = bpx_metadata(summary, results[-1])
    results[-1].cell.renamed(output.name.removesuffix(".bpx.json")).to_bpx(output, **extra)
    _json(output.with_name(output.name.removesuffix(".bpx.json") + ".summary.json"), summary)
    return summary


def settings(camp: Any) -> Any:
    """The campaign's fit settings (``[fit]``), with the engine's defaults for the rest; the start SOCs free within
    the span of measurements with a logged preparation (their rest voltage is still relaxing)."""
    from battlab.identify.cumulative import FitSettings
    from battlab.identify.fit_options import PREPARED_SOC_SPAN

    return FitSettings(
        max_evaluations=camp.config.fit.max_evaluations, polish=camp.config.fit.polish, soc_span=PREPARED_SOC_SPAN
    )


def finish(summary: dict[str, Any], camp: Any, start: Cell) -> None:
    """On the virtual lab: the recovery table of a fit's summary against the truth (in place)."""
    if camp.tester.virtual:
        truth = Cell.load(camp.tester.truth)
        summary["recovery"] = recovery(summary, truth, start)
        summary["recovery_invariants"] = invariant_recovery(summary, truth, start)


def recovery(summary: dict[str, Any], truth: Cell, start: Cell) -> list[dict[str, Any]]:
    """Per parameter: start, truth, estimate, interval, whether it covers the truth and whether the
    interval is trusted (:mod:`battlab.identify.fit_summary`), and whether the truth sits on a bound (those are
    excluded from the coverage count, as decided in docs/decisions.md)."""
    from battlab import parameters

    rows = []
    for name, e in summary["parameters"].items():
        if name not in parameters.SPECS and name not in parameters.EXTENSION_SPECS:
            continue
        t = float(truth.value(name))
        tb = float(truth.normalised(name))
        ci = e["ci95"] if e.get("ci95") and e["ci95"][0] is not None else None
        rows.append(
            {
                "parameter": name,
                "start": float(start.value(name)),
                "truth": t,
                "estimate": e["value"],
                "ci95": ci,
                "covered": _covers(ci, t),
                "trusted": e.get("trusted"),
                "untrusted_because": e.get("untrusted_because", []),
                "truth_on_bound": bool(tb <= 1e-6 or tb >= 1 - 1e-6),
                "estimate_at_bound": e.get("bound"),
                "set_identified": e.get("set_identified", False),
                "theta_bar": {"start": float(start.normalised(name)), "truth": tb, "estimate": e.get("theta_bar")},
            }
        )
    return rows


def invariant_recovery(summary: dict[str, Any], truth: Cell, start: Cell) -> list[dict[str, Any]]:
    """Per identifiable invariant (τ, κ, ρ of an electrode whose four orbit parameters were fitted): start, truth,
    estimate, interval, whether it covers the truth and whether it is trusted."""
    from battlab.identify.symmetry import INVARIANTS

    rows = []
    for name, inv in summary.get("invariants", {}).items():
        powers = next(d[name] for d in INVARIANTS.values() if name in d)

        def value(c: Cell, powers: dict[str, int] = powers) -> float:
            out = 1.0
            for p, k in powers.items():
                out *= float(c[p]) ** k
            return out

        rows.append(
            {
                "parameter": name,
                "invariant": inv["definition"],
                "start": value(start),
                "truth": value(truth),
                "estimate": inv["value"],
                "ci95": inv["ci95"],
                "covered": _covers(inv["ci95"], value(truth)),
                "trusted": inv.get("trusted"),
                "untrusted_because": inv.get("untrusted_because", []),
                "truth_on_bound": False,
                "estimate_at_bound": None,
                "set_identified": False,
            }
        )
    return rows


def _covers(ci: Sequence[float] | None, value: float) -> bool | None:
    if ci is None:
        return None
    lo, hi = ci
    return bool(lo * (1 - 1e-12) <= value <= hi * (1 + 1e-12)) if lo > 0 else bool(lo <= value <= hi)


def score(
    logs: Mapping[str, tuple[Path, float]], cells: Mapping[str, Cell], truth: Cell | None, out: Path
) -> dict[str, Any]:
    """RMSE [mV] of each cell on each validation log (each cell starts from its own SOC at the logged rest
    voltage), against the noise-free true voltage on the virtual lab, else against the data; writes a figure per
    log and ``validation.json``."""
    from battlab.campaign import data as D
    from battlab.identify.forward import ForwardModel
    from battlab.identify.validation import plot_validation, prediction

    out.mkdir(parents=True, exist_ok=True)
    table: dict[str, dict[str, float]] = {label: {} for label in cells}
    coverage: dict[str, dict[str, float]] = {label: {} for label in cells}
    figures = {}
    forwards = {label: ForwardModel(c, v_margin=0.15) for label, c in cells.items()}
    for name, (path, dt) in logs.items():
        preds = {}
        ref_exp = None
        for label, c in cells.items():
            e = D.experiment(path, c, name=name, dt=dt)
            if truth is not None and ref_exp is None:
                ref_exp = D.with_truth(e, truth, float(e.voltage[0]))
            ref = ref_exp.truth if ref_exp is not None and ref_exp.truth is not None else e.voltage
            p, _ = prediction(forwards[label], c, e)
            ok = np.isfinite(p)
            table[label][name] = float(1e3 * np.sqrt(np.mean((p[ok] - ref[ok]) ** 2))) if ok.any() else float("nan")
            coverage[label][name] = float(ok.mean())
            preds[label] = p
        assert ref_exp is not None or truth is None
        e_plot = ref_exp if ref_exp is not None else D.experiment(path, next(iter(cells.values())), name=name, dt=dt)
        fig = plot_validation(e_plot, preds, out / f"{_slug(name)}.png")
        figures[name] = str(Path(fig).name)
    summary = {
        "rmse_mV": table,
        "coverage": coverage,
        "reference": "noise-free true voltage" if truth is not None else "measured voltage",
        "figures": figures,
    }
    _json(out / "validation.json", summary)
    return summary


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name).strip("_")


def experiments_hours(exps: Sequence[Any]) -> float:
    return float(sum(e.hours for e in exps))


def renamed(e: Any, name: str) -> Any:
    return replace(e, name=name)
