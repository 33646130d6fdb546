"""Identification and validation as functions on values: ``fit`` and ``validate``.

``fit`` takes logged data (our run logs, BDF CSV, Panasonic ``.mat``) and a start cell: a slow test (|I| ≤ C/10
for at least 5 h) is the OCV test for the equilibrium fit (eqs. 10–21); the others are dynamic data for the
weighted, group-wise Levenberg–Marquardt fit (eqs. 41–46). ``validate`` scores cells on held-out data. Both
return report values that know how to write their products (the BPX cell and its ``.summary.json``; figures); they
print nothing: stage results go to an ``on_stage`` callback and load warnings come back in the report.
"""

from __future__ import annotations

import copy
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.identify.data_files import Ambient, ambient_of, check_ambient_keys, is_ocv_test, load_all
from protocols.errors import InputError

#: what SOC 1 of a fitted cell is: where its OCV reaches V_max (eq. 20), or the state at the start of the OCV test
FULL_CHARGE = ("v-max", "ocv-start")


def full_charge_at_ocv_start(eq: Any) -> Cell:
    """The equilibrium fit's cell with SOC 1 moved to the state at the start of its OCV test (θ⁻ at q = 0, θ⁺ from
    the lithium balance, eq. 10); SOC 0 stays where the OCV reaches V_min. A test that starts right after the lab's
    full charge (a CCCV to V_max with a small cut-off current, then a rest) starts below V_max on the OCV; with
    this window ``soc0=1`` is the cell as that charge leaves it."""
    n0, _, p0, _ = eq.cell.stoichiometry_window()
    tn = float(eq.theta_n0)
    tp = (float(eq.n_Li) - float(eq.H_n) * tn) / float(eq.H_p)
    if not (n0 < tn < 1.0 and 0.0 < tp < p0):
        raise InputError(
            f"the OCV test's start (θ⁻ {tn:.4f}, θ⁺ {tp:.4f}) is not inside the cell's window from V_min "
            f"(θ⁻ {n0:.4f}, θ⁺ {p0:.4f}): it cannot be the full charge"
        )
    src = f"the state at the start of the OCV test {eq.curve.source}".strip()
    values = {"sto_n_0": n0, "sto_n_100": tn, "sto_p_0": p0, "sto_p_100": tp}
    new = eq.cell.with_values(**values)
    return Cell(new.name, new.values, {**new.sources, **{k: src for k in values}}, new.description)


def plan_groups(plan: Path) -> list[tuple[list[str], set[str]]]:
    """Groups (parameters, selected profile ids) of a design plan (:func:`battlab.io.plan.design_groups`)."""
    from battlab.io.plan import design_groups

    return [(list(g.parameters), set(g.selected)) for g in design_groups(plan)]


