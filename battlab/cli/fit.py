"""``battlab fit`` and ``battlab validate``: thin shells over :mod:`battlab.identify.workflow` (identify a cell
from logged data, score cells on held-out data).

DATA: our HDF5 run logs (``.h5``), BDF CSV (``.csv``, optional ``.summary.json`` sidecar) or Panasonic ``.mat``.
A slow test (|I| ≤ C/10 for at least 5 h) is taken as the OCV test for the equilibrium fit; the others are
dynamic data. A run log is cut at the profile steps of the plan it ran (kept in its metadata; ``--plan`` must be
that plan): one experiment per profile, named ``<log>:<profile id>``, and the design's groups (from ``--plan``'s
summary, else those the runner kept in the log) are the stages.

Outputs: the BPX cell (intervals and fit report under "User-defined") and ``<cell>.summary.json`` next to it:
``{"parameters": {name: {"value", "ci95": [lo, hi], "at_bound"}}, "rmse_mV": {data: value}, "converged": bool, ...}``.
"""

from __future__ import annotations

from typing import Any

import click

from battlab.cli.options import (
    AMBIENT_OPTION,
    CAPACITY,
    DATA_FORMATS,
    apply_extensions,
    apply_ocps,
    bounded_option,
    dt_option,
    extension_option,
    max_iter_option,
    ocp_option,
    parse_ambients,
    soc0_option,
)


