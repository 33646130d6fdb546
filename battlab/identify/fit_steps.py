"""The steps of :func:`battlab.identify.workflow.fit`, each on the options, the data and the report so far: checks
before any work, the equilibrium fit of an OCV test, the dynamic stages (the cumulative-fit engine), the Arrhenius
refits and the per-file ageing of the written cell."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from battlab.cell import Cell
from battlab.identify import ageing as A
from battlab.identify import fit_summary
from battlab.identify.cumulative import StageError, check_stages_informed, fit_cumulative
from battlab.identify.data_files import ambient_of, load_all
from battlab.identify.fit_options import FitOptions
from battlab.identify.fit_plan import full_charge_at_ocv_start, stages, unique_names
from battlab.identify.fit_report import EquilibriumDone, FitReport, StageDone, StageFailed, ValuesDone
from battlab.progress import Reporter
from protocols.errors import InputError


def check_options(o: FitOptions, cell: Cell) -> None:
    """One :class:`InputError` for options that contradict each other, before any data are read."""
    if o.per_file_ageing:
        A.parse_names(o.per_file_ageing)
        if len(o.data) < 2:
            raise InputError(
                "--per-file-ageing needs two or more data files (with one file its ageing is the cell's own: fit "
                "without the option)"
            )
    if o.soc0 is not None and not 0.0 <= o.soc0 <= 1.0:
        raise InputError(f"--soc0 {o.soc0:g}: a state of charge is between 0 and 1")


def check_data(o: FitOptions, ocv: Sequence[Any], dyn: Sequence[Any]) -> None:
    if o.full_charge == "ocv-start" and not ocv:
        raise InputError("--full-charge ocv-start needs an OCV test (|I| <= C/10 for at least 5 h) among the data")
    if o.per_file_ageing and not dyn:
        raise InputError("--per-file-ageing: no dynamic data among the files (only the OCV test)")


def equilibrium_step(o: FitOptions, d: Any, cell: Cell, report: FitReport) -> Cell:
    """The equilibrium fit of the OCV test ``d`` (eqs. 10–21) into the report; returns the fitted cell."""
    from battlab.identify.equilibrium import fit_equilibrium, ocv_curve

    eq = fit_equilibrium(
        ocv_curve(d.t, d.current, d.voltage, source=d.source, branch=o.ocv_branch),
        cell,
        ocp_terms=o.ocp_terms,
        rated_capacity=o.rated_capacity,
    )
    cell = eq.cell
    rep = eq.report()
    if o.full_charge == "ocv-start":
        cell = full_charge_at_ocv_start(eq)
        n0, n1, p0, p1 = cell.stoichiometry_window()
        rep["window"] = {"sto_n_0": n0, "sto_n_100": n1, "sto_p_0": p0, "sto_p_100": p1}
        rep["capacity_Ah"] = cell.capacity()
    rep["full_charge"] = o.full_charge
    s = report.summary
    s["equilibrium"] = rep
    s["rmse_mV"][d.name] = eq.rmse_mV
    s["converged"] = eq.converged
    for k in ("eps_s_n", "eps_s_p", "n_Li"):
        s["parameters"][k] = {"value": rep[k], "ci95": [None, None], "at_bound": False}
    report.extra["equilibrium"] = {k: v for k, v in rep.items() if not isinstance(v, str)}
    report.equilibrium, report.equilibrium_data = eq, d.name
    return cell


def equilibrium_only_step(o: FitOptions, report: FitReport, progress: Reporter) -> None:
    """No dynamic stage: the equilibrium fit (or the start cell) alone, complete."""
    if report.equilibrium is not None:
        _equilibrium_only(report, 0)
    if o.output is not None:
        report.write(o.output)
    if report.equilibrium is not None:
        progress("note", payload=EquilibriumDone(report.equilibrium_data, report.equilibrium))


def _equilibrium_only(report: FitReport, total: int) -> None:
    report.summary = fit_summary.equilibrium_only(report.summary, total)
    keys = ("partial", "status", "stages_done", "stages_total", "converged")
    report.extra["fit_report"] = {k: report.summary[k] for k in keys}


@dataclass
class _Dynamic:
    """What the dynamic stages share: the experiments, the engine's start, the per-file ageing so far."""

    exps: list[Any]
    stages: list[Any]
    forward: Any
    ageing: A.Ageing | None
    by_ambient: dict[float, list[Any]] = field(default_factory=dict)
    per_file: dict[str, Any] = field(default_factory=dict)  # file -> name -> {value, ci95, ...}: latest fit