def stages(
    params: str | None,
    plan: str | Path | None,
    experiments: list[Any],
    groups: Sequence[tuple[Sequence[str], set[str]]] | None = None,
    cell: Cell | None = None,
) -> list[Any]:
    """Stages of the cumulative fit: from the plan's design summary, else the given ``groups`` (parameters,
    selected library ids; e.g. a run log's), else ``params`` (table9 | all | NAMES; None: table9). Each experiment
    joins one stage: that of its run log step's ``group`` when that group selected its profile's ``library_id``,
    else the first group that selected it, else stage 1 (the fit is cumulative: later stages see it too). With
    model extensions on in ``cell``, their parameters join the last stage (``all``: every parameter of ``cell``)."""
    from battlab import parameters
    from battlab.identify.fit import Stage

    extra = cell.parameter_names()[len(parameters.NAMES) :] if cell is not None else ()
    if plan is not None:
        groups = plan_groups(Path(plan))
    if groups is not None:
        groups = list(groups)

        def lib_id(e: Any) -> str:
            return str(e.profile.params.get("library_id", e.name))

        home: dict[int, int] = {}  # experiment (by position) -> its group (0-based); each experiment in one stage
        for i, e in enumerate(experiments):  # a run log's profile step labelled 'group k' that group k selected
            k = e.profile.params.get("group")
            if isinstance(k, int) and 1 <= k <= len(groups) and lib_id(e) in groups[k - 1][1]:
                home[i] = k - 1
        for i, e in enumerate(experiments):  # else the first group that selected its profile; else stage 1
            if i not in home:
                home[i] = next((k for k, (_, sel) in enumerate(groups) if lib_id(e) in sel), 0)
        out = [
            Stage(tuple(names), tuple(e for i, e in enumerate(experiments) if home[i] == k))
            for k, (names, _) in enumerate(groups)
        ]
        if out and extra:
            out[-1] = Stage(out[-1].names + tuple(extra), out[-1].experiments)
        return out
    p = (params or "table9").strip()
    if p == "none":
        return []
    if p == "table9":
        table9 = list(parameters.TABLE9_GROUPS)
        table9[-1] = table9[-1] + tuple(extra)
        return [Stage(g, tuple(experiments) if k == 0 else ()) for k, g in enumerate(table9)]
    names = [*parameters.NAMES, *extra] if p == "all" else [s.strip() for s in p.split(",") if s.strip()]
    return [Stage(parameters.check_names(names), tuple(experiments))]


def unique_names(experiments: list[Any]) -> list[Any]:
    """The experiments with unique names: a name met again (data files of the same name from different
    directories, e.g. the run logs of a sequential design) gets ``~2``, ``~3``, … in the order given (the summary's
    RMSE and the stages' experiment lists are keyed by name)."""
    seen: dict[str, int] = {}
    out = []
    for e in experiments:
        n = seen.get(e.name, 0) + 1
        seen[e.name] = n
        out.append(e if n == 1 else replace(e, name=f"{e.name}~{n}"))
    return out


@dataclass
class FitReport:
    """A fit's outcome: the identified cell, the machine-readable summary, the BPX metadata, the stages."""

    cell: Cell
    summary: dict[str, Any]
    extra: dict[str, Any]
    results: list[Any] = field(default_factory=list)  # identify.fit.FitResult per stage
    equilibrium: Any = None  # identify.equilibrium result, when an OCV test was given
    equilibrium_data: str = ""  # the name of that OCV test
    warnings: list[str] = field(default_factory=list)

    @property
    def last(self) -> Any:
        return self.results[-1] if self.results else None

    def write(self, output: str | Path) -> tuple[Path, Path]:
        """The BPX cell (intervals and fit report under "User-defined"), ``<cell>.summary.json`` beside it and the
        same summary as ``summary.json`` (the name scripts read: docs/file-formats.md).

        Each file is written to a temporary name and renamed over the old one, so a crash while writing leaves
        the previous version (e.g. the last finished stage) whole."""
        from battlab.io.paths import summary_path as summary_of

        out = Path(output)
        tmp = out.with_name(f".{out.name}.tmp")
        self.cell.renamed(out.name.removesuffix(".json").removesuffix(".bpx")).to_bpx(tmp, **self.extra)
        os.replace(tmp, out)
        summary_path = summary_of(out)
        text = json.dumps(self.summary, indent=2, default=json_default)
        for path in (summary_path, out.with_name("summary.json")):
            tmp = path.with_name(f".{path.name}.tmp")
            tmp.write_text(text)
            os.replace(tmp, path)
        return out, summary_path


def stages_text(done: int, total: int) -> str:
    """``"stage 1 of 4"``, ``"stages 1–3 of 4"``, or with no stage done ``"equilibrium only (stages 0 of 4)"`` (the
    only result written before stage 1 is the equilibrium fit's)."""
    if done == 0:
        return f"equilibrium only (stages 0 of {total})"
    return f"stage 1 of {total}" if done == 1 else f"stages 1–{done} of {total}"