@click.command(
    "fit",
    epilog=f"{DATA_FORMATS} A real cell step by step: examples/panasonic/fit.sh (the Panasonic 18650PF data).",
)
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cell_name", required=True, help="Start cell: a built-in name or a BPX file.")
@click.option(
    "--plan",
    type=click.Path(dir_okay=False),
    default=None,
    help="Design plan (protocols TOML); its <plan>.summary.json gives the parameter groups.",
)
@click.option(
    "--params",
    "--groups",
    "params",
    default=None,
    help="Without a plan: 'table9' (paper's groups, cumulative), 'all', 'none' (no stage) or comma-separated names "
    "[default: the groups of a run log's plan, else table9].",
)
@click.option(
    "--ocp-terms",
    type=int,
    default=0,
    show_default=True,
    help="Terms of the positive-OCP correction in the equilibrium fit (0 = the paper's method).",
)
@bounded_option("--rated-capacity", CAPACITY, "Set the cell's 1C capacity [Ah]")
@click.option(
    "--full-charge",
    type=click.Choice(["v-max", "ocv-start"]),
    default="v-max",
    show_default=True,
    help="SOC 1 of the fitted cell: where its OCV reaches V_max, or the state at the start of the OCV test (a "
    "test that starts from the lab's full charge: then soc0=1 is the cell as charged).",
)
@click.option(
    "--ocv-branch",
    type=click.Choice(["both", "discharge", "charge"]),
    default="both",
    show_default=True,
    help="Pseudo-OCV from the mean of the OCV test's discharge and charge, or from one branch (shifted by its "
    "rest-step overpotential): with hysteresis, 'discharge' is the equilibrium that discharge tests see.",
)
@soc0_option()
@AMBIENT_OPTION
@dt_option("Resample dynamic data to this step [s]")
@max_iter_option("Function evaluations per stage", default=40)
@click.option("--fix-sign", is_flag=True, help="Flip a current logged with positive = discharge.")
@extension_option()
@ocp_option()
@click.option(
    "--fit-values",
    "value_stages",
    multiple=True,
    metavar="[TARGET:]NAMES",
    help="After the stages, fit cell values outside the 18 (e.g. R_c, E_kappa, h2a; C1+C2: one factor on both) to "
    "the voltage (default) or the surface 'temperature:' by finite differences; repeat for several fits, in order.",
)
@click.option(
    "--arrhenius",
    is_flag=True,
    help="Fit the stages on the data within 5 K of T_ref, then refit their parameters with an activation energy "
    "(D_s, k, D_e_scale, kappa_scale) per other ambient and set the activation energies from them.",
)
@click.option(
    "--per-file-ageing",
    "per_file_ageing",
    default=None,
    metavar="NAMES",
    help="Give each data file its own ageing state, fitted with the shared parameters: 'n_Li' (cyclable lithium "
    "[mol], within +-15 % of the start cell's; every file starts at the OCV the start cell has at soc0) and/or "
    "'capacity' (active electrode area, 0.7-1.05 of the start cell's), e.g. n_Li,capacity; for tests of one cell "
    "on different dates. Each file's values and 95 % intervals go to the summary and the BPX metadata; the "
    "written cell holds their mean (one cell for every date).",
)
@click.option(
    "--noise",
    "noise_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="Noise model (eq. 38) that weighs the residuals: noise.toml, or a campaign's noise/noise.json [default: "
    "fitted to the repeated trials in the run logs, else the paper's coefficients].",
)
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="cell.bpx.json")
def fit(
    data: tuple[str, ...],
    cell_name: str,
    plan: str | None,
    params: str | None,
    ocp_terms: int,
    rated_capacity: float | None,
    full_charge: str,
    ocv_branch: str,
    soc0: float | None,
    ambients: tuple[str, ...],
    dt: float,
    max_iter: int,
    fix_sign: bool,
    extensions: tuple[str, ...],
    ocps: tuple[str, ...],
    value_stages: tuple[str, ...],
    arrhenius: bool,
    per_file_ageing: str | None,
    noise_file: str | None,
    output: str,
) -> None:
    """Identify CELL's parameters from DATA (equilibrium from an OCV test, dynamics by weighted LM).

    The result is written after the equilibrium fit and after every stage, marked partial until the last; a failing
    stage is one line naming it and exit code 1, with the finished stages (or the equilibrium fit) kept.

    The residuals are weighted by a noise model (eqs. 36-40): --noise FILE, else eq. 38 fitted to the repeated
    trials in the run logs (a plan's noise trials, `battlab design --noise-trials`), else the paper's coefficients;
    the output and the summary's "noise" say which."""
    import json
    import sys

    from battlab.identify import values, workflow
    from battlab.io import paths
    from protocols.errors import InputError

    if noise_file is not None:  # a bad file is one line before any data is read
        from battlab.noise import load

        load(noise_file)
    start: Any = cell_name
    if extensions or ocps:  # the extensions' parameters join the last stage (with --params all: every parameter)
        from battlab.cell import Cell

        start = apply_extensions(apply_ocps(Cell.load(cell_name), ocps), extensions)
    out = paths.check_output_path(output, create=True)
    stem = out.name.removesuffix(".json").removesuffix(".bpx")
    summary_path = paths.summary_path(out)
    if plan is not None and paths.summary_path(plan).resolve() == summary_path.resolve():
        click.echo(
            f"warning: {summary_path} (the design's summary) is replaced by the fit's summary; give the fitted "
            "cell another name than the plan to keep both",
            err=True,
        )
    done = 0
    equilibrium_written = False  # before stage 1 (when dynamic data follow the OCV test)

    def show_equilibrium(name: str, eq: Any) -> None:
        nonlocal equilibrium_written
        equilibrium_written = True
        click.echo(
            f"equilibrium ({name}): capacity {eq.capacity:.4f} Ah, eps_s_n {eq.eps_s_n:.4f}, "
            f"eps_s_p {eq.eps_s_p:.4f}, n_Li {eq.n_Li:.5f} mol, RMSE {eq.rmse_mV:.1f} mV "
            f"({eq.rmse_5_95_mV:.1f} mV over 5-95 % SOC)"
        )

    def show(k: int, r: Any) -> None:
        nonlocal done
        done = k
        c = r.convergence
        click.echo(
            f"stage {k}: {len(r.names)} parameters, {c.iterations} evaluations, cost {c.cost_start:.4g} "
            f"-> {c.cost:.4g}, |g| {c.gradient_norm:.3g}, {c.reason}"
        )
        workflow.stage_figures(r, out.with_name(f"{stem}.stage{k}"))

    def show_values(vf: Any) -> None:
        if hasattr(vf, "energies"):  # the Arrhenius refits
            click.echo(
                "activation energies [kJ/mol]: "
                + ", ".join(f"{k} {vf.start[k] / 1e3:.1f} -> {v / 1e3:.1f}" for k, v in vf.energies.items())
                + (f" (clipped: {', '.join(vf.clipped)})" if vf.clipped else "")
            )
            for amb, vals in vf.values.items():
                click.echo(f"  at {amb - 273.15:.1f} degC: " + ", ".join(f"{k} {v:.4g}" for k, v in vals.items()))
            return
        unit = "mV" if vf.target == "voltage" else "K"
        before = ", ".join(f"{k} {v:.2f}" for k, v in vf.rmse_before.items())
        after = ", ".join(f"{k} {v:.2f}" for k, v in vf.rmse_after.items())
        click.echo(
            f"value fit ({vf.target}; {vf.evaluations} evaluations, {vf.seconds:.0f} s): "
            + ", ".join(f"{k} {vf.start[k]:.4g} -> {v:.4g}" for k, v in vf.values.items())
            + f"; RMSE [{unit}] {before} -> {after}"
        )

    try:
        values_ = [values.parse_value_stage(v) for v in value_stages]
        rep = workflow.fit(
            data,
            start,
            plan=plan,
            params=params,
            ocp_terms=ocp_terms,
            rated_capacity=rated_capacity,
            full_charge=full_charge,
            ocv_branch=ocv_branch,
            soc0=soc0,
            ambient=parse_ambients(ambients),
            dt=dt,
            max_iter=max_iter,
            fix_sign=fix_sign,
            value_stages=values_,
            arrhenius=arrhenius,
            noise=noise_file,
            per_file_ageing=per_file_ageing or (),
            on_values=show_values,
            on_stage=show,
            on_equilibrium=show_equilibrium,
            output=out,
        )
    except workflow.StageFailed as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(2 if isinstance(exc.cause, InputError) else 1)
    except KeyboardInterrupt:
        written = done or equilibrium_written
        status = json.loads(summary_path.read_text()).get("status", "") if written else ""
        if status.startswith("complete"):  # while the last stage's figures were drawn
            click.echo(f"interrupted after the fit; {status.removeprefix('complete: ')} written to {out}", err=True)
        elif written:
            kept = status.removeprefix("partial: ") or "the finished stages"
            click.echo(f"interrupted in stage {done + 1}; {kept} kept (partial) in {out} and {summary_path}", err=True)
        else:
            click.echo(f"interrupted in stage 1; no stage finished, nothing written to {out}", err=True)
        sys.exit(130)
    for w in rep.warnings:
        click.echo(f"warning: {w}", err=True)
    if "noise" in rep.summary:
        _print_noise(rep.summary["noise"])
    last = rep.last
    if last is not None:
        _print_estimates(last)
        if last.statistics.s2 > 10:
            click.echo(
                f"warning: weighted residual variance s² = {last.statistics.s2:.3g} >> 1: the residuals are "
                "model error, not measurement noise (or the data come from another cell); the intervals of "
                "eq. 44 are too narrow, the summary also gives them scaled by s² (ci95_scaled)",
                err=True,
            )
        if not last.statistics.valid:
            click.echo(f"warning: {last.statistics.reason}", err=True)
    if "per_file_ageing" in rep.summary:
        _print_ageing(rep.summary["per_file_ageing"])
    click.echo(f"wrote {out}, {summary_path} and {out.with_name('summary.json')}")


