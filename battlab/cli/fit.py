"""``battlab fit`` and ``battlab validate``: identify a cell from logged data, and score cells on held-out data.

DATA: our HDF5 run logs (``.h5``), BDF CSV (``.csv``, optional ``.meta.json`` sidecar) or Panasonic ``.mat``.
A slow test (|I| ≤ C/10 for at least 5 h) is taken as the OCV test for the equilibrium fit; the others are
dynamic data. Outputs: the BPX cell (intervals and fit report under "User-defined") and ``summary.json`` next
to it: ``{"parameters": {name: {"value", "ci95": [lo, hi], "at_bound"}}, "rmse_mV": {data: value},
"converged": bool, ...}``.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import click
import numpy as np

from protocols.errors import InputError


def _is_ocv_test(data: Any, q_nom: float) -> bool:
    dur = float(data.t[-1] - data.t[0])
    return float(np.max(np.abs(data.current))) <= 0.1 * q_nom * 1.05 and dur >= 5 * 3600


def _stages(params: str, plan: str | None, experiments: list[Any]) -> list[Any]:
    """Stages of the cumulative fit: from the plan's design summary, or --params (table9 | all | NAMES)."""
    from battlab import parameters
    from battlab.identify.fit import TABLE9_GROUPS, Stage

    if plan is not None:
        groups = _plan_groups(Path(plan))
        stages = []
        used: set[str] = set()
        for names, selected in groups:
            exps = tuple(e for e in experiments if str(e.profile.params.get("library_id", e.name)) in selected)
            used |= {e.name for e in exps}
            stages.append(Stage(tuple(names), exps))
        rest = tuple(e for e in experiments if e.name not in used)
        if stages and rest:
            stages[0] = Stage(stages[0].names, stages[0].experiments + rest)
        return stages
    p = params.strip()
    if p == "table9":
        return [Stage(g, tuple(experiments) if k == 0 else ()) for k, g in enumerate(TABLE9_GROUPS)]
    names = list(parameters.NAMES) if p == "all" else [s.strip() for s in p.split(",") if s.strip()]
    return [Stage(parameters.check_names(names), tuple(experiments))]


def _plan_groups(plan: Path) -> list[tuple[list[str], set[str]]]:
    """Groups (parameters, selected profile ids) of a design plan: its ``summary.json`` beside it, else the
    plan's profile steps labelled 'group N' with the Table 9 groups."""
    from battlab.identify.fit import TABLE9_GROUPS
    from protocols.protocol import ProfileStep, Protocol

    proto = Protocol.load(plan)
    summary = plan.with_name("summary.json")
    if summary.is_file():
        try:
            groups = json.loads(summary.read_text())["groups"]
            return [(list(g["parameters"]), {str(s) for s in g["selected"]}) for g in groups]
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise InputError(f"{summary}: expected the design summary with 'groups' ({exc})") from None
    out: list[tuple[list[str], set[str]]] = [(list(g), set()) for g in TABLE9_GROUPS]
    for s in proto.steps:
        if isinstance(s, ProfileStep):
            label = s.label.lower()
            k = int(label.split("group", 1)[1].split()[0].strip(":")) - 1 if "group" in label else 0
            if 0 <= k < len(out):
                out[k][1].add(str(s.profile.id))
    return out