def experiments_of(o: FitOptions, dyn: Sequence[Any], cell: Cell) -> tuple[list[Any], dict[str, str]]:
    """The dynamic data's experiments (run logs cut at their plans' profile steps), unique names, and each
    experiment's data file."""
    from battlab.identify import runlog
    from battlab.io.plan import Plan

    plan = Plan.load(o.plan) if o.plan is not None else None
    preps = _preparations(o)
    pairs = []
    for d in dyn:
        es = runlog.experiments(
            d, cell, plan=plan, plan_name=str(o.plan), dt=o.dt, soc0=o.soc0, ambient=ambient_of(d, o.ambient)
        )
        prep = preps.get(Path(d.source).resolve()) if d.source else None
        if prep is not None and es:  # the measurement's first experiment starts with its preparation
            es[0] = runlog.after_preparation(es[0], prep, cell, log=d)
        pairs += [(e, d.name) for e in es]
    exps = unique_names([e for e, _ in pairs])
    return exps, {e.name: f for e, (_, f) in zip(exps, pairs, strict=True)}


def _preparations(o: FitOptions) -> dict[Path, Any]:
    """The preparations' logs by their measurement's resolved path."""
    if not o.preparations:
        return {}
    loaded, _ = load_all([p for _, p in o.preparations], fix_sign=o.fix_sign)
    return {Path(d).resolve(): prep for (d, _), prep in zip(o.preparations, loaded, strict=True)}


def _prepare(o: FitOptions, dyn: Sequence[Any], cell: Cell, report: FitReport) -> _Dynamic:
    from battlab.identify import runlog
    from battlab.identify.forward import ForwardModel
    from battlab.identify.weights import weigh

    exps, files = experiments_of(o, dyn, cell)
    names = A.parse_names(o.per_file_ageing) if o.per_file_ageing else ()
    ageing = A.Ageing(names, files, cell.lithium_moles()) if names else None
    exps, _, report.summary["noise"] = weigh(exps, o.noise)
    if not exps:
        raise InputError("the data hold only noise trials: nothing to fit")
    by_ambient: dict[float, list[Any]] = {}
    if o.arrhenius:
        from battlab.identify.arrhenius import split_by_ambient

        exps, by_ambient = split_by_ambient(exps, float(cell["T_ref"]))
        if not exps:
            raise InputError(f"--arrhenius needs data within 5 K of the cell's T_ref {float(cell['T_ref']):g} K")
    groups = o.groups
    if groups is None and o.plan is None and o.params is None:
        logged = runlog.logged_groups(dyn)
        groups = tuple((tuple(g.parameters), frozenset(g.selected)) for g in logged) if logged is not None else None
    st = stages(o.params, o.plan, exps, groups, cell)
    if o.drop_uninformed:
        st, dropped = drop_uninformed(st, cell)
        if dropped:
            report.summary["not_informed"] = dropped
    check_stages_informed(st, cell)
    report.experiments = list(exps)
    delays = {e.name: e.sample_delay for e in exps if e.sample_delay > 0}
    if delays:  # the run logs' set-to-sample delay: the model changes the current that much before each sample
        report.summary["sample_delay_s"] = delays
    return _Dynamic(exps, st, ForwardModel(cell, v_margin=0.15), ageing, by_ambient)


def drop_uninformed(stages_: list[Any], cell: Cell) -> tuple[list[Any], dict[str, str]]:
    """The stages without the parameters their data cannot inform (cumulative, as they are fitted), and those
    left out with why."""
    from battlab.identify.fit import Stage
    from battlab.identify.informing import uninformed

    seen: list[Any] = []
    out, dropped = [], {}
    for st in stages_:
        seen += [e for e in st.experiments if e not in seen]
        bad = uninformed(st.names, seen, 0.01 * float(cell["Q_nom"]))
        dropped.update(bad)
        out.append(Stage(tuple(n for n in st.names if n not in bad), st.experiments))
    return [s for s in out if s.names], dropped


def _export(report: FitReport, unaged: Cell, dyn: _Dynamic) -> Cell:
    """The written cell: ``unaged`` at the mean of the files' ageing values (without per-file ageing: itself)."""
    if dyn.ageing is None or not dyn.per_file:
        return unaged
    ageing = dyn.ageing
    mean = A.mean_state(dyn.per_file, ageing)
    why = f"mean of the per-file ageing values of {len(dyn.per_file)} data files (battlab fit --per-file-ageing)"
    exported = {"state": "mean of the files' values", **mean, "reference_n_Li": ageing.n_li_ref}
    block = {"names": list(ageing.names), "files": copy.deepcopy(dyn.per_file), "exported": exported}
    report.summary["per_file_ageing"] = block
    report.extra["per_file_ageing"] = {
        "files": {
            f: {n: {"value": v["value"], "ci95": v["ci95"]} for n, v in d.items()} for f, d in dyn.per_file.items()
        },
        "exported": {**mean, "reference_n_Li": ageing.n_li_ref},
    }
    return A.aged_cell(unaged, mean.get("n_Li", ageing.n_li_ref), mean.get("capacity", 1.0), why)