class StageFailed(Exception):
    """``fit`` failed in a stage: the stage (1-based, of ``total``), its cause, the report of the finished stages
    (partial), the files the last of them was written to and how many stages those hold (``written`` None: nothing
    written; ``kept`` 0 with files: the equilibrium fit alone)."""

    def __init__(
        self,
        stage: int,
        total: int,
        cause: Exception,
        report: FitReport,
        written: tuple[Path, Path] | None,
        kept: int,
    ) -> None:
        self.stage, self.total, self.cause, self.report = stage, total, cause, report
        self.written, self.kept = written, kept
        what = " ".join(str(cause).split())  # one line, whatever the cause's text
        what = what if isinstance(cause, InputError) else f"{type(cause).__name__}: {what}"
        if written is not None:
            where = f"{stages_text(kept, total)} kept (partial) in {written[0]} and {written[1]}"
        elif report.results:
            where = f"{stages_text(len(report.results), total)} finished, nothing written (no output given)"
        else:
            where = "no stage finished, nothing written"
        super().__init__(f"fit failed in stage {stage} of {total}: {what}; {where}")


def fit(
    data: Sequence[str | Path],
    cell: Cell | str,
    *,
    plan: str | Path | None = None,
    params: str | None = "table9",
    ocp_terms: int = 0,
    rated_capacity: float | None = None,
    full_charge: str = "v-max",
    ocv_branch: str = "both",
    soc0: float | None = None,
    ambient: Ambient = None,
    dt: float = 1.0,
    max_iter: int = 40,
    fix_sign: bool = False,
    value_stages: Sequence[tuple[str, str]] = (),
    arrhenius: bool = False,
    on_stage: Callable[[int, Any], None] | None = None,
    on_equilibrium: Callable[[str, Any], None] | None = None,
    on_values: Callable[[Any], None] | None = None,
    output: str | Path | None = None,
    hold_radii: bool = True,
    noise: Any = None,
    per_file_ageing: Sequence[str] | str = (),
) -> FitReport:
    """Identify the cell's parameters from logged data: equilibrium from an OCV test, then the dynamic
    parameters by weighted LM, group by group and cumulatively (stages from ``plan``, else ``params``; ``params``
    None: the groups of the run log's plan when a run log has one, else table9).
    ``ambient`` [K]: for data that do not log it (see :data:`Ambient`); such data are refused otherwise.
    A run log (with its plan in its metadata, or ``plan``) is cut at its plan's profile steps, one experiment each
    (:mod:`battlab.identify.runlog`). ``hold_radii``: where a stage would estimate all four orbit parameters of an
    electrode, its R_s is held and the invariants are reported (:mod:`battlab.identify.reduced`).
    ``full_charge``: SOC 1 of the identified cell, "v-max" (the OCV reaches V_max, eq. 20) or "ocv-start" (the
    state at the start of the OCV test, :func:`full_charge_at_ocv_start`; for a test that starts from the lab's
    full charge). ``ocv_branch``: the OCV test's branches that make the pseudo-OCV (:func:`ocv_curve`).

    ``output`` (the BPX path; ``summary.json`` beside it): the report is written there after every stage, before
    ``on_stage`` is called, marked partial (``summary["partial"]`` True, ``"status": "partial: stages 1–3 of 4"``,
    ``"converged"`` False; the BPX's fit report says the same) until the last stage, and then complete. The
    equilibrium fit, when dynamic stages follow, is written before stage 1 starts, marked partial the same way
    (``"partial: equilibrium only (stages 0 of 4)"``, ``stages_done`` 0); ``on_equilibrium(data name, result)`` is
    called then (after that write, or without stages after the final one). ``value_stages`` ((target, names),
    e.g. ("voltage", "R_c,E_kappa"), ("temperature", "C1+C2,h2a")): fits of cell values outside the 18 by finite
    differences (:mod:`battlab.identify.values`), in order, after the stages (``params`` "none": no stage); each
    is written when done and reported to ``on_values``. ``arrhenius``: the stages fit the data within 5 K of the
    cell's T_ref only; then the last stage's parameters with an activation energy are refitted per other ambient and
    the activation energies set from them (:mod:`battlab.identify.arrhenius`), reported to ``on_values``. A failure
    in a stage raises :class:`StageFailed` naming it, with the finished stages (or the equilibrium fit) kept on disk.
    ``noise`` (a :class:`battlab.noise.NoiseModel` or a noise file): the model that weighs the residuals; without
    it, eq. 38 fitted to the repeated trials in the run logs, else the paper's (:mod:`battlab.identify.weights`);
    ``summary["noise"]`` says which.

    ``per_file_ageing`` (names among ``n_Li``, ``capacity``; :mod:`battlab.identify.ageing`): each dynamic data file
    gets its own cyclable lithium and/or capacity, fitted in every stage and in the Arrhenius refits with the shared
    parameters; ``summary["per_file_ageing"]`` (and the BPX's user-defined metadata) holds each file's values and
    95 % intervals. The written cell is ONE cell at the mean of the files' values (one cell for every test date,
    :func:`battlab.identify.ageing.aged_cell`); the value stages fit that cell."""
    from battlab.identify import ageing as A
    from battlab.identify import fit as F
    from battlab.identify import runlog
    from battlab.identify.equilibrium import fit_equilibrium, ocv_curve
    from battlab.identify.forward import ForwardModel
    from battlab.identify.informing import check_informed
    from battlab.identify.weights import weigh
    from battlab.io.plan import Plan

    if full_charge not in FULL_CHARGE:
        raise InputError(f"full charge {full_charge!r}: expected one of {', '.join(FULL_CHARGE)}")
    cell = cell if isinstance(cell, Cell) else Cell.load(cell)
    age_names = A.parse_names(per_file_ageing) if per_file_ageing else ()
    if age_names and len(data) < 2:
        raise InputError(
            "--per-file-ageing needs two or more data files (with one file its ageing is the cell's own: fit "
            "without the option)"
        )
    check_ambient_keys(data, ambient)
    plan_obj = Plan.load(plan) if plan is not None else None
    loaded, warned = load_all(data, fix_sign=fix_sign)
    ocv = [d for d in loaded if is_ocv_test(d, float(cell["Q_nom"]))]
    dyn = [d for d in loaded if d not in ocv]
    if full_charge == "ocv-start" and not ocv:
        raise InputError("--full-charge ocv-start needs an OCV test (|I| <= C/10 for at least 5 h) among the data")
    summary: dict[str, Any] = {"parameters": {}, "rmse_mV": {}, "converged": True}
    extra: dict[str, Any] = {}
    report = FitReport(cell, summary, extra, warnings=warned)
    written: tuple[Path, Path] | None = None  # where the last finished stage (or the equilibrium fit) was written
    kept = 0  # the stages written there
    if ocv:
        d = ocv[0]
        eq = fit_equilibrium(
            ocv_curve(d.t, d.current, d.voltage, source=d.source, branch=ocv_branch),
            cell,
            ocp_terms=ocp_terms,
            rated_capacity=rated_capacity,
        )
        cell = eq.cell
        rep = eq.report()
        if full_charge == "ocv-start":
            cell = full_charge_at_ocv_start(eq)
            n0, n1, p0, p1 = cell.stoichiometry_window()
            rep["window"] = {"sto_n_0": n0, "sto_n_100": n1, "sto_p_0": p0, "sto_p_100": p1}
            rep["capacity_Ah"] = cell.capacity()
        rep["full_charge"] = full_charge
        summary["equilibrium"] = rep
        summary["rmse_mV"][d.name] = eq.rmse_mV
        summary["converged"] = eq.converged
        for k in ("eps_s_n", "eps_s_p", "n_Li"):
            summary["parameters"][k] = {"value": rep[k], "ci95": [None, None], "at_bound": False}
        extra["equilibrium"] = {k: v for k, v in rep.items() if not isinstance(v, str)}
        report.equilibrium, report.equilibrium_data = eq, d.name
    elif rated_capacity is not None:
        cell = cell.with_values(Q_nom=rated_capacity)
    if age_names and not dyn:
        raise InputError("--per-file-ageing: no dynamic data among the files (only the OCV test)")
    if dyn:
        pairs = [
            (e, d.name)
            for d in dyn
            for e in runlog.experiments(
                d, cell, plan=plan_obj, plan_name=str(plan), dt=dt, soc0=soc0, ambient=ambient_of(d, ambient)
            )
        ]
        exps = unique_names([e for e, _ in pairs])
        ageing = (
            A.Ageing(age_names, {e.name: f for e, (_, f) in zip(exps, pairs, strict=True)}, cell.lithium_moles())
            if age_names
            else None
        )
        per_file: dict[str, Any] = {}  # file -> name -> {value, ci95, ...}: the latest fit of each file

        def export(unaged: Cell) -> Cell:
            """The written cell: ``unaged`` at the mean of the files' ageing values (without the option: itself)."""
            if ageing is None or not per_file:
                return unaged
            mean = A.mean_state(per_file, ageing)
            why = f"mean of the per-file ageing values of {len(per_file)} data files (battlab fit --per-file-ageing)"
            exported = {"state": "mean of the files' values", **mean, "reference_n_Li": ageing.n_li_ref}
            block = {"names": list(ageing.names), "files": copy.deepcopy(per_file), "exported": exported}
            report.summary["per_file_ageing"] = block
            report.extra["per_file_ageing"] = {
                "files": {
                    f: {n: {"value": v["value"], "ci95": v["ci95"]} for n, v in d.items()} for f, d in per_file.items()
                },
                "exported": {**mean, "reference_n_Li": ageing.n_li_ref},
            }
            return A.aged_cell(unaged, mean.get("n_Li", ageing.n_li_ref), mean.get("capacity", 1.0), why)

        exps, _, summary["noise"] = weigh(exps, noise)
        if not exps:
            raise InputError("the data hold only noise trials: nothing to fit")
        fm = ForwardModel(cell, v_margin=0.15)
        by_ambient: dict[float, list[Any]] = {}
        if arrhenius:
            from battlab.identify.arrhenius import split_by_ambient

            exps, by_ambient = split_by_ambient(exps, float(cell["T_ref"]))
            if not exps:
                raise InputError(f"--arrhenius needs data within 5 K of the cell's T_ref {float(cell['T_ref']):g} K")
        logged = runlog.logged_groups(dyn) if plan is None and params is None else None
        groups = [(g.parameters, set(g.selected)) for g in logged] if logged is not None else None
        plan_stages = stages(params, plan, exps, groups, cell)
        seen: list[Any] = []
        for st in plan_stages:  # stages are cumulative: a stage fits its own and every earlier stage's data
            seen += [e for e in st.experiments if e not in seen]
            check_informed(st.names, seen, 0.01 * float(cell["Q_nom"]))
        base_summary, base_extra = copy.deepcopy(summary), copy.deepcopy(extra)

        def stage_done(k: int, res: Any) -> None:
            nonlocal written, kept
            report.results.append(res)
            report.cell = res.cell
            report.summary, report.extra = copy.deepcopy(base_summary), copy.deepcopy(base_extra)
            _summarise_dynamic(report.results, report.summary, report.extra, len(plan_stages))
            per_file.update(res.extra.get("ageing", {}))
            report.cell = export(res.cell)
            if output is not None:
                written, kept = report.write(output), k
            if on_stage is not None:
                on_stage(k, res)

        report.cell = cell  # the start of the dynamic fit, until a stage finishes
        if report.equilibrium is not None and plan_stages:
            _summarise_equilibrium_only(report.summary, report.extra, len(plan_stages))
            if output is not None:  # a crash or Ctrl-C in stage 1 keeps the equilibrium fit
                written, kept = report.write(output), 0
            if on_equilibrium is not None:
                on_equilibrium(report.equilibrium_data, report.equilibrium)
        try:
            if plan_stages:
                fit_stages(
                    cell,
                    plan_stages,
                    options=F.Options(max_nfev=max_iter),
                    forward=fm,
                    progress=stage_done,
                    hold_radii=hold_radii,
                    ageing=ageing,
                )
        except F.StageError as exc:
            raise StageFailed(exc.stage, exc.total, exc.cause, report, written, kept) from exc.cause
        if arrhenius:
            from battlab.identify.arrhenius import fit_arrhenius

            names = [n for r in report.results for n in r.names] if report.results else []
            unaged = report.results[-1].cell if report.results else report.cell
            if ageing is not None:  # the other ambients' files start where the stages left the files (the reference)
                ageing = ageing.with_start({f: {n: v["value"] for n, v in d.items()} for f, d in per_file.items()})
            arr = fit_arrhenius(
                unaged, by_ambient, names, forward=fm, options=F.Options(max_nfev=max_iter), ageing=ageing
            )
            per_file.update(arr.ageing)
            report.cell = export(arr.cell)
            report.summary["arrhenius"] = arr.report()
            report.extra["arrhenius"] = {"E_J_per_mol": arr.energies, "clipped": arr.clipped}
            for k, v in arr.energies.items():
                report.summary["parameters"][k] = {"value": v, "ci95": [None, None], "at_bound": k in arr.clipped}
            if output is not None:
                written = report.write(output)
            if on_values is not None:
                on_values(arr)
    else:
        report.cell = cell
    if not report.results:  # no stage: the equilibrium fit (or the start cell) alone
        if report.equilibrium is not None:
            _summarise_equilibrium_only(report.summary, report.extra, 0)
        if output is not None:
            report.write(output)
        if report.equilibrium is not None and on_equilibrium is not None:
            on_equilibrium(report.equilibrium_data, report.equilibrium)
    if value_stages:
        from battlab.identify.values import fit_value_stages

        fit_value_stages(
            report, dyn, value_stages, dt=dt, soc0=soc0, ambient=ambient, max_iter=max_iter, on_values=on_values
        )
        if output is not None:
            report.write(output)
    return report