@click.command("fit")
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cell_name", required=True, help="Start cell: a built-in name or a BPX file.")
@click.option(
    "--plan",
    type=click.Path(dir_okay=False),
    default=None,
    help="Design plan (protocols TOML); its summary.json gives the parameter groups.",
)
@click.option(
    "--params",
    default="table9",
    show_default=True,
    help="Without a plan: 'table9' (paper's groups, cumulative), 'all', or comma-separated names.",
)
@click.option(
    "--ocp-terms",
    type=int,
    default=0,
    show_default=True,
    help="Terms of the positive-OCP correction in the equilibrium fit (0 = the paper's method).",
)
@click.option("--rated-capacity", type=float, default=None, help="Set the cell's 1C capacity [Ah].")
@click.option("--soc0", type=float, default=None, help="Start SOC of data that do not start at rest.")
@click.option("--dt", type=float, default=1.0, show_default=True, help="Resample dynamic data to this step [s].")
@click.option("--max-iter", type=int, default=40, show_default=True, help="Function evaluations per stage.")
@click.option("--fix-sign", is_flag=True, help="Flip a current logged with positive = discharge.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="cell.bpx.json")
def fit(
    data: tuple[str, ...],
    cell_name: str,
    plan: str | None,
    params: str,
    ocp_terms: int,
    rated_capacity: float | None,
    soc0: float | None,
    dt: float,
    max_iter: int,
    fix_sign: bool,
    output: str,
) -> None:
    """Identify CELL's parameters from DATA (equilibrium from an OCV test, dynamics by weighted LM)."""
    from battlab.cell import Cell
    from battlab.identify import fit as F
    from battlab.identify.equilibrium import fit_equilibrium, ocv_curve
    from battlab.identify.experiments import experiments_from_data
    from battlab.identify.forward import ForwardModel
    from battlab.io.data import load_data

    out = Path(output)
    cell = Cell.load(cell_name)
    loaded = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for p in data:
            loaded.append(load_data(p, fix_sign=fix_sign))
    for w in caught:
        click.echo(f"warning: {w.message}", err=True)
    ocv = [d for d in loaded if _is_ocv_test(d, float(cell["Q_nom"]))]
    dyn = [d for d in loaded if d not in ocv]
    summary: dict[str, Any] = {"parameters": {}, "rmse_mV": {}, "converged": True}
    extra: dict[str, Any] = {}
    if ocv:
        d = ocv[0]
        eq = fit_equilibrium(
            ocv_curve(d.t, d.current, d.voltage, source=d.source),
            cell,
            ocp_terms=ocp_terms,
            rated_capacity=rated_capacity,
        )
        cell = eq.cell
        rep = eq.report()
        summary["equilibrium"] = rep
        summary["rmse_mV"][d.name] = eq.rmse_mV
        summary["converged"] = eq.converged
        for k in ("eps_s_n", "eps_s_p", "n_Li"):
            summary["parameters"][k] = {"value": rep[k], "ci95": [None, None], "at_bound": False}
        extra["equilibrium"] = {k: v for k, v in rep.items() if not isinstance(v, str)}
        click.echo(
            f"equilibrium ({d.name}): capacity {eq.capacity:.4f} Ah, eps_s_n {eq.eps_s_n:.4f}, "
            f"eps_s_p {eq.eps_s_p:.4f}, n_Li {eq.n_Li:.5f} mol, RMSE {eq.rmse_mV:.1f} mV "
            f"({eq.rmse_5_95_mV:.1f} mV over 5-95 % SOC)"
        )
    elif rated_capacity is not None:
        cell = cell.with_values(Q_nom=rated_capacity)
    if dyn:
        exps = [e for d in dyn for e in experiments_from_data(d, cell, dt=dt, soc0=soc0)]
        fm = ForwardModel(cell, v_margin=0.15)
        stages = _stages(params, plan, exps)

        stem = out.name.removesuffix(".json").removesuffix(".bpx")

        def show(k: int, r: F.FitResult) -> None:
            c = r.convergence
            click.echo(
                f"stage {k}: {len(r.names)} parameters, {c.iterations} evaluations, cost {c.cost_start:.4g} "
                f"-> {c.cost:.4g}, |g| {c.gradient_norm:.3g}, {c.reason}"
            )
            _stage_figures(r, out.with_name(f"{stem}.stage{k}"))

        results = F.fit_groupwise(cell, stages, options=F.Options(max_nfev=max_iter), forward=fm, progress=show)
        last = results[-1]
        cell = last.cell
        summary["converged"] = bool(summary["converged"] and all(r.convergence.converged for r in results))
        for e in last.statistics.estimates:
            summary["parameters"][e.name] = {
                "value": e.value,
                "ci95": list(e.ci95) if e.ci95 else [None, None],
                "at_bound": e.at_bound is not None,
                "identifiable": e.identifiable,
                "set_identified": e.set_identified,
            }
        summary["rmse_mV"].update(last.rmse_mV)
        summary["stages"] = [r.report() for r in results]
        _print_estimates(last)
        if last.statistics.s2 > 10:
            click.echo(
                f"warning: weighted residual variance s² = {last.statistics.s2:.3g} >> 1: the residuals are "
                "model error, not measurement noise (or the data come from another cell); the intervals of "
                "eq. 44 are too narrow, summary.json also gives them scaled by s² (ci95_scaled)",
                err=True,
            )
        if not last.statistics.valid:
            click.echo(f"warning: {last.statistics.reason}", err=True)
        extra["confidence_intervals"] = {e.name: list(e.ci95) for e in last.statistics.estimates if e.ci95}
        if last.statistics.invariants:
            extra["invariants"] = {
                i.name: {"value": i.value, "ci95": list(i.ci95), "definition": i.definition}
                for i in last.statistics.invariants
            }
        if last.statistics.unidentifiable:
            extra["not_identifiable"] = list(last.statistics.unidentifiable)
            extra["null_space"] = [dict(d) for d in last.statistics.null_space]
        extra["at_bound"] = {e.name: e.at_bound is not None for e in last.statistics.estimates}
        extra["fit_report"] = {
            "converged": summary["converged"],
            "iterations": last.convergence.iterations,
            "cost": last.convergence.cost,
            "s2": last.statistics.s2,
            "rmse_mV": last.rmse_mV,
            "reason": last.convergence.reason,
        }
    cell.renamed(out.name.removesuffix(".json").removesuffix(".bpx")).to_bpx(out, **extra)
    summary_path = out.with_name("summary.json")
    if plan is not None and Path(plan).with_name("summary.json").resolve() == summary_path.resolve():
        click.echo(
            f"warning: {summary_path} (the design's summary) is replaced by the fit's summary; write the "
            "fitted cell to another directory to keep both",
            err=True,
        )
    summary_path.write_text(json.dumps(summary, indent=2, default=_json_default))
    click.echo(f"wrote {out} and {summary_path}")


def _stage_figures(r: Any, prefix: Path) -> None:
    """Fig. 7 for one stage: CDF of |voltage error| before and after, and the correlation matrix."""
    from battlab.identify.statistics import correlation
    from battlab.identify.validation import plot_cdf, plot_correlation

    plot_cdf(
        {"before": r.errors_before_mV, "after": r.errors_after_mV},
        f"{prefix}.error_cdf.png",
        f"stage {r.stage}: |voltage error| before and after",
    )
    st = r.statistics
    corr = st.correlation if st.correlation is not None else correlation(st.covariance_identifiable)
    if corr is not None:
        plot_correlation(st.names, corr, f"{prefix}.correlation.png", f"stage {r.stage}: parameter correlation")


def _print_estimates(r: Any) -> None:
    """The final stage's estimates: value, 95 % interval, flags."""
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"identified parameters (stage {r.stage}; s² = {r.statistics.s2:.3g})")
    for col in ("parameter", "value", "95 % interval", "note"):
        t.add_column(col)
    for e in r.statistics.estimates:
        ci = f"[{e.ci95[0]:.4g}, {e.ci95[1]:.4g}]" if e.ci95 else "-"
        note = (
            "symmetry orbit (set-identified)" if e.set_identified else "not identifiable" if not e.identifiable else ""
        )
        note += f" at {e.at_bound} bound" + ("" if e.set_identified else " (one-sided)") if e.at_bound else ""
        t.add_row(e.name, f"{e.value:.4g}", ci, note.strip())
    for i in r.statistics.invariants:
        t.add_row(i.name, f"{i.value:.4g}", f"[{i.ci95[0]:.4g}, {i.ci95[1]:.4g}]", f"invariant {i.definition}")
    Console(width=110).print(t)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


