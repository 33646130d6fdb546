"""``battlab fit`` as a function on values: :func:`fit` takes one :class:`~battlab.identify.fit_options.FitOptions`
and returns a :class:`FitReport`, in steps.

Logged data (our run logs, BDF CSV, Panasonic ``.mat``) and a start cell: a slow test (|I| ≤ C/10 for at least 5 h) is
the OCV test for the equilibrium fit (eqs. 10–21); the others are dynamic data for the weighted, group-wise
Levenberg–Marquardt fit (eqs. 41–46) of the one cumulative-fit engine (:mod:`battlab.identify.cumulative`). The report
knows how to write its products (the BPX cell and its ``.summary.json``); nothing is printed: progress and each
finished step's result go to subscribers as :class:`battlab.progress.ProgressEvent` values, with a :class:`StageDone`,
:class:`EquilibriumDone` or :class:`ValuesDone` payload on the ``note`` that announces it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from battlab.identify import fit_steps as S
from battlab.identify.data_files import check_ambient_keys, is_ocv_test, load_all
from battlab.identify.fit_options import FULL_CHARGE, FitOptions
from battlab.identify.fit_plan import full_charge_at_ocv_start, stages, unique_names
from battlab.identify.fit_report import (
    EquilibriumDone,
    FitReport,
    StageDone,
    StageFailed,
    ValuesDone,
    on_equilibrium,
    on_stage,
)
from battlab.identify.fit_summary import stages_text
from battlab.jsonable import json_default
from battlab.progress import Reporter, Subscriber

__all__ = [
    "FULL_CHARGE",
    "EquilibriumDone",
    "FitOptions",
    "FitReport",
    "StageDone",
    "StageFailed",
    "ValuesDone",
    "fit",
    "full_charge_at_ocv_start",
    "json_default",
    "on_equilibrium",
    "on_stage",
    "stage_figures",
    "stages",
    "stages_text",
    "unique_names",
]


def fit(options: FitOptions, subscribers: Sequence[Subscriber] = ()) -> FitReport:
    """Identify the cell's parameters from logged data (see :class:`FitOptions` and the module docstring): the
    equilibrium from an OCV test, then the dynamic parameters by weighted LM, group by group and cumulatively
    (stages from ``plan``, else ``groups``, else ``params``; ``params`` None: the groups of the run log's plan when
    a run log has one, else table9). A run log (with its plan in its metadata, or ``plan``) is cut at its plan's
    profile steps, one experiment each (:mod:`battlab.identify.runlog`). Data that do not log their ambient need
    ``ambient``.

    With ``output`` (the BPX path; ``summary.json`` beside it) the report is written after the equilibrium fit and
    after every stage, marked partial (``"status": "partial: stages 1–3 of 4"``, ``"converged"`` False) until the last.
    ``value_stages`` ((target, names)): fits of cell values outside the 18 by finite differences
    (:mod:`battlab.identify.values`) after the stages. ``arrhenius``: the stages fit the data within 5 K of T_ref;
    then the activation energies from per-ambient refits (:mod:`battlab.identify.arrhenius`). ``per_file_ageing``
    (names among ``n_Li``, ``capacity``; :mod:`battlab.identify.ageing`): each dynamic data file gets its own
    cyclable lithium and/or capacity; the written cell holds their mean. A failure in a stage raises
    :class:`StageFailed` naming it, with the finished stages (or the equilibrium fit) kept on disk."""
    o = options
    progress = Reporter("fit", subscribers)
    cell = o.start_cell()
    S.check_options(o, cell)
    check_ambient_keys(o.data, o.ambient)
    loaded, warned = load_all(o.data, fix_sign=o.fix_sign)
    ocv = [d for d in loaded if is_ocv_test(d, float(cell["Q_nom"]))]
    dyn = [d for d in loaded if d not in ocv]
    S.check_data(o, ocv, dyn)
    report = FitReport(cell, {"parameters": {}, "rmse_mV": {}, "converged": True}, {}, warnings=warned)
    for w in warned:
        progress("note", text=f"warning: {w}")
    if ocv:
        cell = S.equilibrium_step(o, ocv[0], cell, report)
    elif o.rated_capacity is not None:
        cell = cell.with_values(Q_nom=o.rated_capacity)
    report.cell = cell
    if dyn:
        S.dynamic_step(o, dyn, cell, report, progress)
    if not report.results:  # no stage: the equilibrium fit (or the start cell) alone
        S.equilibrium_only_step(o, report, progress)
    if o.value_stages:
        from battlab.identify.values import fit_value_stages

        def on_values(vf: Any) -> None:
            progress("note", payload=ValuesDone(vf))

        fit_value_stages(
            report,
            dyn,
            o.value_stages,
            dt=o.dt,
            soc0=o.soc0,
            ambient=o.ambient,
            max_iter=o.max_iter,
            on_values=on_values,
        )
        report.checkpoint(o.output, report.kept)
    return report


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