def fit_stages(
    cell: Cell,
    stages: Sequence[Any],
    *,
    options: Any = None,
    forward: Any = None,
    progress: Callable[[int, Any], None] | None = None,
    hold_radii: bool = True,
    ageing: Any = None,
) -> list[Any]:
    """The cumulative group-wise fit of :func:`battlab.identify.fit.fit_groupwise` (stage k fits groups 1..k on
    the experiments of stages 1..k from where stage k − 1 ended), in the identifiable coordinates when
    ``hold_radii``: the R_s of an electrode whose R_s, D_s, k, R_f are all fitted is held at the stage's start
    value (:mod:`battlab.identify.reduced`). ``ageing`` (:class:`battlab.identify.ageing.Ageing`): per-file ageing
    values, each stage starting from the last one's. Errors in stage k are raised as
    :class:`battlab.identify.fit.StageError` with the finished stages."""
    from battlab.identify import fit as F
    from battlab.identify import reduced
    from battlab.identify.forward import ForwardModel

    fm = forward or ForwardModel(cell)
    current = cell
    names: list[str] = []
    exps: list[Any] = []
    results: list[Any] = []
    for k, stg in enumerate(stages, start=1):
        names += [n for n in stg.names if n not in names]
        exps += list(stg.experiments)
        fitted, held = reduced.split(names) if hold_radii else (list(names), [])
        try:
            res = F.fit(cell, exps, fitted, options=options, forward=fm, start=current, stage=k, ageing=ageing)
            if ageing is not None:
                values = res.extra.get("ageing", {})
                ageing = ageing.with_start({f: {n: v["value"] for n, v in d.items()} for f, d in values.items()})
            if held:
                res = replace(res, statistics=reduced.with_held(res.statistics, reduced.held_values(current, held)))
            if progress is not None:
                progress(k, res)
        except Exception as exc:
            raise F.StageError(k, len(stages), names, results, exc) from exc
        results.append(res)
        current = res.cell
    return results