def _print_noise(info: dict[str, Any]) -> None:
    """Which noise model weighed the residuals, and the repeated trials' noise levels."""
    m = info["model"]
    click.echo(
        f"noise model: {info['source']}: charge q = {m['a_c']:.4g} I + {m['b_c']:.4g} V, discharge q = "
        f"{m['a_d']:.4g} exp({m['b_d']:.4g} I) V, floor {m['floor']:.3g} V (I: input intensity, A s^0.5)"
    )
    for t in info.get("trials", []):
        click.echo(
            f"  repeated trials of profile {t['profile']} ({t['direction']}, intensity {t['intensity']:.1f} A s^0.5): "
            f"{t['trials']} trials, q {1e6 * t['q_V']:.0f} uV"
        )


def _print_ageing(block: dict[str, Any]) -> None:
    """Each file's ageing values with their 95 % intervals, and the state the written cell holds."""
    for f, vals in block["files"].items():
        parts = []
        for n, v in vals.items():
            ci = f" [{v['ci95'][0]:.5g}, {v['ci95'][1]:.5g}]" if v["ci95"] else ""
            parts.append(f"{n} {v['value']:.5g}{ci}" + (f" (at {v['at_bound']} bound)" if v["at_bound"] else ""))
        click.echo(f"ageing of {f}: " + ", ".join(parts))
    ex = block["exported"]
    click.echo(
        "written cell: the mean, "
        + ", ".join(f"{n} {ex[n]:.5g}" for n in block["names"])
        + f" (start cell's n_Li {ex['reference_n_Li']:.5g} mol)"
    )


def _print_estimates(r: Any) -> None:
    """The final stage's estimates: value, 95 % interval, flags."""
    from rich.table import Table

    from battlab.cli.console import make_console

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
    make_console().print(t)


@click.command("validate", epilog=DATA_FORMATS)
@click.argument("data", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--cell", "cells", multiple=True, required=True, help="A cell to score (repeat for several).")
@soc0_option()
@AMBIENT_OPTION
@dt_option()
@click.option("--fix-sign", is_flag=True, help="Flip a current logged with positive = discharge.")
@click.option(
    "-o",
    "--output",
    default="validation",
    show_default=True,
    type=click.Path(file_okay=False),
    help="Directory for the figures and the summary (<DIR>/<DIR>.summary.json).",
)
def validate(
    data: tuple[str, ...],
    cells: tuple[str, ...],
    soc0: float | None,
    ambients: tuple[str, ...],
    dt: float,
    fix_sign: bool,
    output: str,
) -> None:
    """Print the voltage RMSE of each CELL on each DATA file and save the figures (Figs. 7 and 9)."""
    from battlab.identify.validate import validate
    from battlab.identify.validation import format_table
    from battlab.io.paths import check_output_path

    check_output_path(output, directory=True, create=True)
    rep = validate(data, cells, soc0=soc0, ambient=parse_ambients(ambients), dt=dt, fix_sign=fix_sign)
    for w in rep.warnings:
        click.echo(f"warning: {w}", err=True)
    click.echo(format_table(rep.table, rep.coverage))
    summary = rep.write(output)
    click.echo(f"figures in {output}, summary {summary}")