@click.command("validate")
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cells", multiple=True, required=True, help="A cell to score (repeat for several).")
@click.option("--soc0", type=float, default=None, help="Start SOC of data that do not start at rest.")
@click.option("--dt", type=float, default=1.0, show_default=True, help="Resample to this step [s].")
@click.option("--fix-sign", is_flag=True, help="Flip a current logged with positive = discharge.")
@click.option(
    "-o",
    "--output",
    default="validation",
    show_default=True,
    type=click.Path(file_okay=False),
    help="Directory for the figures and summary.json.",
)
def validate(
    data: tuple[str, ...], cells: tuple[str, ...], soc0: float | None, dt: float, fix_sign: bool, output: str
) -> None:
    """Print the voltage RMSE of each CELL on each DATA file and save the figures (Figs. 7 and 9)."""
    from battlab.cell import Cell
    from battlab.identify.experiments import experiments_from_data
    from battlab.identify.fit import predict
    from battlab.identify.forward import ForwardModel
    from battlab.identify.validation import format_table, plot_cdf, plot_validation
    from battlab.io.data import load_data

    outdir = Path(output)
    outdir.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = [load_data(p, fix_sign=fix_sign) for p in data]
    for w in caught:
        click.echo(f"warning: {w.message}", err=True)
    table: dict[str, dict[str, float]] = {}
    errors: dict[str, np.ndarray] = {}
    per_exp: dict[str, tuple[Any, dict[str, np.ndarray]]] = {}
    for spec in cells:
        cell = Cell.load(spec)
        label = Path(spec).name.removesuffix(".json").removesuffix(".bpx") if spec.endswith(".json") else spec
        fm = ForwardModel(cell, v_margin=0.15)
        table[label] = {}
        errs = []
        for d in loaded:
            for e in experiments_from_data(d, cell, dt=dt, soc0=soc0):
                p = predict(fm, cell, e)
                table[label][e.name] = float(1e3 * np.sqrt(np.nanmean((p - e.voltage) ** 2)))
                errs.append(1e3 * (p - e.voltage))
                per_exp.setdefault(e.name, (e, {}))[1][label] = p
        errors[label] = np.concatenate(errs)
    click.echo(format_table(table))
    for name, (e, preds) in per_exp.items():
        plot_validation(e, preds, outdir / f"{name.replace('#', '_')}.png")
    plot_cdf(errors, outdir / "error_cdf.png", "validation: |voltage error|")
    (outdir / "summary.json").write_text(json.dumps({"rmse_mV": table}, indent=2))
    click.echo(f"figures and summary.json in {outdir}")