def _summarise_equilibrium_only(summary: dict[str, Any], extra: dict[str, Any], total: int) -> None:
    """The summary and BPX metadata of the equilibrium fit alone: partial, none of ``total`` stages done, or
    (``total`` 0: no dynamic stage follows) complete."""
    partial = total > 0
    status = "partial: " + stages_text(0, total) if partial else "complete: equilibrium only"
    converged = bool(summary["converged"]) and not partial
    keys = {"partial": partial, "status": status, "stages_done": 0, "stages_total": total, "converged": converged}
    summary.update(keys, stages=[])
    extra["fit_report"] = dict(keys)


def _summarise_dynamic(results: list[Any], summary: dict[str, Any], extra: dict[str, Any], total: int) -> None:
    """The summary and BPX metadata of the finished stages ``results`` of ``total``: partial until the last."""
    last = results[-1]
    st = last.statistics
    partial = len(results) < total
    stages_converged = all(r.convergence.converged for r in results)
    summary["converged"] = bool(summary["converged"] and stages_converged and not partial)
    summary["partial"] = partial
    summary["status"] = ("partial: " if partial else "complete: ") + stages_text(len(results), total)
    summary["stages_done"], summary["stages_total"] = len(results), total
    for e in st.estimates:
        summary["parameters"][e.name] = {
            "value": e.value,
            "ci95": list(e.ci95) if e.ci95 else [None, None],
            "at_bound": e.at_bound is not None,
            "identifiable": e.identifiable,
            "set_identified": e.set_identified,
        }
    summary["rmse_mV"].update(last.rmse_mV)
    summary["stages"] = [r.report() for r in results]
    extra["confidence_intervals"] = {e.name: list(e.ci95) for e in st.estimates if e.ci95}
    if st.invariants:
        extra["invariants"] = {
            i.name: {"value": i.value, "ci95": list(i.ci95), "definition": i.definition} for i in st.invariants
        }
        summary["invariants"] = copy.deepcopy(extra["invariants"])
    held = [n for n in (e.name for e in st.estimates) if n not in last.names]
    if held:
        summary["held"] = {e.name: e.value for e in st.estimates if e.name in held}
    if st.unidentifiable:
        extra["not_identifiable"] = list(st.unidentifiable)
        extra["null_space"] = [dict(d) for d in st.null_space]
    extra["at_bound"] = {e.name: e.at_bound is not None for e in st.estimates}
    extra["fit_report"] = {
        "status": summary["status"],
        "partial": partial,
        "stages_done": len(results),
        "stages_total": total,
        "converged": summary["converged"],
        "iterations": last.convergence.iterations,
        "cost": last.convergence.cost,
        "s2": st.s2,
        "rmse_mV": last.rmse_mV,
        "reason": last.convergence.reason,
    }


def stage_figures(r: Any, prefix: Path) -> list[Path]:
    """Fig. 7 for one stage: CDF of |voltage error| before and after, and the correlation matrix."""
    from battlab.identify.statistics import correlation
    from battlab.identify.validation import plot_cdf, plot_correlation

    out = [Path(f"{prefix}.error_cdf.png")]
    plot_cdf(
        {"before": r.errors_before_mV, "after": r.errors_after_mV},
        out[0],
        f"stage {r.stage}: |voltage error| before and after",
    )
    st = r.statistics
    corr = st.correlation if st.correlation is not None else correlation(st.covariance_identifiable)
    if corr is not None:
        out.append(Path(f"{prefix}.correlation.png"))
        plot_correlation(st.names, corr, out[-1], f"stage {r.stage}: parameter correlation")
    return out


def json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)
