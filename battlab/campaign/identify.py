"""The campaign's fits, validation scores and residual analysis on its own experiments.

The fits call :func:`battlab.identify.fit.fit_groupwise` (weighted Levenberg-Marquardt with sensitivities, eqs.
41-46) with the campaign's experiments, weighted by the noise model fitted from repeated trials, so that the OED fit
and the conventional fit share start point, optimiser and stopping rule (``[fit] max_evaluations``).
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
    from battlab.identify.workflow import json_default

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, default=json_default))


def cumulative_fit(
    cell: Cell,
    stages: Sequence[Any],
    camp: Any,
    output: Path,
    progress: Callable[[float, float, str], None],
) -> dict[str, Any]:
    """Fit ``stages`` (:class:`battlab.identify.fit.Stage`) cumulatively from ``cell``; write the BPX cell and
    ``<stem>.summary.json`` beside it; return the summary: per parameter value, 95 % interval and bound flag, the
    stages' reports, and on the virtual lab the recovery table against the truth."""
    from battlab.identify import fit as F
    from battlab.identify.forward import ForwardModel

    progress(0, len(stages), "stage 1")

    def done(k: int, res: Any) -> None:
        progress(k, len(stages), f"stage {k} of {len(stages)} done ({res.convergence.iterations} evaluations)")

    fm = ForwardModel(cell, v_margin=0.15)
    opts = F.Options(max_nfev=camp.config.fit.max_evaluations, polish=camp.config.fit.polish)
    results = F.fit_groupwise(cell, stages, options=opts, forward=fm, progress=done)
    last = results[-1]
    st = last.statistics
    params = {
        e.name: {
            "value": e.value,
            "ci95": list(e.ci95) if e.ci95 else [None, None],
            "at_bound": e.at_bound is not None,
            "bound": e.at_bound,
            "identifiable": e.identifiable,
            "set_identified": e.set_identified,
            "theta_bar": e.theta_bar,
        }
        for e in st.estimates
    }
    summary: dict[str, Any] = {
        "parameters": params,
        "rmse_mV": last.rmse_mV,
        "converged": all(r.convergence.converged for r in results),
        "s2": st.s2,
        "stages": [
            {
                "parameters": list(r.names),
                "experiments": list(r.experiments),
                "iterations": r.convergence.iterations,
                "converged": r.convergence.converged,
                "reason": r.convergence.reason,
                "seconds": r.convergence.seconds,
                "cost_start": r.convergence.cost_start,
                "cost": r.convergence.cost,
            }
            for r in results
        ],
        "invariants": {i.name: {"value": i.value, "ci95": list(i.ci95)} for i in st.invariants},
        "data_hours": float(sum(e.hours for s in stages for e in s.experiments)),
    }
    if camp.tester.virtual:
        summary["recovery"] = recovery(st.estimates, Cell.load(camp.tester.truth), cell)
    output.parent.mkdir(parents=True, exist_ok=True)
    ci = {e.name: list(e.ci95) for e in st.estimates if e.ci95}
    last.cell.renamed(output.name.removesuffix(".bpx.json")).to_bpx(output, confidence_intervals=ci)
    _json(output.with_name(output.name.removesuffix(".bpx.json") + ".summary.json"), summary)
    return summary


def recovery(estimates: Sequence[Any], truth: Cell, start: Cell) -> list[dict[str, Any]]:
    """Per parameter: start, truth, estimate, interval, whether it covers the truth, and whether the truth sits on a
    bound (those are excluded from the coverage count, as decided in docs/decisions.md)."""
    rows = []
    for e in estimates:
        t = float(truth[e.name])
        tb = float(truth.normalised(e.name))
        rows.append(
            {
                "parameter": e.name,
                "start": float(start[e.name]),
                "truth": t,
                "estimate": e.value,
                "ci95": list(e.ci95) if e.ci95 else None,
                "covered": e.covers(t),
                "truth_on_bound": bool(tb <= 1e-6 or tb >= 1 - 1e-6),
                "estimate_at_bound": e.at_bound,
                "set_identified": e.set_identified,
                "theta_bar": {"start": float(start.normalised(e.name)), "truth": tb, "estimate": e.theta_bar},
                "sigma_bar": e.sigma_bar,
            }
        )
    return rows


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


def residuals(logs: Mapping[str, Path], cell: Cell, out: Path) -> dict[str, Any]:
    """Residual analysis (battlab.diagnose.residuals) of the identified cell on each validation log: what the
    simulation gets wrong, when, and whether the residual is white. Naming a cause (score tests of the model
    extensions, held-out fits of the leading ones) is ``battlab diagnose``'s work: it takes minutes per hour of data,
    so the campaign leaves it to that command and its summary says how to run it on these logs."""
    from battlab.campaign import data as D
    from battlab.diagnose.figures import conditional_errors, residual_vs_time
    from battlab.diagnose.residuals import analyse
    from battlab.identify.forward import ForwardModel
    from battlab.identify.validation import prediction

    out.mkdir(parents=True, exist_ok=True)
    fm = ForwardModel(cell, v_margin=0.15)
    per: dict[str, Any] = {}
    figures: list[str] = []
    for name, path in logs.items():
        dt = 10.0 if "discharge" in name else 1.0
        e = D.experiment(path, cell, name=name, dt=dt)
        p, _ = prediction(fm, cell, e)
        ok = np.isfinite(p)
        a = analyse(
            e.profile.t[ok], e.voltage[ok], p[ok], e.profile.current[ok], noise_variance=float(np.mean(e.variance))
        )
        per[name] = _plain(a.summary())
        slug = _slug(name)
        figures.append(residual_vs_time(a, out / f"{slug}.residual.png", f"{name}: residual").name)
        figures.append(conditional_errors(a, out / f"{slug}.conditional.png").name)
    summary = {
        "method": "residual analysis only (battlab.diagnose.residuals); no extension was scored or fitted",
        "name_a_cause": "battlab diagnose "
        + " ".join(f"runs/validation/{Path(p).name}" for p in logs.values())
        + " --cell fit/oed.bpx.json -o diagnosis/causes",
        "cause": None,
        "data": per,
        "figures": figures,
    }
    _json(out / "diagnosis.json", summary)
    return summary


def _plain(x: Any) -> Any:
    from battlab.identify.workflow import json_default

    return json.loads(json.dumps(x, default=json_default))


def experiments_hours(exps: Sequence[Any]) -> float:
    return float(sum(e.hours for e in exps))


def renamed(e: Any, name: str) -> Any:
    return replace(e, name=name)