def bpx_metadata(summary: dict[str, Any], last: Any) -> dict[str, Any]:
    """The BPX file's user-defined fit metadata of a dynamic fit's summary."""
    st = last.statistics
    out: dict[str, Any] = {
        "confidence_intervals": {e.name: list(e.ci95) for e in st.estimates if e.ci95},
        "at_bound": {e.name: e.at_bound is not None for e in st.estimates},
    }
    if st.invariants:
        out["invariants"] = {
            i.name: {"value": i.value, "ci95": list(i.ci95), "definition": i.definition} for i in st.invariants
        }
    if st.unidentifiable:
        out["not_identifiable"] = list(st.unidentifiable)
        out["null_space"] = [dict(d) for d in st.null_space]
    out["fit_report"] = {
        "status": summary["status"],
        "partial": summary["partial"],
        "stages_done": summary["stages_done"],
        "stages_total": summary["stages_total"],
        "converged": summary["converged"],
        "iterations": last.convergence.iterations,
        "cost": last.convergence.cost,
        "s2": st.s2,
        "rmse_mV": last.rmse_mV,
        "reason": last.convergence.reason,
        "trusted": summary["trust"]["trusted"],
    }
    return out


def dynamic_step(o: FitOptions, data: Sequence[Any], cell: Cell, report: FitReport, progress: Reporter) -> None:
    """The cumulative stages on the dynamic data (then the Arrhenius refits), written after each stage."""
    dyn = _prepare(o, data, cell, report)
    total = len(dyn.stages)
    base_summary, base_extra = copy.deepcopy(report.summary), copy.deepcopy(report.extra)
    if report.equilibrium is not None and total:
        _equilibrium_only(report, total)
        report.checkpoint(o.output, 0)  # a crash or Ctrl-C in stage 1 keeps the equilibrium fit
        progress("note", payload=EquilibriumDone(report.equilibrium_data, report.equilibrium))

    def stage_done(k: int, res: Any) -> None:
        report.results.append(res)
        report.summary = fit_summary.dynamic_summary(report.results, total, base_summary)
        report.extra = {**copy.deepcopy(base_extra), **bpx_metadata(report.summary, res)}
        dyn.per_file.update(res.extra.get("ageing", {}))
        report.cell = _export(report, res.cell, dyn)
        report.checkpoint(o.output, k)
        progress("note", k, total, payload=StageDone(k, total, res))

    try:
        if dyn.stages:
            fit_cumulative(
                cell,
                dyn.stages,
                o.settings,
                forward=dyn.forward,
                ageing=dyn.ageing,
                on_stage=stage_done,
                progress=progress,
            )
    except StageError as exc:
        raise StageFailed(exc.stage, exc.total, exc.cause, report, report.written, report.kept) from exc.cause
    if o.arrhenius:
        _arrhenius_step(o, report, dyn, progress)


def _arrhenius_step(o: FitOptions, report: FitReport, dyn: _Dynamic, progress: Reporter) -> None:
    from battlab.identify.arrhenius import fit_arrhenius

    names = [n for r in report.results for n in r.names] if report.results else []
    unaged = report.results[-1].cell if report.results else report.cell
    ageing = dyn.ageing
    if ageing is not None:  # the other ambients' files start where the stages left the files (the reference)
        ageing = ageing.with_start({f: {n: v["value"] for n, v in d.items()} for f, d in dyn.per_file.items()})
    arr = fit_arrhenius(unaged, dyn.by_ambient, names, forward=dyn.forward, options=o.settings.options(), ageing=ageing)
    dyn.per_file.update(arr.ageing)
    report.cell = _export(report, arr.cell, dyn)
    report.summary["arrhenius"] = arr.report()
    report.extra["arrhenius"] = {"E_J_per_mol": arr.energies, "clipped": arr.clipped}
    for k, v in arr.energies.items():
        report.summary["parameters"][k] = {"value": v, "ci95": [None, None], "at_bound": k in arr.clipped}
    report.checkpoint(o.output, report.kept)
    progress("note", payload=ValuesDone(arr))


__all__ = ["bpx_metadata", "check_data", "check_options", "dynamic_step", "equilibrium_step", "experiments_of"]
